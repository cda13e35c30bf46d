"""Compiled zero-order-hold step of ``J x'' + B x' = u - F(x', u)`` with true stick/slip.

One element function, :func:`advance`, steps one plant over one control period; the batch
kernels :func:`step_batch` (serial) and :func:`step_batch_parallel` (numba threads) loop it
over N plants. Every caller goes through them, so a plant stepped alone and inside a batch,
serially or in parallel, follows a bit-identical trajectory.

Integrators (docs/physics.md):

* **Exact** (static law with a ``step`` or ``linear`` decay, which covers none and
  Coulomb): friction is affine in ``v`` on each of at most two speed ranges, so each
  sliding phase has a closed form. Velocity is monotone within a phase (a 1-D autonomous
  ODE), so a step holds at most four events (leave the decay range, stop, break away the
  other way, enter the Coulomb range), each located exactly in time. A body stays
  *bit-exactly* at rest while the input lies in the break-away band.
* **Split** (``smooth`` and ``exponential`` decays): sub-stepped, implicit in the viscous
  term, with the zero crossing located by linear interpolation inside the substep, then
  the stick-or-reverse test (first order in the substep).
* **LuGre**: bristle state advanced by its exact exponential update at frozen velocity,
  mechanics semi-implicit, sub-stepped.

The input is held over the step (ZOH). An optional first-order actuator lag is applied per
substep by holding the lag output at its exact substep average.

An optional rigid **end stop** (the Altino's wall) bounds the position from above. Contact is
inelastic: the body stops at the stop (``x`` lands on it exactly, ``v = 0.0``) and stays
there while the input pushes it on, its friction at the break-away level and the stop taking
the rest. The exact integrator locates the contact inside the step like any other event; the
sub-stepped ones by linear interpolation inside the substep, as they locate stops.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import numpy.typing as npt
from numba import njit
from numba.core.errors import NumbaPerformanceWarning

from frictiongym.friction import _core as friction_core

#: Decorator of the serial batch loops: ``parallel=True`` over a plain ``range``: they start
#: no threads, but numba's parallel pipeline drops the reference counting that the plain
#: pipeline keeps for every array argument of the inlined element function (1.3x faster per
#: plant here, 3x per env in the env kernel; docs/benchmarks.md). Numba then warns that nothing
#: was parallelised, which is the point.
serial_njit = njit(cache=True, parallel=True)
warnings.filterwarnings(
    "ignore",
    message=r"(?s).*The keyword argument 'parallel=True' was specified but no transformation",
    category=NumbaPerformanceWarning,
)


# Plant row: [J, B, u_max, lag, end stop, dead zone] followed by the friction row.
I_J = 0
I_B = 1
I_UMAX = 2
I_LAG = 3
I_STOP = 4  #: position of the rigid end stop ahead (inf: none)
I_DEAD_ZONE = 5  #: half-width of the command's dead zone (0: none), command units
F0 = 6  #: offset of the friction row inside a plant row
#: Offset of the exact step's coefficient cache: for each slope b of the static law (the Coulomb
#: range's, then the decay range's forward and backward), the key ``l = b / J * h`` of a full
#: substep ``h`` and ``E1(l)``, ``E2(l)`` (:func:`_phi12`). A phase uses the cached values only
#: when its own ``l`` equals the key, so a stale or unprimed cache (NaN keys) costs speed, never
#: accuracy; :func:`prime_rows` fills it.
K0 = F0 + friction_core.ROW_SIZE
CACHE_SLOPES = 3
#: Backlash between motor and load, after the cache (a field the fast passes never read):
I_GAP = K0 + 3 * CACHE_SLOPES  #: half the play, position units (0: a rigid drivetrain)
I_LOAD_INERTIA = I_GAP + 1  #: the load's share of J (the motor has the rest)
I_LOAD_FRICTION = I_GAP + 2  #: the load's share of the friction law and of B
I_JITTER = I_GAP + 3  #: the largest extra latency of a new drive, s (0: none)
ROW_SIZE = I_GAP + 4
if friction_core.ROW_SIZE != 11:  # step_batch unpacks the friction row by hand
    raise ImportError("frictiongym.plants._kernel.step_batch must unpack every friction field")

# State columns.
S_X = 0  #: position
S_V = 1  #: velocity (exactly 0.0 while stuck)
S_Z = 2  #: LuGre bristle deflection
S_LAG = 3  #: actuator-lag output
S_FRICTION = 4  #: friction force averaged over the last step (nonlinear + viscous part of the law)
S_COMMAND = 5  #: last command after saturation
S_STUCK = 6  #: 1.0 if the body ended the last step stuck
S_GAP = 7  #: backlash: the motor's offset from the middle of the play (0.0 without backlash)
S_MOTOR_V = 8  #: backlash: the motor's velocity (equal to S_V while engaged)
S_DRIVE = 9  #: jitter: the drive in effect at the end of the last step
S_JITTER_RNG = 10  #: jitter: the generator's state, a 52-bit integer held exactly
STATE_SIZE = 11
#: The state columns by what they hold, for the plant's named accessors.
COLUMNS = {
    "position": S_X,
    "velocity": S_V,
    "bristle": S_Z,
    "lag": S_LAG,
    "friction_force": S_FRICTION,
    "command": S_COMMAND,
    "stuck": S_STUCK,
    "gap": S_GAP,
    "motor_velocity": S_MOTOR_V,
    "drive": S_DRIVE,
    "jitter_rng": S_JITTER_RNG,
}


def pack_row(
    plant: tuple[float, ...],
    friction: npt.NDArray[np.float64],
    backlash: tuple[float, float, float] = (0.0, 1.0, 1.0),
    jitter: float = 0.0,
) -> npt.NDArray[np.float64]:
    """Return a plant row.

    The row holds ``(J, B, u_max, lag, end stop, dead zone)``, the friction row, the coefficient
    cache, then ``backlash``: ``(half play, load's share of J, load's share of friction and B)``
    and the ``jitter`` of the drive's latency.
    """
    cache = np.full(I_GAP - K0, np.nan)
    return np.concatenate((plant, friction, cache, backlash, (jitter,)))


def end_stops(rows: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Return the end stop of each plant row (a view)."""
    return rows[:, I_STOP]


def scale_row(
    row: npt.NDArray[np.float64],
    friction: float,
    inertia: float,
    damping: float,
    dead_zone: float = 1.0,
    backlash: float = 1.0,
) -> npt.NDArray[np.float64]:
    """Return a plant row with its friction levels, J, damping (B, viscous), zone, play scaled."""
    scaled = row.copy()
    levels = [
        F0 + i
        for i in (
            friction_core.I_US_POS,
            friction_core.I_US_NEG,
            friction_core.I_UC_POS,
            friction_core.I_UC_NEG,
        )
    ]
    scaled[levels] *= friction
    scaled[I_J] *= inertia
    scaled[[I_B, F0 + friction_core.I_VISCOUS]] *= damping
    scaled[I_DEAD_ZONE] *= dead_zone
    scaled[I_GAP] *= backlash
    scaled[K0:I_GAP] = np.nan  # the cache no longer matches (prime_rows refills it)
    return scaled


@njit(cache=True)
def reset_plants(
    mask: npt.NDArray[np.bool_],
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    position: npt.NDArray[np.float64],
    velocity: npt.NDArray[np.float64],
) -> None:
    """Put the plants of ``mask`` at rest-or-moving starts (k-th masked one: ``position[k]``).

    The rest of their state (a task's columns too) and their commands in flight are zeroed; a
    velocity of exactly 0.0 starts a plant stuck. ``position`` and ``velocity`` hold an entry
    per masked plant, or one for all.
    """
    reset_selected(selected(mask), state, delay_buffer, position, velocity)


@njit(cache=True)
def selected(mask: npt.NDArray[np.bool_]) -> npt.NDArray[np.int64]:
    """Return the indices of ``mask``'s set entries, in order.

    It reads 8 entries at once and skips words with none set: a reset selects few of many.
    """
    n = mask.shape[0]
    words = n // 8
    chunks = mask[: words * 8].view(np.uint64)
    index = np.empty(n, dtype=np.int64)
    count = 0
    for word in range(words + 1):  # the last one: the entries after the whole words
        if word < words and chunks[word] == 0:
            continue
        for i in range(8 * word, min(8 * word + 8, n)):
            index[count] = i  # kept if set: no branch to mispredict
            count += mask[i]
    return index[:count]


@njit(cache=True, inline="always")
def reset_selected(
    index: npt.NDArray[np.int64],
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    position: npt.NDArray[np.float64],
    velocity: npt.NDArray[np.float64],
) -> None:
    """:func:`reset_plants` for the plants ``index`` (k-th: ``position[k]``, or one for all)."""
    for k in range(index.shape[0]):
        at = k if position.shape[0] > 1 else 0
        reset_plant(index[k], position[at], velocity[at], state, delay_buffer)


@njit(cache=True, inline="always")
def reset_plant(
    i: int,
    position: float,
    velocity: float,
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
) -> None:
    """Put plant ``i`` at ``position`` moving at ``velocity`` (see :func:`reset_plants`)."""
    for column in range(state.shape[0]):
        state[column, i] = 0.0
    state[S_X, i] = position
    state[S_V, i] = velocity
    state[S_STUCK, i] = 1.0 if velocity == 0.0 else 0.0
    state[S_MOTOR_V, i] = velocity  # in the middle of any play, moving with the load
    for slot in range(delay_buffer.shape[0]):
        delay_buffer[slot, i] = 0.0


# The jitter's generator: a linear congruential state modulo 2^52 (full period: the multiplier
# is 1 mod 4, the increment odd; the constants of Knuth's MMIX), held exactly in a float64 state
# column and read through the splitmix64 finaliser (Steele, Lea and Flood, OOPSLA 2014), which
# hides the low bits' short periods and decorrelates neighbouring seeds.
_LCG_MULTIPLIER = np.uint64(6364136223846793005)
_LCG_INCREMENT = np.uint64(1442695040888963407)
_MASK52 = np.uint64((1 << 52) - 1)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


@njit(cache=True, inline="always")
def jitter_draw(state: float) -> tuple[float, float]:
    """Advance the generator state ``state``; return the new state and a draw in ``[0, 1)``."""
    s = (np.uint64(state) * _LCG_MULTIPLIER + _LCG_INCREMENT) & _MASK52
    z = (s ^ (s >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    z = z ^ (z >> np.uint64(31))
    return float(s), float(z >> np.uint64(11)) * 2.0**-53


@njit(cache=True, inline="always")
def dead_zone(u: float, width: float) -> float:
    """Return the drive of command ``u`` through a dead zone of half-width ``width``.

    No drive while ``|u| <= width``, and ``u - width sign(u)`` beyond: the actuator dead zone
    of Tao and Kokotovic (Adaptive Control of Systems with Actuator and Sensor Nonlinearities,
    Wiley 1996, ch. 2) with equal slopes and a symmetric band. With ``width = 0.0`` it returns
    ``u`` bit for bit (``-0.0`` too).
    """
    return math.copysign(max(abs(u) - width, 0.0), u)


#: A packed row as the element functions receive it: a tuple of floats, not an array view.
#: Array views cost a reference-count round trip each; per plant that was most of the step.
Row = tuple[float, ...]

_MAX_SEGMENTS = 8  # at most 4 events + the final phase + a stuck phase; 8 leaves margin
#: Below this ``|l|``, :func:`_phi12` takes its Taylor series.
SERIES_LIMIT = 0.1
_SERIES_TERMS = 11
_INV_FACTORIALS = np.array([1.0 / math.factorial(n) for n in range(_SERIES_TERMS + 2)])


@njit(cache=True)
def _phi12(ell: float) -> tuple[float, float]:
    """Return ``E1 = (1 - e^-l)/l`` and ``E2 = (l - 1 + e^-l)/l^2``, accurate near l = 0.

    For |l| < 0.1, which covers every control-rate step of a motion-control plant, a Taylor
    series (relative error below 1e-17) replaces the transcendental call.
    """
    if abs(ell) < SERIES_LIMIT:
        return phi12_series(ell)
    return phi12_closed(ell, math.expm1(-ell))


@njit(cache=True, inline="always")
def phi12_closed(ell: float, em1: float) -> tuple[float, float]:
    """:func:`_phi12` for ``|l| >= SERIES_LIMIT``, given ``em1 = expm1(-l)``."""
    return -em1 / ell, (ell + em1) / (ell * ell)


@njit(cache=True, inline="always")
def phi12_given(ell: float, em1: float) -> tuple[float, float]:
    """:func:`_phi12` with ``expm1(-l)`` given (used only if ``|l| >= SERIES_LIMIT``).

    No branch: the series and the closed form are both computed (SIMD code).
    """
    s1, s2 = phi12_series(ell)
    c1, c2 = phi12_closed(ell, em1)
    series = abs(ell) < SERIES_LIMIT
    return (s1 if series else c1), (s2 if series else c2)


@njit(cache=True, inline="always")
def phi12_series(ell: float) -> tuple[float, float]:
    """:func:`_phi12` for ``|l| < SERIES_LIMIT``: its Taylor series (no branch: SIMD code)."""
    e1 = 0.0
    e2 = 0.0
    for n in range(_SERIES_TERMS - 1, -1, -1):  # Horner: sum (-l)^n / (n+1)!, / (n+2)!
        # an array, not a tuple: a tuple indexed by n compiles to a switch, kept from SIMD code
        e1 = _INV_FACTORIALS[n + 1] - ell * e1
        e2 = _INV_FACTORIALS[n + 2] - ell * e2
    return e1, e2


@njit(cache=True, inline="always")
def _affine_advance_by(
    x: float, v: float, a: float, j: float, t: float, ell: float, e1: float, e2: float
) -> tuple[float, float]:
    """:func:`affine_advance` given ``l = b / j * t`` and ``E1(l)``, ``E2(l)``."""
    acc = a / j
    v_new = v * (1.0 - ell * e1) + acc * t * e1
    x_new = x + v * t * e1 + acc * t * t * e2
    return x_new, v_new


@njit(cache=True)
def affine_advance(
    x: float, v: float, a: float, b: float, j: float, t: float
) -> tuple[float, float]:
    """Advance ``j v' = a - b v``, ``x' = v`` by time ``t`` in closed form.

    Written with ``E1``/``E2`` so it stays accurate for ``b -> 0`` and for negative ``b``
    (the velocity-weakening part of a Stribeck curve).
    """
    ell = b / j * t
    e1, e2 = _phi12(ell)
    return _affine_advance_by(x, v, a, j, t, ell, e1, e2)


@njit(cache=True, inline="always")
def _cached_advance(
    x: float, v: float, a: float, b: float, j: float, t: float, cache: Row, slope: int
) -> tuple[float, float]:
    """:func:`affine_advance`, with ``E1``/``E2`` from the row's cache when its key matches.

    ``E1``/``E2`` are functions of ``l`` alone, so the result is bit-identical either way.
    """
    ell = b / j * t
    if ell == cache[3 * slope]:
        e1, e2 = cache[3 * slope + 1], cache[3 * slope + 2]
    else:
        e1, e2 = _phi12(ell)
    return _affine_advance_by(x, v, a, j, t, ell, e1, e2)


@njit(cache=True)
def prime_rows(rows: npt.NDArray[np.float64], h: float) -> None:
    """Fill the coefficient cache of each plant row for a full substep of length ``h``.

    The slopes are computed as :func:`exact_phase` computes them, so a phase that spans a full
    substep finds its key.
    """
    for r in range(rows.shape[0]):
        j = rows[r, I_J]
        p = rows[r, F0 : F0 + friction_core.ROW_SIZE]
        b_total = rows[r, I_B] + p[friction_core.I_VISCOUS]
        slopes = [b_total, math.nan, math.nan]
        for n, (us, uc, v0) in enumerate(
            (
                (p[friction_core.I_US_POS], p[friction_core.I_UC_POS], p[friction_core.I_V0_POS]),
                (p[friction_core.I_US_NEG], p[friction_core.I_UC_NEG], p[friction_core.I_V0_NEG]),
            )
        ):
            if v0 > 0.0:  # a decay range (the law's own checks decide whether it is used)
                slopes[1 + n] = b_total - (us - uc) / v0
        for n in range(CACHE_SLOPES):
            ell = slopes[n] / j * h
            e1, e2 = _phi12(ell)
            rows[r, K0 + 3 * n] = ell
            rows[r, K0 + 3 * n + 1] = e1
            rows[r, K0 + 3 * n + 2] = e2


@njit(cache=True)
def affine_time_to(v: float, target: float, a: float, b: float, j: float) -> float:
    """Time for ``j v' = a - b v`` to bring ``v`` to ``target``, or ``inf`` if it never does."""
    never, q, num, den = time_to_terms(v, target, a, b)
    if never:
        return math.inf
    ratio = 1.0 - q / 2.0 if abs(q) < LOG_SERIES_LIMIT else math.log1p(q) / q
    return j * num / den * ratio


#: Below this ``|q|``, :func:`affine_time_to` takes ``log1p(q) / q`` as ``1 - q / 2``.
LOG_SERIES_LIMIT = 1e-8


@njit(cache=True, inline="always")
def time_to_terms(v: float, target: float, a: float, b: float) -> tuple[bool, float, float, float]:
    """Return the terms of :func:`affine_time_to`: ``never`` (it is inf), ``q``, ``num``, ``den``.

    The time is ``j num / den log1p(q) / q``. No branch: SIMD code.
    """
    num = target - v
    den = a - b * v
    q = -b * num / den if den != 0.0 else math.inf
    # Compare signs, not the product: num * den underflows to 0 for tiny (denormal) speeds.
    # q <= -1: the target lies beyond the asymptote v = a/b.
    never = num == 0.0 or den == 0.0 or (num > 0.0) != (den > 0.0) or q <= -1.0
    return never, q, num, den


@njit(cache=True)
def affine_time_to_position(
    x: float, v: float, a: float, b: float, j: float, target: float, t_max: float
) -> float:
    """First time in ``[0, t_max]`` at which ``j v' = a - b v`` carries ``x`` up to ``target``.

    The caller guarantees that ``x`` rises monotonically over the interval (``v >= 0`` on it)
    and reaches ``target`` by ``t_max``. Safeguarded Newton on the closed form; returns the
    smallest bracketing time found at which ``x >= target``.
    """
    if x >= target:
        return 0.0
    lo, hi = 0.0, t_max
    x_end, _ = affine_advance(x, v, a, b, j, t_max)
    t = t_max * (target - x) / (x_end - x)  # secant guess
    for _ in range(64):
        xt, vt = affine_advance(x, v, a, b, j, t)
        if xt >= target:
            hi = t
        else:
            lo = t
        if xt == target or hi - lo <= 4e-16 * hi:
            break
        t_next = t - (xt - target) / vt if vt > 0.0 else -1.0
        if not lo < t_next < hi:
            t_next = 0.5 * (lo + hi)
        if t_next == t:
            break
        t = t_next
    return hi


@njit(cache=True)
def held_at_stop(x: float, s: float, stop: float) -> bool:
    """Whether a body at rest at ``x`` that would break away toward ``s`` is held by the stop."""
    return s > 0.0 and x >= stop


@njit(cache=True)
def breakaway_direction(u: float, p: Row) -> float:
    """Direction a body at rest moves under input ``u``: +1.0, -1.0, or 0.0 if it stays put.

    The band is closed: the body breaks away only when ``u`` is strictly outside
    ``[-us_neg, us_pos]`` (Filippov's sliding-mode semantics, as Modelica's friction
    elements; docs/physics.md).
    """
    if u > p[friction_core.I_US_POS]:
        return 1.0
    if u < -p[friction_core.I_US_NEG]:
        return -1.0
    return 0.0


@njit(cache=True, inline="always")
def direction_levels(s: float, p: Row) -> tuple[float, float, float]:
    """Break-away level, Coulomb level and decay speed of direction ``s`` (+1.0 or -1.0)."""
    if s > 0.0:
        return p[friction_core.I_US_POS], p[friction_core.I_UC_POS], p[friction_core.I_V0_POS]
    return p[friction_core.I_US_NEG], p[friction_core.I_UC_NEG], p[friction_core.I_V0_NEG]


@njit(cache=True, inline="always")
def sliding_setup(
    v: float, u: float, s: float, b_total: float, us: float, uc: float, v0: float, linear: bool
) -> tuple[float, float, float, bool, int, float]:
    """Return the affine law ``j v' = a - bb v`` of a body sliding in direction ``s``, its event.

    The body slides in direction ``s`` at ``v`` (``s v >= 0``; ``v`` may be 0.0 just after
    break-away) under input ``u``, with the levels and decay speed of that direction
    (``linear``: the decay is linear; otherwise a step).

    Returns
    -------
    a, bb : float
        Force and slope of the speed range the body is on.
    k : float
        Slope of the linear decay (0.0 without one).
    inner : bool
        Whether it is on the decay range.
    slope : int
        Which of the row cache's slopes ``bb`` is: 0 Coulomb range, 1 and 2 the decay range
        forward and backward.
    target : float
        The velocity whose crossing ends the phase (stop, or the edge of the decay range), NaN
        if none lies ahead.

    Written with conditional expressions only, so that a loop over plants compiles to SIMD.
    """
    decays = linear and us > uc
    speed = s * v
    # Coulomb range: a = u - s uc, slope b_total. Decay range (|v| < v0): the level falls
    # linearly, u - s[us - k|v|] = (u - s us) + k v, so the slope drops by k.
    a_out = u - s * uc
    k = (us - uc) / v0 if decays else 0.0
    # on the boundary speed == v0: the side it is heading to
    inner = decays and (speed < v0 or (speed == v0 and s * (a_out - b_total * v) < 0.0))
    a = u - s * us if inner else a_out
    bb = b_total - k if inner else b_total
    slope = (1 if s > 0.0 else 2) if inner else 0
    acc = a - bb * v
    slowing, speeding = s * acc < 0.0, s * acc > 0.0
    beyond = s * v0 if decays and not inner else 0.0  # the next event when slowing down
    target = beyond if slowing else (s * v0 if speeding and inner else math.nan)
    return a, bb, k, inner, slope, target


@njit(cache=True, inline="always")
def phase_impulse(
    inner: bool, s: float, us: float, uc: float, k: float, dt: float, dx: float
) -> float:
    """Time integral of the nonlinear friction over a sliding phase of length ``dt`` and ``dx``."""
    return s * us * dt - k * dx if inner else s * uc * dt


@njit(cache=True, inline="always")
def exact_phase(
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
    """One phase of the event-exact step: from ``(x, v)`` for ``t_left`` or up to its first event.

    A phase is a stretch in one state (held, or sliding one way on one speed range) that ends
    at the end of the step or at an event (stop, leaving or entering the decay range, contact
    with the end stop), located exactly in time. Parameters as :func:`exact_static`.

    Returns
    -------
    x, v, dt, impulse : float
        State at the end of the phase, its length and the time integral of the nonlinear
        friction force over it.
    """
    if v == 0.0:
        s = breakaway_direction(u, p)
        if s == 0.0:  # held: static friction balances the input exactly
            return x, v, t_left, u * t_left
        if held_at_stop(x, s, stop):  # pressed on the stop: friction at break-away
            return x, v, t_left, p[friction_core.I_US_POS] * t_left
    else:
        s = 1.0 if v > 0.0 else -1.0
    us, uc, v0 = direction_levels(s, p)
    a, bb, k, inner, slope, target = sliding_setup(
        v, u, s, b_total, us, uc, v0, p[friction_core.I_SHAPE] == friction_core.SHAPE_LINEAR
    )
    dt = t_left
    x_new, v_new = _cached_advance(x, v, a, bb, j, dt, cache, slope)
    # v is monotone within a phase, so the event lies in this step iff v reaches the target.
    # Written as "not still short of it" so that an end state that overflowed (a steep
    # velocity-weakening range grows like e^(|b|t/J)) also counts as reached.
    short = v_new > target if v > target else v_new < target
    if not math.isnan(target) and not short:
        t_event = affine_time_to(v, target, a, bb, j)
        if t_event < t_left:
            dt = t_event
            x_new, v_new = affine_advance(x, v, a, bb, j, dt)
        v_new = target  # land exactly on the event: 0.0 means stuck-test next
    if x_new > stop:  # x rises through this phase: the contact comes first
        dt = affine_time_to_position(x, v, a, bb, j, stop, dt)
        x_new, v_new = stop, 0.0
    return x_new, v_new, dt, phase_impulse(inner, s, us, uc, k, dt, x_new - x)


@njit(cache=True)
def exact_static(
    x: float,
    v: float,
    u: float,
    h: float,
    j: float,
    b_total: float,
    p: Row,
    stop: float,
    cache: Row,
    impulse: float = 0.0,
    phases: int = _MAX_SEGMENTS,
) -> tuple[float, float, float]:
    """Event-exact step of a static law with a ``step`` or ``linear`` decay.

    Parameters
    ----------
    x, v : float
        State at the start of the step (``v == 0.0`` means stuck).
    u : float
        Input held over the step.
    h : float
        Step length.
    j, b_total : float
        Inertia and total viscous damping (plant ``B`` plus the law's viscous slope).
    p : tuple of float
        Packed friction row.
    stop : float
        Position of the end stop ahead (``inf``: none).
    cache : tuple of float
        The plant row's coefficient cache (see ``K0``).
    impulse : float, default 0.0
        Impulse so far (a caller that ran the step's first phase itself goes on from there).
    phases : int
        At most this many phases (:func:`exact_phase`).

    Returns
    -------
    x, v, impulse : float
        New state and the time integral of the nonlinear friction force over the step.
    """
    t_left = h
    for _ in range(phases):
        if t_left <= 0.0:
            break
        x, v, dt, imp = exact_phase(x, v, u, t_left, j, b_total, p, stop, cache)
        impulse += imp
        t_left -= dt
    return x, v, impulse


@njit(cache=True)
def split_static(
    x: float,
    v: float,
    u: float,
    h: float,
    j: float,
    b_total: float,
    p: Row,
    stop: float,
) -> tuple[float, float, float]:
    """One substep of the split scheme for any static decay shape (docs/physics.md).

    Returns the new ``x, v`` and the impulse of the nonlinear friction force.
    """
    if v == 0.0:
        s = breakaway_direction(u, p)
        if s == 0.0:
            return x, 0.0, u * h
        if held_at_stop(x, s, stop):
            return x, 0.0, p[friction_core.I_US_POS] * h
    else:
        s = 1.0 if v > 0.0 else -1.0
    f = s * friction_core.sliding_level(abs(v), s, p)
    v_try = (j * v + h * (u - f)) / (j + h * b_total)
    if v != 0.0 and s * v_try < 0.0:  # crosses zero inside the substep
        # Locate the stop with the deceleration at the substep's start, damping included: the
        # input then never does more work up to the stop than the kinetic energy it removes
        # (the implicit v_try would place the stop slightly late and create energy).
        theta = j * v / (h * (f + b_total * v - u))
        x += theta * h * v / 2.0
        impulse = f * theta * h
        rest = (1.0 - theta) * h
        s = breakaway_direction(u, p)
        if s == 0.0:
            return x, 0.0, impulse + u * rest
        f = s * friction_core.sliding_level(0.0, s, p)
        v_new = rest * (u - f) / (j + rest * b_total)
        return x + rest * v_new / 2.0, v_new, impulse + f * rest
    return x + h * (v + v_try) / 2.0, v_try, f * h


@njit(cache=True)
def lugre_substep(
    x: float,
    v: float,
    z: float,
    u: float,
    h: float,
    j: float,
    b_total: float,
    p: Row,
) -> tuple[float, float, float, float]:
    """One LuGre substep: exact bristle update at frozen ``v``, then semi-implicit mechanics.

    Returns ``x, v, z`` and the impulse of the bristle force ``sigma0 z + sigma1 dz/dt``.
    """
    sigma0, sigma1 = p[friction_core.I_SIGMA0], p[friction_core.I_SIGMA1]
    z_new = z
    if v != 0.0:
        s = 1.0 if v > 0.0 else -1.0
        g = friction_core.sliding_level(abs(v), s, p)
        z_ss = s * g / sigma0
        z_new = z_ss + (z - z_ss) * math.exp(-sigma0 * abs(v) / g * h)
    z_dot = (z_new - z) / h
    f = sigma0 * z_new + sigma1 * z_dot
    v_new = (j * v + h * (u - f)) / (j + h * b_total)
    return x + h * (v + v_new) / 2.0, v_new, z_new, f * h


@njit(cache=True, inline="always")
def lagged(u: float, y: float, hs: float, lag: float) -> tuple[float, float]:
    """Return the force of a substep ``hs`` under ``u`` through the actuator lag, and its output.

    The force is the lag output's exact average over the substep (``u`` itself without a lag).
    """
    if lag > 0.0:
        em1 = math.expm1(-hs / lag)
        return u - (y - u) * em1 * lag / hs, u + (y - u) * (1.0 + em1)
    return u, y


@njit(cache=True, inline="always")
def has_exact_step(friction: Row | npt.NDArray[np.float64]) -> bool:
    """Whether the law has the event-exact step: static, with a ``step`` or ``linear`` decay."""
    return friction[friction_core.I_LAW] == friction_core.LAW_STATIC and (
        friction[friction_core.I_SHAPE] == friction_core.SHAPE_STEP
        or friction[friction_core.I_SHAPE] == friction_core.SHAPE_LINEAR
    )


@njit(cache=True)
def advance(
    x: float,
    v: float,
    z: float,
    y: float,
    u: float,
    h: float,
    n_sub: int,
    plant: Row,
    friction: Row,
    cache: Row,
) -> tuple[float, float, float, float, float]:
    """Advance one plant by one control period with input ``u``.

    Parameters
    ----------
    x, v, z, y : float
        Position, velocity, LuGre bristle deflection and actuator-lag output.
    u : float
        Command after saturation and dead time; the actuator lag, if any, acts here.
    h : float
        Control period.
    n_sub : int
        Substeps.
    plant, friction, cache : tuple of float
        ``(J, B, u_max, lag, end stop)``, the packed friction row and the row's coefficient
        cache.

    Returns
    -------
    x, v, z, y, friction_force : float
        The new state and the friction force averaged over the step.
    """
    j = plant[I_J]
    b_total = plant[I_B] + friction[friction_core.I_VISCOUS]
    lag = plant[I_LAG]
    stop = plant[I_STOP]
    law = friction[friction_core.I_LAW]
    exact = has_exact_step(friction)
    x_start = x
    hs = h / n_sub
    impulse = 0.0
    # Held at rest for the whole step (static law, no lag): friction equals the input exactly,
    # not impulse / h, which can be off by one ulp (the test oracle F_f = u of docs/physics.md).
    held = law == friction_core.LAW_STATIC and lag == 0.0
    for _ in range(n_sub):
        force, y = lagged(u, y, hs, lag)
        if v != 0.0 or breakaway_direction(force, friction) != 0.0:
            held = False
        if exact:
            x, v, imp = exact_static(x, v, force, hs, j, b_total, friction, stop, cache)
        else:
            if law == friction_core.LAW_STATIC:
                x, v, imp = split_static(x, v, force, hs, j, b_total, friction, stop)
            else:
                x, v, z, imp = lugre_substep(x, v, z, force, hs, j, b_total, friction)
            if x > stop:  # contact inside the substep (first order, as its stops are)
                x, v = stop, 0.0
        impulse += imp
    if held:
        return x, v, z, y, u
    return x, v, z, y, (impulse + friction[friction_core.I_VISCOUS] * (x - x_start)) / h
