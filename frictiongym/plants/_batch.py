"""Batch kernels: N plants stepped by one compiled call, the common case in SIMD lanes.

A batch is stepped in blocks of ``BLOCK`` plants (:func:`step_plants`). Each block takes up to
three passes over its plants:

1. :func:`slide_lanes`, a loop with no branches that the compiler turns into SIMD code over the
   state's contiguous columns: it saturates and delays each command, and finishes every step
   that needs no event of the event-exact law (a held body; a body sliding on one speed range
   all step). The rest it marks pending (``S_STUCK = PENDING``, the command due in
   ``S_FRICTION``): one plant in twenty to one in twelve under commands around the break-away
   band.
1b. :func:`two_phase_lanes`, over the pending plants gathered into a work array: SIMD loops finish
   the steps of two phases (a stop, then held; a crossing of the decay range's edge, then a
   slide to the step's end), with ``log1p`` and ``expm1`` in scalar loops of their own.
2. A scalar loop over what is still pending (a second event, a break-away after a stop, a
   contact with the end stop: under 1 % of the plants) through :func:`advance_plant`, the
   element step that handles every law and every event.

All passes compute with the same operations in the same order as the element step alone
(:func:`~frictiongym.plants._kernel.sliding_setup` is the one copy of the sliding arithmetic),
so a plant's trajectory is bit-identical whichever pass steps it, alone or in a batch, serially
or on threads. The passes run for blocks of at least ``LANES_MIN`` plants that share one plant
row of the exact law without actuator lag, stepped once per period (no substeps); every other
batch takes the element step for each plant.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
from numba import njit, prange

from frictiongym.friction import _core as friction_core
from frictiongym.plants._backlash import step_backlash
from frictiongym.plants._kernel import (
    _MAX_SEGMENTS,
    F0,
    I_B,
    I_DEAD_ZONE,
    I_GAP,
    I_J,
    I_JITTER,
    I_LAG,
    I_LOAD_FRICTION,
    I_LOAD_INERTIA,
    I_STOP,
    I_UMAX,
    K0,
    LOG_SERIES_LIMIT,
    S_COMMAND,
    S_DRIVE,
    S_FRICTION,
    S_JITTER_RNG,
    S_LAG,
    S_STUCK,
    S_V,
    S_X,
    S_Z,
    SERIES_LIMIT,
    _affine_advance_by,
    advance,
    breakaway_direction,
    dead_zone,
    exact_phase,
    exact_static,
    has_exact_step,
    jitter_draw,
    phase_impulse,
    phi12_given,
    serial_njit,
    sliding_setup,
    time_to_terms,
)

#: Plants per block: pass 2 of a block follows pass 1 while its state is in cache, and the
#: threaded kernels spread whole blocks over their threads.
BLOCK = 256
#: Blocks of fewer plants take the element step only (a single env, a tuner's small batch).
LANES_MIN = 16
#: ``S_STUCK`` of a plant that pass 1 left to pass 2 (1.0 / 0.0 are stuck / sliding).
PENDING = 2.0
#: Pass 1b runs its SIMD loops over a multiple of this many entries, the pending plants padded
#: with zeros (never stored): the compiled loops step 8 plants at a time (AVX-512), and would
#: leave the last 1 to 7 of a block's 13 to 22 pending plants to a scalar copy of the loop.
LANE_GROUP = 8
if I_GAP != 26:  # slide_lanes unpacks the plant row up to the backlash by hand
    raise ImportError("frictiongym.plants._batch.slide_lanes must unpack every plant row field")


@njit(cache=True)
def first_non_finite(command: npt.NDArray[np.floating[Any]]) -> int:
    """Index of the first NaN or infinite command, or -1."""
    finite = True  # first a loop without exits, which runs in SIMD lanes; the search if needed
    for i in range(command.shape[0]):
        finite &= math.isfinite(command[i])
    if finite:
        return -1
    for i in range(command.shape[0]):
        if not math.isfinite(command[i]):
            return i
    return -1


@njit(cache=True, inline="always")
def advance_plant(
    i: int,
    state: npt.NDArray[np.float64],
    u: float,
    h: float,
    n_sub: int,
    params: npt.NDArray[np.float64],
    one_row: bool,
) -> None:
    """Step plant ``i`` under the command ``u`` due now (saturated, after the dead time)."""
    if params[0 if one_row else i, I_JITTER] > 0.0:
        jittered_step(i, state, u, h, n_sub, params, one_row)
    else:
        _advance(i, state, u, h, n_sub, params, one_row)


@njit(cache=True)
def jittered_step(
    i: int,
    state: npt.NDArray[np.float64],
    u: float,
    h: float,
    n_sub: int,
    params: npt.NDArray[np.float64],
    one_row: bool,
) -> None:
    """:func:`advance_plant` with a random latency: the last drive holds, then ``u`` takes over.

    The switch comes at ``jitter`` times a uniform draw after the step's start; the reported
    friction is the time average over both parts.
    """
    rng, draw = jitter_draw(state[S_JITTER_RNG, i])
    state[S_JITTER_RNG, i] = rng
    late = params[0 if one_row else i, I_JITTER] * draw
    friction = 0.0
    if late > 0.0:
        _advance_for(i, state, state[S_DRIVE, i], late, n_sub, params, one_row)
        friction = state[S_FRICTION, i] * late
    _advance_for(i, state, u, h - late, n_sub, params, one_row)
    state[S_FRICTION, i] = (friction + state[S_FRICTION, i] * (h - late)) / h
    state[S_DRIVE, i] = u


@njit(cache=True)
def _advance_for(
    i: int,
    state: npt.NDArray[np.float64],
    u: float,
    h: float,
    n_sub: int,
    params: npt.NDArray[np.float64],
    one_row: bool,
) -> None:
    """:func:`_advance`, compiled once for the jittered step's two calls."""
    _advance(i, state, u, h, n_sub, params, one_row)


@njit(cache=True, inline="always")
def _advance(
    i: int,
    state: npt.NDArray[np.float64],
    u: float,
    h: float,
    n_sub: int,
    params: npt.NDArray[np.float64],
    one_row: bool,
) -> None:
    """:func:`advance_plant` without the jitter: over ``h``, all under ``u``."""
    r = 0 if one_row else i
    plant = (params[r, I_J], params[r, I_B], params[r, I_UMAX], params[r, I_LAG], params[r, I_STOP])
    friction = (
        params[r, F0 + 0],
        params[r, F0 + 1],
        params[r, F0 + 2],
        params[r, F0 + 3],
        params[r, F0 + 4],
        params[r, F0 + 5],
        params[r, F0 + 6],
        params[r, F0 + 7],
        params[r, F0 + 8],
        params[r, F0 + 9],
        params[r, F0 + 10],
    )
    cache = (
        params[r, K0 + 0],
        params[r, K0 + 1],
        params[r, K0 + 2],
        params[r, K0 + 3],
        params[r, K0 + 4],
        params[r, K0 + 5],
        params[r, K0 + 6],
        params[r, K0 + 7],
        params[r, K0 + 8],
    )
    x0, v0 = state[S_X, i], state[S_V, i]
    z, y = state[S_Z, i], state[S_LAG, i]
    if params[r, I_GAP] > 0.0:
        drivetrain = (params[r, I_GAP], params[r, I_LOAD_INERTIA], params[r, I_LOAD_FRICTION])
        step_backlash(i, state, u, h, n_sub, plant, friction, cache, drivetrain)
        return
    if n_sub == 1 and plant[I_LAG] == 0.0 and has_exact_step(friction):
        # The exact law's step without advance's substep loop (a call of advance costs more
        # than most steps): one phase, and the rest phase by phase only if that one ended at
        # an event. The same operations as advance, so the same bits.
        j, stop = plant[I_J], plant[I_STOP]
        b_total = plant[I_B] + friction[friction_core.I_VISCOUS]
        x, v, dt, impulse = exact_phase(x0, v0, u, h, j, b_total, friction, stop, cache)
        if dt != h and v == 0.0 and breakaway_direction(u, friction) == 0.0:
            # stopped, then held for the rest: exact_static's next phase, written out
            impulse = (0.0 + impulse) + u * (h - dt)
        elif dt != h:
            x, v, impulse = exact_static(
                x, v, u, h - dt, j, b_total, friction, stop, cache, 0.0 + impulse, _MAX_SEGMENTS - 1
            )
        impulse = 0.0 + impulse
        if v0 == 0.0 and breakaway_direction(u, friction) == 0.0:
            f = u  # held all step: friction equals the input exactly, as in advance
        else:
            f = (impulse + friction[friction_core.I_VISCOUS] * (x - x0)) / h
    else:
        x, v, z, y, f = advance(x0, v0, z, y, u, h, n_sub, plant, friction, cache)
    state[S_X, i] = x
    state[S_V, i] = v
    state[S_Z, i] = z
    state[S_LAG, i] = y
    state[S_FRICTION, i] = f
    state[S_STUCK, i] = 1.0 if v == 0.0 else 0.0


@njit(cache=True, inline="always")
def apply_command(
    i: int,
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    c: float,
    umax: float,
    width: float,
    delayed: bool,
) -> float:
    """Saturate plant ``i``'s command ``c`` and record it; return the drive due now.

    The drive is the command due now (after the dead time) through the dead zone of half-width
    ``width``.
    """
    c = min(max(c, -umax), umax)
    state[S_COMMAND, i] = c
    if delayed:
        due = delay_buffer[head, i]
        delay_buffer[head, i] = c
        return dead_zone(due, width)
    return dead_zone(c, width)


@njit(cache=True, inline="always")
def _setup(
    v: float, u: float, s: float, row: tuple[float, ...]
) -> tuple[float, float, float, bool, int, float, float, float]:
    """:func:`sliding_setup` of direction ``s`` from the plant row; also that direction's levels."""
    forward = s > 0.0
    us = row[F0 + friction_core.I_US_POS] if forward else row[F0 + friction_core.I_US_NEG]
    uc = row[F0 + friction_core.I_UC_POS] if forward else row[F0 + friction_core.I_UC_NEG]
    v0 = row[F0 + friction_core.I_V0_POS] if forward else row[F0 + friction_core.I_V0_NEG]
    linear = row[F0 + friction_core.I_SHAPE] == friction_core.SHAPE_LINEAR
    b_total = row[I_B] + row[F0 + friction_core.I_VISCOUS]
    a, bb, k, inner, slope, target = sliding_setup(v, u, s, b_total, us, uc, v0, linear)
    return a, bb, k, inner, slope, target, us, uc


@njit(cache=True, inline="always")
def _slide(
    x: float,
    v: float,
    u: float,
    s: float,
    t: float,
    row: tuple[float, ...],
    uncached: bool,
    em1: float,
) -> tuple[float, float, float, bool, float, float, float, bool, float, float, bool, float]:
    """One sliding phase of the exact law from ``x``, ``v`` in direction ``s``, for time ``t``.

    As :func:`~frictiongym.plants._kernel.exact_phase` computes it before it looks for an event:
    ``E1``, ``E2`` from the row's cache when its key matches, else (``uncached``, a constant
    where this is inlined) as :func:`~frictiongym.plants._kernel._phi12` gives them, with
    ``em1 = expm1(-l)`` given. Conditional expressions only (SIMD code).

    Returns
    -------
    a, bb, k : float
        The phase's affine law and decay slope (:func:`sliding_setup`).
    inner : bool
    target, us, uc : float
        The velocity that ends the phase (NaN: none) and the direction's friction levels.
    cached : bool
        Whether ``E1``, ``E2`` came from the cache.
    x_new, v_new : float
        The state after time ``t``, if no event comes first.
    reached : bool
        Whether the phase reaches ``target`` within ``t`` (an event).
    ell : float
        ``l = bb t / J``, the argument of ``E1``, ``E2``.
    """
    j = row[I_J]
    a, bb, k, inner, slope, target, us, uc = _setup(v, u, s, row)
    key = row[K0] if slope == 0 else (row[K0 + 3] if slope == 1 else row[K0 + 6])
    e1 = row[K0 + 1] if slope == 0 else (row[K0 + 4] if slope == 1 else row[K0 + 7])
    e2 = row[K0 + 2] if slope == 0 else (row[K0 + 5] if slope == 1 else row[K0 + 8])
    ell = bb / j * t
    cached = ell == key
    if uncached:
        g1, g2 = phi12_given(ell, em1)
        e1, e2 = (e1 if cached else g1), (e2 if cached else g2)
    x_new, v_new = _affine_advance_by(x, v, a, j, t, ell, e1, e2)
    short = v_new > target if v > target else v_new < target
    reached = target == target and not short
    return a, bb, k, inner, target, us, uc, cached, x_new, v_new, reached, ell


@njit(cache=True, inline="always")
def _lane(
    x: float, v: float, c: float, due: float, h: float, delayed: bool, row: tuple[float, ...]
) -> tuple[float, float, float, float, float]:
    """Pass 1 for one plant at ``x``, ``v`` under the command ``c`` (``due``: after the dead time).

    Returns the new ``x`` and ``v``, the saturated command to record, and the values of
    ``S_FRICTION`` and ``S_STUCK``: a step without an event is finished; any other step keeps
    ``x`` and ``v`` and is marked ``PENDING`` with the command due now in ``S_FRICTION``.
    Scalars in and out, and conditional expressions only: the loop that inlines it compiles to
    SIMD code.
    """
    umax, stop = row[I_UMAX], row[I_STOP]
    us_pos, us_neg = row[F0 + friction_core.I_US_POS], row[F0 + friction_core.I_US_NEG]
    visc = row[F0 + friction_core.I_VISCOUS]
    eligible = row[I_LAG] == 0.0 and (
        row[F0 + friction_core.I_LAW] == friction_core.LAW_STATIC
        and (
            row[F0 + friction_core.I_SHAPE] == friction_core.SHAPE_LINEAR
            or row[F0 + friction_core.I_SHAPE] == friction_core.SHAPE_STEP
        )
    )
    c = min(max(c, -umax), umax)
    u = dead_zone(due if delayed else c, row[I_DEAD_ZONE])
    moving = v != 0.0
    s_rest = 1.0 if u > us_pos else (-1.0 if u < -us_neg else 0.0)
    s = (1.0 if v > 0.0 else -1.0) if moving else s_rest
    held = s == 0.0
    pressed = not moving and s > 0.0 and x >= stop
    phase = _slide(x, v, u, s, h, row, False, 0.0)
    _, _, k, inner, _, us, uc, cached, x_new, v_new, reached, _ = phase
    event = reached or x_new > stop
    pending = not eligible or (not held and (pressed or event or not cached))
    dx = x_new - x
    f = (0.0 + phase_impulse(inner, s, us, uc, k, h, dx) + visc * dx) / h
    keep = held or pending
    stuck = PENDING if pending else (1.0 if held or v_new == 0.0 else 0.0)
    return (x if keep else x_new), (v if keep else v_new), c, (u if keep else f), stuck


@njit(cache=True, inline="always")
def _row(params: npt.NDArray[np.float64], r: int) -> tuple[float, ...]:
    """Plant row ``r`` as a tuple (the fields :func:`_lane` reads)."""
    return (
        params[r, 0],
        params[r, 1],
        params[r, 2],
        params[r, 3],
        params[r, 4],
        params[r, 5],
        params[r, 6],
        params[r, 7],
        params[r, 8],
        params[r, 9],
        params[r, 10],
        params[r, 11],
        params[r, 12],
        params[r, 13],
        params[r, 14],
        params[r, 15],
        params[r, 16],
        params[r, 17],
        params[r, 18],
        params[r, 19],
        params[r, 20],
        params[r, 21],
        params[r, 22],
        params[r, 23],
        params[r, 24],
        params[r, 25],
    )


@njit(cache=True, inline="always")
def _lanes(
    lo: int,
    hi: int,
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    h: float,
    params: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    delayed: bool,
) -> None:
    """Run the loop of pass 1 (``delayed`` is a constant where it is inlined: no branches)."""
    row = _row(params, 0)
    # an unsigned index: numba then adds no wrap-around of negative indices, which would hide
    # from the compiler that the loop walks each column with unit stride
    for i in range(np.uint64(lo), np.uint64(hi)):
        skip = fresh[i]
        due = delay_buffer[head, i] if delayed else 0.0
        x, v, c, f, stuck = _lane(state[S_X, i], state[S_V, i], command[i], due, h, delayed, row)
        if not skip:
            state[S_X, i] = x
            state[S_V, i] = v
            state[S_COMMAND, i] = c
            state[S_FRICTION, i] = f
            state[S_STUCK, i] = stuck
            if delayed:
                delay_buffer[head, i] = c


@njit(cache=True, parallel=True, error_model="numpy")
def slide_lanes(
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    h: float,
    params: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    lo: int,
    hi: int,
) -> None:
    """Pass 1 over plants ``lo`` to ``hi - 1`` (those not ``fresh``).

    For a batch that shares one plant row (:func:`step_plants` checks it has the exact law and
    no lag); ``fresh`` has an entry per plant. One loop with a dead time and one without, so
    that neither branches inside. Compiled on its own with NumPy's error model: a division
    by zero gives inf instead of raising, so no branch keeps the loop out of SIMD code (every
    divisor here is a positive parameter). The state is indexed as one 2-D array, never through
    row views: the compiler then sees that the columns cannot overlap.
    """
    if delay_buffer.shape[0] > 0:
        _lanes(lo, hi, state, delay_buffer, head, command, h, params, fresh, True)
    else:
        _lanes(lo, hi, state, delay_buffer, head, command, h, params, fresh, False)


#: Rows of pass 1b's work array, an entry per pending plant of a block: its position, velocity
#: and command due; its first phase as :func:`_first_phase` returns it (booleans as 1.0 / 0.0;
#: ``W_LOG`` holds ``q`` where it is ``logged``, then ``log1p(q) / q``, else NaN); the
#: arguments of ``expm1`` that its two phases need, then their ``expm1(-l)`` (else NaN); its end
#: position, speed and friction, and 1.0 if pass 1b finished its step. One flat array of
#: ``WORK_ROWS`` rows of ``BLOCK`` entries: with a row offset the compiler knows, it proves the
#: rows apart, which it must before it runs a loop that writes many of them in SIMD lanes.
(
    W_X,
    W_V,
    W_U,
    W_MAYBE,
    W_LOG,
    W_NEVER,
    W_Q,
    W_NUM,
    W_DEN,
    W_A,
    W_BB,
    W_S,
    W_INNER,
    W_US,
    W_UC,
    W_K,
    W_TARGET,
    W_X_FULL,
    W_EM1_ONE,
    W_EM1_TWO,
    W_X_END,
    W_V_END,
    W_FRICTION,
    W_DONE,
) = range(24)
WORK_ROWS = 24


@njit(cache=True, inline="always")
def _first_phase(x: float, v: float, u: float, h: float, row: tuple[float, ...]) -> tuple[Any, ...]:
    """Read a pending plant's step as pass 1b would: its first phase, up to an event.

    Returns ``maybe``: whether the first phase (as
    :func:`~frictiongym.plants._kernel.exact_phase` finds it, with the row's cached coefficients
    for the full step) of a moving body reaches its target speed (rest, or the edge of the
    decay range); ``logged``: whether the time of it needs ``log1p(q) / q``; then ``never``,
    ``q``, ``num``, ``den`` (:func:`time_to_terms`), the phase's ``a``, ``bb``, ``s``,
    ``inner``, ``us``, ``uc``, ``k``, ``target`` and the position after the full step.
    """
    s = 1.0 if v > 0.0 else -1.0
    phase = _slide(x, v, u, s, h, row, False, 0.0)
    a, bb, k, inner, target, us, uc, cached, x_full, _, reached, _ = phase
    never, q, num, den = time_to_terms(v, target, a, bb)
    maybe = v != 0.0 and cached and reached
    logged = maybe and not never and not abs(q) < LOG_SERIES_LIMIT
    return maybe, logged, never, q, num, den, a, bb, s, inner, us, uc, k, target, x_full


@njit(cache=True, inline="always")
def _event_time(
    never: float, q: float, num: float, den: float, log_ratio: float, h: float, j: float
) -> tuple[bool, float]:
    """Whether the first phase's event comes ``early`` (before the step's end), and its length.

    From :func:`_first_phase`'s terms (``never`` as 1.0 / 0.0) and ``log1p(q) / q`` where it
    is ``logged``.
    """
    ratio = 1.0 - q / 2.0 if abs(q) < LOG_SERIES_LIMIT else log_ratio
    t_event = math.inf if never != 0.0 else j * num / den * ratio
    early = t_event < h  # else the body reaches the target speed at the end of the step
    return early, (t_event if early else h)


@njit(cache=True, inline="always")
def _expm1_arguments(
    u: float,
    bb: float,
    s: float,
    target: float,
    early: bool,
    dt: float,
    h: float,
    row: tuple[float, ...],
) -> tuple[float, float]:
    """Return the ``l`` of each phase of :func:`_event_lane` whose ``E1``, ``E2`` need ``expm1``.

    NaN where none is needed: a phase that does not happen, or whose ``|l| < SERIES_LIMIT``.
    """
    j = row[I_J]
    ell_one = bb / j * dt
    _, bb_two, _, _, _, _, _, _ = _setup(target, u, s, row)
    ell_two = bb_two / j * (h - dt)
    two = early and target != 0.0
    ell_one = ell_one if early and not abs(ell_one) < SERIES_LIMIT else math.nan
    ell_two = ell_two if two and not abs(ell_two) < SERIES_LIMIT else math.nan
    return ell_one, ell_two


@njit(cache=True, inline="always")
def _event_lane(
    x: float,
    v: float,
    u: float,
    first: tuple[float, float, float, float, float, float, float, float, float],
    early: bool,
    dt: float,
    em1_one: float,
    em1_two: float,
    h: float,
    row: tuple[float, ...],
) -> tuple[bool, float, float, float]:
    """Finish pass 1b for one plant: whether it could, and its end position, speed and friction.

    What :func:`advance_plant` computes for a step of two phases: up to a stop, then held at
    rest; or up to the edge of the decay range, then sliding on the other range to the end of
    the step. Without branches; ``first`` is the first phase (``a``, ``bb``, ``s``, ``inner``,
    ``us``, ``uc``, ``k``, ``target``, the position after the full step), ``early`` and ``dt``
    its event (:func:`_event_time`), ``em1_one`` and ``em1_two`` the ``expm1(-l)`` of each phase
    where :func:`_expm1_arguments` asks for one. A second event, a break-away after the stop or
    a contact with the end stop is left to the element step.
    """
    a, bb, s, inner_flag, us, uc, k, target, x_full = first
    inner = inner_flag != 0.0
    j, stop = row[I_J], row[I_STOP]
    ell_one = bb / j * dt
    e1, e2 = phi12_given(ell_one, em1_one)
    x_event, _ = _affine_advance_by(x, v, a, j, dt, ell_one, e1, e2)
    x_one = x_event if early else x_full
    impulse = phase_impulse(inner, s, us, uc, k, dt, x_one - x)
    # The rest of the step after an early event: held at rest (u * time: static friction
    # balances the command), or sliding from the edge of the decay range on the other range.
    t_rest = h - dt
    held = not u > row[F0 + friction_core.I_US_POS] and not u < -row[F0 + friction_core.I_US_NEG]
    phase = _slide(x_one, target, u, s, t_rest, row, True, em1_two)
    _, _, k_two, inner_two, _, _, _, _, x_two, v_two, reached_two, _ = phase
    stopped = target == 0.0
    slid = not reached_two and not x_two > stop
    rest = (
        u * t_rest if stopped else phase_impulse(inner_two, s, us, uc, k_two, t_rest, x_two - x_one)
    )
    two = early and not stopped
    x_end, v_end = (x_two if two else x_one), (v_two if two else target)
    impulse = (0.0 + impulse) + rest if early else impulse
    f = ((0.0 + impulse) + row[F0 + friction_core.I_VISCOUS] * (x_end - x)) / h
    done = not x_one > stop and (not early or (held if stopped else slid))
    return done, x_end, v_end, f


@njit(cache=True, parallel=True, error_model="numpy")
def two_phase_lanes(
    state: npt.NDArray[np.float64],
    h: float,
    params: npt.NDArray[np.float64],
    index: npt.NDArray[np.int64],
    pending: int,
    work: npt.NDArray[np.float64],
) -> None:
    """Pass 1b: finish the pending steps of two phases (plants ``index[:pending]``).

    Of the steps pass 1 leaves pending, most are a body coming to rest within the step under a
    command that then holds it, or a body crossing the edge of the decay range (see
    :func:`_event_lane`). Their arithmetic runs here in SIMD lanes over the pending plants,
    gathered into ``work`` (a column each), but for the calls of ``log1p`` and ``expm1``, in
    scalar loops of their own; the others stay pending for the element step. Compiled as
    :func:`slide_lanes`.
    """
    row = _row(params, 0)
    for m in range(pending):
        i = index[m]
        work[W_X * BLOCK + m] = state[S_X, i]
        work[W_V * BLOCK + m] = state[S_V, i]
        work[W_U * BLOCK + m] = state[S_FRICTION, i]  # the command due, as pass 1 leaves it
    padded = (pending + LANE_GROUP - 1) // LANE_GROUP * LANE_GROUP  # <= BLOCK, a multiple
    for m in range(pending, padded):  # a body at rest under no command: never finished here
        work[W_X * BLOCK + m] = 0.0
        work[W_V * BLOCK + m] = 0.0
        work[W_U * BLOCK + m] = 0.0
    n = np.uint64(padded)  # unsigned: no wrap-around of negative indices (SIMD code)
    for m in range(n):
        first = _first_phase(
            work[W_X * BLOCK + m], work[W_V * BLOCK + m], work[W_U * BLOCK + m], h, row
        )
        maybe, logged, never, q, num, den, a, bb, s, inner, us, uc, k, target, x_full = first
        work[W_MAYBE * BLOCK + m] = 1.0 if maybe else 0.0
        work[W_LOG * BLOCK + m] = q if logged else math.nan
        work[W_NEVER * BLOCK + m] = 1.0 if never else 0.0
        work[W_Q * BLOCK + m], work[W_NUM * BLOCK + m], work[W_DEN * BLOCK + m] = q, num, den
        work[W_A * BLOCK + m], work[W_BB * BLOCK + m], work[W_S * BLOCK + m] = a, bb, s
        work[W_INNER * BLOCK + m] = 1.0 if inner else 0.0
        work[W_US * BLOCK + m], work[W_UC * BLOCK + m], work[W_K * BLOCK + m] = us, uc, k
        work[W_TARGET * BLOCK + m], work[W_X_FULL * BLOCK + m] = target, x_full
    for m in range(pending):
        q = work[W_LOG * BLOCK + m]
        if q == q:
            work[W_LOG * BLOCK + m] = math.log1p(q) / q
    for m in range(n):
        never, q, num, den = (
            work[W_NEVER * BLOCK + m],
            work[W_Q * BLOCK + m],
            work[W_NUM * BLOCK + m],
            work[W_DEN * BLOCK + m],
        )
        early, dt = _event_time(never, q, num, den, work[W_LOG * BLOCK + m], h, row[I_J])
        u, bb, s, target = (
            work[W_U * BLOCK + m],
            work[W_BB * BLOCK + m],
            work[W_S * BLOCK + m],
            work[W_TARGET * BLOCK + m],
        )
        ells = _expm1_arguments(u, bb, s, target, early, dt, h, row)
        work[W_EM1_ONE * BLOCK + m], work[W_EM1_TWO * BLOCK + m] = ells
    for m in range(pending):
        for w in (W_EM1_ONE, W_EM1_TWO):
            ell = work[w * BLOCK + m]
            if ell == ell:
                work[w * BLOCK + m] = math.expm1(-ell)
    for m in range(n):
        never, q, num, den = (
            work[W_NEVER * BLOCK + m],
            work[W_Q * BLOCK + m],
            work[W_NUM * BLOCK + m],
            work[W_DEN * BLOCK + m],
        )
        early, dt = _event_time(never, q, num, den, work[W_LOG * BLOCK + m], h, row[I_J])
        first = (
            work[W_A * BLOCK + m],
            work[W_BB * BLOCK + m],
            work[W_S * BLOCK + m],
            work[W_INNER * BLOCK + m],
            work[W_US * BLOCK + m],
            work[W_UC * BLOCK + m],
            work[W_K * BLOCK + m],
            work[W_TARGET * BLOCK + m],
            work[W_X_FULL * BLOCK + m],
        )
        em1_one, em1_two = work[W_EM1_ONE * BLOCK + m], work[W_EM1_TWO * BLOCK + m]
        x, v, u = work[W_X * BLOCK + m], work[W_V * BLOCK + m], work[W_U * BLOCK + m]
        done, x_end, v_end, f = _event_lane(x, v, u, first, early, dt, em1_one, em1_two, h, row)
        work[W_X_END * BLOCK + m] = x_end
        work[W_V_END * BLOCK + m] = v_end
        work[W_FRICTION * BLOCK + m] = f
        work[W_DONE * BLOCK + m] = 1.0 if done and work[W_MAYBE * BLOCK + m] != 0.0 else 0.0
    for m in range(pending):
        if work[W_DONE * BLOCK + m] != 0.0:
            i = index[m]
            state[S_X, i] = work[W_X_END * BLOCK + m]
            state[S_V, i] = work[W_V_END * BLOCK + m]
            state[S_FRICTION, i] = work[W_FRICTION * BLOCK + m]
            state[S_STUCK, i] = 1.0 if work[W_V_END * BLOCK + m] == 0.0 else 0.0


@njit(cache=True)
def step_plants(
    lo: int,
    hi: int,
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    h: float,
    n_sub: int,
    params: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
) -> None:
    """Step plants ``lo`` to ``hi - 1``, those not ``fresh`` (an entry per plant).

    ``command`` holds one command per plant, or one for all. Compiled once and called per
    block, not inlined into each batch kernel: four inlined copies of the element step took
    minutes to compile. Pass 1 runs for a block of ``LANES_MIN`` plants or more that share a
    row of the exact law without lag, with one command per plant; other batches (own rows: the
    compiler cannot prove their loop safe for SIMD code anyway) take the element step for every
    plant.
    """
    one_row, one_command = params.shape[0] == 1, command.shape[0] == 1
    delayed = delay_buffer.shape[0] > 0
    lanes = (
        hi - lo >= LANES_MIN  # a few plants gain nothing from the pass, and pay its calls
        and n_sub == 1
        and one_row
        and not (one_command and state.shape[1] > 1)
        and params[0, I_LAG] == 0.0
        and params[0, I_GAP] == 0.0
        and params[0, I_JITTER] == 0.0
        and has_exact_step(params[0, F0:K0])
    )
    if lanes:
        _step_lanes(lo, hi, state, delay_buffer, head, command, h, params, fresh)
        return
    for i in range(lo, hi):  # the element step for every plant
        if not fresh[i]:
            c = command[0 if one_command else i]
            r = 0 if one_row else i
            width = params[r, I_DEAD_ZONE]
            u = apply_command(i, state, delay_buffer, head, c, params[r, I_UMAX], width, delayed)
            advance_plant(i, state, u, h, n_sub, params, one_row)


@njit(cache=True)
def _step_lanes(
    lo: int,
    hi: int,
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    h: float,
    params: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
) -> None:
    """Run passes 1, 1b and 2 over plants ``lo`` to ``hi - 1`` (see :func:`step_plants`).

    A function of its own, so that a batch without the passes (a single env) allocates nothing.
    """
    slide_lanes(state, delay_buffer, head, command, h, params, fresh, lo, hi)
    index = np.empty(hi - lo, dtype=np.int64)
    pending = 0
    for i in range(lo, hi):  # pass 1 never leaves a fresh plant pending
        index[pending] = i  # kept if pending: no branch to mispredict
        pending += state[S_STUCK, i] == PENDING
    two_phase_lanes(state, h, params, index, pending, np.empty(WORK_ROWS * BLOCK))
    for m in range(pending):  # pass 2: the element step
        i = index[m]
        if state[S_STUCK, i] == PENDING:  # else pass 1b finished it
            advance_plant(i, state, state[S_FRICTION, i], h, 1, params, True)


@njit(cache=True)
def none_fresh(n: int) -> npt.NDArray[np.bool_]:
    """Return a mask of ``n`` plants none of which is fresh.

    Not ``np.zeros``: in a kernel compiled with ``parallel=True`` that is a parallel loop, so
    every call of even the serial kernel would wake numba's thread pool (one plant stepped
    18x slower with a core busy; docs/benchmarks.md, "Fourth round").
    """
    mask = np.empty(n, dtype=np.bool_)
    for i in range(n):
        mask[i] = False
    return mask


@serial_njit
def step_batch(
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    h: float,
    n_sub: int,
    params: npt.NDArray[np.float64],
) -> int:
    """Step N plants in place.

    Parameters
    ----------
    state : ndarray, shape (STATE_SIZE, N)
        Plant states, updated in place.
    delay_buffer : ndarray, shape (D, N)
        Commands in flight for a dead time of D control periods (D may be 0).
    head : int
        Slot of ``delay_buffer`` holding the command that is due now.
    command : ndarray, shape (N,) or (1,)
        Commands (broadcast if of length 1).
    h : float
        Control period.
    n_sub : int
        Substeps per control period.
    params : ndarray, shape (N, ROW_SIZE) or (1, ROW_SIZE), ``ROW_SIZE`` of :mod:`._kernel`
        Plant rows (broadcast if one row).

    Returns
    -------
    int
        -1 on success; otherwise the index of the first non-finite command, in which case
        no state was changed.
    """
    bad = first_non_finite(command)
    if bad >= 0:
        return bad
    n = state.shape[1]
    no_one = none_fresh(n)
    for block in range((n + BLOCK - 1) // BLOCK):
        lo = block * BLOCK
        step_plants(
            lo, min(lo + BLOCK, n), state, delay_buffer, head, command, h, n_sub, params, no_one
        )
    return -1


@njit(cache=True, parallel=True)
def step_batch_parallel(
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    h: float,
    n_sub: int,
    params: npt.NDArray[np.float64],
) -> int:
    """:func:`step_batch` with the blocks spread over numba's threads (bit-identical results)."""
    bad = first_non_finite(command)
    if bad >= 0:
        return bad
    n = state.shape[1]
    no_one = none_fresh(n)
    for block in prange((n + BLOCK - 1) // BLOCK):
        lo = np.int64(block) * BLOCK  # prange's index is unsigned; index with signed integers
        step_plants(
            lo, min(lo + BLOCK, n), state, delay_buffer, head, command, h, n_sub, params, no_one
        )
    return -1
