"""Backlash between motor and load: the two-body event-exact step.

The plant's inertia ``J``, damping ``B`` and friction law are split between a motor (driven by
the input) and a load (what the sensor measures), joined through a play of width ``2 g``. The
state adds to the plant's the gap ``d = x_motor - x_load`` in ``[-g, g]`` and the motor's
velocity. Three modes (docs/physics.md, "Backlash"):

* **free** (inside the play): each body follows the one-body stick/slip law of
  :func:`~frictiongym.plants._kernel.exact_phase` with its share of the law, the motor under
  the input, the load under none, until the gap reaches a face;
* **impact** at a face: perfectly inelastic, both bodies take the momentum average;
* **engaged** at face ``sigma``: the pair moves as one body with the whole law, as the plant
  without backlash does, while the contact force on the load,
  ``F = psi u + (phi - psi) (f(v) + b v)`` (``psi``, ``phi``: the load's shares of inertia and
  friction), pushes (``sigma F >= 0``); the bodies separate the instant it would pull.

Every event (a body's stop or range change, a contact, a separation) is located inside the
step: a contact by a bracketed root search on the gap's closed form, split where the bodies'
relative velocity turns, so the gap is monotone on each piece searched. Only the static law
with a ``step`` or ``linear`` decay has this step; the plant refuses backlash with another law.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit

from frictiongym.friction import _core as friction_core
from frictiongym.plants._kernel import (
    I_B,
    I_J,
    I_LAG,
    I_STOP,
    S_FRICTION,
    S_GAP,
    S_LAG,
    S_MOTOR_V,
    S_STUCK,
    S_V,
    S_X,
    Row,
    affine_advance,
    affine_time_to,
    breakaway_direction,
    direction_levels,
    exact_phase,
    held_at_stop,
    lagged,
    phase_impulse,
    sliding_setup,
)

#: Phases per substep at most: each ends at an event or at the substep's end.
MAX_PHASES = 64
#: An empty coefficient cache (a side's law has no cached coefficients: NaN keys never match).
_NO_CACHE = (math.nan,) * 9
#: Root searches stop when the bracket is this tight relative to its upper end (or stalls).
_BRACKET = 4e-16


@njit(cache=True)
def _phase(
    x: float,
    v: float,
    u: float,
    t_left: float,
    j: float,
    b_total: float,
    p: Row,
    stop: float,
    cache: Row,
) -> tuple[float, float, float, float]:
    """:func:`exact_phase`, compiled once for this module's six calls (not inlined in each)."""
    return exact_phase(x, v, u, t_left, j, b_total, p, stop, cache)


@njit(cache=True, inline="always")
def side_row(p: Row, share: float) -> Row:
    """Return the friction row of one side: its levels and viscous slope times ``share``."""
    return (
        p[friction_core.I_LAW],
        p[friction_core.I_SHAPE],
        share * p[friction_core.I_US_POS],
        share * p[friction_core.I_US_NEG],
        share * p[friction_core.I_UC_POS],
        share * p[friction_core.I_UC_NEG],
        p[friction_core.I_V0_POS],
        p[friction_core.I_V0_NEG],
        share * p[friction_core.I_VISCOUS],
        p[friction_core.I_SIGMA0],
        p[friction_core.I_SIGMA1],
    )


@njit(cache=True, inline="always")
def body_law(
    x: float, v: float, u: float, b_total: float, p: Row, stop: float
) -> tuple[float, float]:
    """Return ``a, b`` of the law ``j v' = a - b v`` that a body at ``(x, v)`` follows under ``u``.

    ``(0.0, 0.0)`` for a body held at rest, as :func:`exact_phase` decides it.
    """
    if v == 0.0:
        s = breakaway_direction(u, p)
        if s == 0.0 or held_at_stop(x, s, stop):
            return 0.0, 0.0
    else:
        s = 1.0 if v > 0.0 else -1.0
    us, uc, v0 = direction_levels(s, p)
    linear = p[friction_core.I_SHAPE] == friction_core.SHAPE_LINEAR
    a, bb, _, _, _, _ = sliding_setup(v, u, s, b_total, us, uc, v0, linear)
    return a, bb


@njit(cache=True, inline="always")
def _relative(t: float, d: float, motor: Row, load: Row) -> tuple[float, float]:
    """Return the gap and the relative velocity at ``t``; a body is ``(v, a, b, j)``."""
    dxm, vm = affine_advance(0.0, motor[0], motor[1], motor[2], motor[3], t)
    dxl, vl = affine_advance(0.0, load[0], load[1], load[2], load[3], t)
    return d + (dxm - dxl), vm - vl


@njit(cache=True)
def _root(lo: float, hi: float, d: float, motor: Row, load: Row, gap: bool, target: float) -> float:
    """First time in ``[lo, hi]`` at which a monotone function reaches ``target`` (bracketed).

    The function is the gap (``gap``) or the relative velocity; it lies on one side of
    ``target`` at ``lo`` and on the other or on it at ``hi``. Regula falsi (Illinois), with
    bisection when it stalls; returns the bracket's end on the far side.
    """
    f_lo = _relative(lo, d, motor, load)[0 if gap else 1] - target
    f_hi = _relative(hi, d, motor, load)[0 if gap else 1] - target
    side = 1.0 if f_lo < 0.0 else -1.0  # the sign of the function's change over the bracket
    for _ in range(200):
        if f_hi == 0.0 or hi - lo <= _BRACKET * hi:
            break
        t = hi - f_hi * (hi - lo) / (f_hi - f_lo)
        if not lo < t < hi:
            t = 0.5 * (lo + hi)
        if t == lo or t == hi:
            break
        f = _relative(t, d, motor, load)[0 if gap else 1] - target
        if side * f >= 0.0:
            hi, f_hi = t, f
            f_lo *= 0.5  # Illinois: keep the stale end from stalling the secant
        else:
            lo, f_lo = t, f
            f_hi *= 0.5
    return hi


@njit(cache=True)
def _crossing(
    t0: float, t1: float, d: float, g: float, motor: Row, load: Row
) -> tuple[float, float]:
    """First contact on ``[t0, t1]``, over which the gap is monotone: its time and face.

    ``(inf, 0.0)`` if none. A gap that starts on a face (or past it, by rounding) and moves
    into it is a contact at ``t0``.
    """
    d0 = _relative(t0, d, motor, load)[0]
    d1 = _relative(t1, d, motor, load)[0]
    for sigma in (1.0, -1.0):
        face = sigma * g
        if sigma * d1 >= g and sigma * d0 < g:
            return _root(t0, t1, d, motor, load, True, face), sigma
        if sigma * d0 >= g and sigma * d1 > sigma * d0:  # on (or past) the face, moving in
            return t0, sigma
    return math.inf, 0.0


@njit(cache=True)
def contact_time(d: float, g: float, motor: Row, load: Row, t_end: float) -> tuple[float, float]:
    """First time in ``[0, t_end]`` at which the gap reaches a face, and the face (+1 or -1).

    ``(inf, 0.0)`` if it stays inside the play. Each body follows one affine law over the
    interval (``motor``, ``load``: ``(v, a, b, j)``), so its acceleration is
    ``acc0 e^(-b t / j)``: the relative velocity has at most one turning point (in closed
    form) and a zero on each side of it, so the gap is monotone between those times.
    """
    acc_m = (motor[1] - motor[2] * motor[0]) / motor[3]
    acc_l = (load[1] - load[2] * load[0]) / load[3]
    rate_m, rate_l = motor[2] / motor[3], load[2] / load[3]
    turn = math.nan
    if acc_m * acc_l > 0.0 and rate_m != rate_l:
        turn = math.log(acc_m / acc_l) / (rate_m - rate_l)
    if not 0.0 < turn < t_end:
        turn = t_end
    lo = 0.0
    for hi in (turn, t_end):  # the relative velocity is monotone on [lo, hi]
        if hi <= lo:
            continue
        w_lo = _relative(lo, d, motor, load)[1]
        w_hi = _relative(hi, d, motor, load)[1]
        mid = hi
        if w_lo * w_hi < 0.0:
            mid = _root(lo, hi, d, motor, load, False, 0.0)
        for a, b in ((lo, mid), (mid, hi)):
            if b > a:
                tau, sigma = _crossing(a, b, d, g, motor, load)
                if sigma != 0.0:
                    return tau, sigma
        lo = hi
    return math.inf, 0.0


@njit(cache=True)
def free_phase(
    x: float,
    v: float,
    d: float,
    vm: float,
    u: float,
    t_left: float,
    g: float,
    sides: Row,
    pm: Row,
    pl: Row,
    stop: float,
) -> tuple[float, float, float, float, float, float, bool]:
    """Both bodies on their own, up to the first event of either or a contact.

    ``sides`` is ``(j_motor, b_motor, j_load, b_load)``. Returns ``x, v, d, vm``, the phase's
    length, the friction impulse of both bodies, and whether it ended in a contact (then the
    pair is engaged: ``d`` on the face, both at the momentum average).
    """
    jm, bm, jl, bl = sides
    inf = math.inf
    dxm, vm1, dt_m, imp_m = _phase(0.0, vm, u, t_left, jm, bm, pm, inf, _NO_CACHE)
    xl, vl, dt_l, imp_l = _phase(x, v, 0.0, t_left, jl, bl, pl, stop, _NO_CACHE)
    dt = min(dt_m, dt_l)
    am, bbm = body_law(0.0, vm, u, bm, pm, inf)
    al, bbl = body_law(x, v, 0.0, bl, pl, stop)
    tau, sigma = contact_time(d, g, (vm, am, bbm, jm), (v, al, bbl, jl), dt)
    if tau <= dt:
        dt = tau
    if dt_m != dt:
        dxm, vm1, _, imp_m = _phase(0.0, vm, u, dt, jm, bm, pm, inf, _NO_CACHE)
    if dt_l != dt:
        xl, vl, _, imp_l = _phase(x, v, 0.0, dt, jl, bl, pl, stop, _NO_CACHE)
    impulse = imp_m + imp_l
    if sigma == 0.0:  # no contact: the gap stays in the play whatever the rounding says
        # (xl - x) is rounded to the spacing of floats at x, the search's displacement is not
        return xl, vl, min(max(d + (dxm - (xl - x)), -g), g), vm1, dt, impulse, False
    common = vl if vm1 == vl else (jm * vm1 + jl * vl) / (jm + jl)  # inelastic impact
    if xl >= stop and common > 0.0:
        common = 0.0  # the load is against the end stop: the stop takes the motor's momentum
    return xl, common, sigma * g, common, dt, impulse, True


@njit(cache=True)
def engaged_phase(
    x: float,
    v: float,
    sigma: float,
    u: float,
    t_left: float,
    j: float,
    b_total: float,
    p: Row,
    pm: Row,
    stop: float,
    cache: Row,
    shares: tuple[float, float],
    check: bool,
) -> tuple[float, float, float, float, bool]:
    """Move the pair engaged on face ``sigma`` as one body, up to an event or a separation.

    ``pm`` is the motor's share of the law, ``shares`` the load's of inertia and friction;
    ``check`` is False to keep the contact for this phase whatever the contact force's
    rounding says (a pair that just separated and touched again at the same instant). Returns
    ``x, v``, the phase's length, the friction impulse and whether the pair is still engaged.
    """
    psi, phi = shares
    if v == 0.0:
        s = breakaway_direction(u, p)
        if s != sigma or held_at_stop(x, s, stop):
            if breakaway_direction(u, pm) == -sigma:
                return x, v, 0.0, 0.0, False  # the motor leaves the face; the load stays
            x1, v1, dt, imp = _phase(x, v, u, t_left, j, b_total, p, stop, cache)
            return x1, v1, dt, imp, True  # held
    x1, v1, dt, imp = _phase(x, v, u, t_left, j, b_total, p, stop, cache)
    if not check:
        return x1, v1, dt, imp, True
    s = sigma if v == 0.0 else (1.0 if v > 0.0 else -1.0)
    us, uc, v0 = direction_levels(s, p)
    linear = p[friction_core.I_SHAPE] == friction_core.SHAPE_LINEAR
    a, bb, k, inner, _, _ = sliding_setup(v, u, s, b_total, us, uc, v0, linear)
    # contact force F(w) = psi u + (phi - psi) (f(w) + b w), with f(w) + b w = (u - a) + bb w
    c = phi - psi
    force = psi * u + c * ((u - a) + bb * v)
    if sigma * force < 0.0:
        return x, v, 0.0, 0.0, False
    _, v_end = affine_advance(0.0, v, a, bb, j, dt)
    if sigma * (force + c * bb * (v_end - v)) >= 0.0:
        return x1, v1, dt, imp, True
    # F is affine in the velocity, which is monotone over the phase: it turns at one speed
    t_sep = min(affine_time_to(v, v - force / (c * bb), a, bb, j), dt)
    x2, v2 = affine_advance(x, v, a, bb, j, t_sep)
    return x2, v2, t_sep, phase_impulse(inner, s, us, uc, k, t_sep, x2 - x), False


@njit(cache=True)
def backlash_substep(
    x: float,
    v: float,
    d: float,
    vm: float,
    u: float,
    hs: float,
    j: float,
    b_total: float,
    p: Row,
    stop: float,
    cache: Row,
    drivetrain: tuple[float, float, float],
) -> tuple[float, float, float, float, float]:
    """Advance the pair by ``hs`` under ``u``; ``drivetrain`` is ``(g, psi, phi)``.

    Returns ``x, v, d, vm`` and the friction impulse of both bodies (the laws' viscous parts
    left out, as :func:`exact_static`'s).
    """
    g, psi, phi = drivetrain
    jl = psi * j
    sides = (j - jl, (1.0 - phi) * b_total, jl, phi * b_total)
    pm, pl = side_row(p, 1.0 - phi), side_row(p, phi)
    engaged = (d == g or d == -g) and vm == v
    check, separated_now = True, False
    impulse = 0.0
    t_left = hs
    for _ in range(MAX_PHASES):
        if t_left <= 0.0:
            break
        if engaged:
            sigma = 1.0 if d > 0.0 else -1.0
            x, v, dt, imp, engaged = engaged_phase(
                x, v, sigma, u, t_left, j, b_total, p, pm, stop, cache, (psi, phi), check
            )
            vm = v
            check, separated_now = True, not engaged and dt == 0.0
        else:
            x, v, d, vm, dt, imp, engaged = free_phase(
                x, v, d, vm, u, t_left, g, sides, pm, pl, stop
            )
            # touched again the instant it separated: F is zero to rounding; keep the contact
            check = not (engaged and dt == 0.0 and separated_now)
            separated_now = False
        impulse += imp
        t_left -= dt
    return x, v, d, vm, impulse


@njit(cache=True)
def backlash_advance(
    x: float,
    v: float,
    d: float,
    vm: float,
    y: float,
    u: float,
    h: float,
    n_sub: int,
    plant: Row,
    friction: Row,
    cache: Row,
    drivetrain: tuple[float, float, float],
) -> tuple[float, float, float, float, float, float]:
    """:func:`~frictiongym.plants._kernel.advance` of a plant with backlash.

    Parameters as ``advance``, and the gap ``d``, the motor's velocity ``vm``, and
    ``drivetrain = (g, psi, phi)`` (half play, the load's shares of inertia and of friction).
    Returns ``x, v, d, vm, y`` and the friction force of both bodies averaged over the step.
    """
    j = plant[I_J]
    visc = friction[friction_core.I_VISCOUS]
    b_total = plant[I_B] + visc
    x0, d0 = x, d
    hs = h / n_sub
    impulse = 0.0
    for _ in range(n_sub):
        force, y = lagged(u, y, hs, plant[I_LAG])
        x, v, d, vm, imp = backlash_substep(
            x, v, d, vm, force, hs, j, b_total, friction, plant[I_STOP], cache, drivetrain
        )
        impulse += imp
    # the laws' viscous parts: each body's share over its own travel
    travel = (x - x0) + (1.0 - drivetrain[2]) * (d - d0)
    return x, v, d, vm, y, (impulse + visc * travel) / h


@njit(cache=True)
def step_backlash(
    i: int,
    state: npt.NDArray[np.float64],
    u: float,
    h: float,
    n_sub: int,
    plant: Row,
    friction: Row,
    cache: Row,
    drivetrain: tuple[float, float, float],
) -> None:
    """Step plant ``i`` of a batch, which has backlash, under the drive ``u`` due now."""
    x, v, d, vm, y, f = backlash_advance(
        state[S_X, i],
        state[S_V, i],
        state[S_GAP, i],
        state[S_MOTOR_V, i],
        state[S_LAG, i],
        u,
        h,
        n_sub,
        plant,
        friction,
        cache,
        drivetrain,
    )
    state[S_X, i] = x
    state[S_V, i] = v
    state[S_GAP, i] = d
    state[S_MOTOR_V, i] = vm
    state[S_LAG, i] = y
    state[S_FRICTION, i] = f
    state[S_STUCK, i] = 1.0 if v == 0.0 and vm == 0.0 else 0.0
