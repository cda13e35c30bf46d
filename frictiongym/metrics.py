"""Closed-loop performance metrics from raw sampled data.

Every function takes the raw samples of one run (1-D array_like, one value per sample time),
checks them (same length, finite, strictly increasing ``t``, enough samples) and raises a
``ValueError`` that says what is wrong and how to fix it. Times are measured from ``t[0]``.

Contents
--------
:func:`step_metrics` → :class:`StepMetrics`
    Rise time, peak time, settling time, overshoot and steady-state error of a step.
:func:`iae`, :func:`itae`
    Integral of ``|e|`` and of ``(t - t[0]) |e|`` (trapezoidal rule).
:func:`control_effort`
    RMS command over the run.
:func:`limit_cycle`
    Amplitude and period of a *sustained* oscillation at the end of the run (hunting,
    stick-slip), or ``(0.0, nan)`` when there is none.
:func:`time_stuck`
    Time the body spent held by friction after it first moved.
:func:`response_metrics` → :class:`ResponseMetrics`
    All of the above for one step run.

Conventions
-----------
Amplitudes are measured against the **reference** step (``reference - y0``), not against the
final value, because with friction the final value is exactly what is in question: a servo
that sticks 3 % short has a 3 % steady-state error and never settles in a 2 % band. Pass
``final_value`` to :func:`step_metrics` to measure rise, overshoot and settling against the
final value instead (python-control's convention). A time that is never reached (rise,
settling) is ``inf``.

Differences from python-control's ``step_info``
-----------------------------------------------
:func:`step_metrics` is modelled on ``control.step_info`` and, on the same ``(T, y)`` data
with ``y0 = 0``, ``T[0] = 0`` and ``final_value`` equal to python-control's final value, gives
the same rise time, peak time and overshoot, and the same settling time up to one sample.
The definitions differ as follows (read from python-control 0.10.2's ``timeresp.py``):

* **Origin of amplitudes.** ``step_info`` assumes the response starts at 0: rise limits are
  fractions of the final value and the settling test is ``|y / y_final - 1|``. Here every
  fraction is of the step ``target - y0``, so an offset start (``y0 != 0``) is handled.
* **Origin of times.** ``step_info`` reports ``PeakTime`` and ``SettlingTime`` as absolute
  values of ``T``; here they are measured from ``t[0]``.
* **Settling band edge.** ``step_info`` counts a sample exactly on the band edge as outside
  (``>=``); here it is inside (``>``). This can move the settling time by one sample.
* **Peak.** ``step_info``'s ``PeakTime`` is the time of the largest ``|y|``, whatever its
  sign; here it is the largest excursion in the step's direction. They differ when an
  undershoot (non-minimum-phase zero) is larger than the overshoot, or when ``y0 != 0``.
* **Final value.** For time-series data ``step_info`` uses ``y[-1]`` unless ``final_output``
  is given (and ``final_output=0`` is silently ignored); here the default is the reference.
* **Never reached.** When the upper rise limit is never reached ``step_info`` fails with an
  ``IndexError``, and an unsettled response has ``SettlingTime`` nan; here both are ``inf``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt

__all__ = [
    "ResponseMetrics",
    "StepMetrics",
    "control_effort",
    "iae",
    "itae",
    "limit_cycle",
    "response_metrics",
    "step_metrics",
    "time_stuck",
]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


# --------------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------------


def _as_times(t: npt.ArrayLike, min_samples: int = 2) -> FloatArray:
    """Return ``t`` as a float array after checking it is 1-D, finite and strictly increasing."""
    try:
        arr = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"t must be an array of numbers (sample times in s): {exc}") from exc
    if arr.ndim != 1:
        raise ValueError(
            f"t must be a 1-D array of sample times, got shape {arr.shape}; "
            "pass a flat array (e.g. np.ravel(t))"
        )
    if arr.size < min_samples:
        raise ValueError(
            f"need at least {min_samples} samples, got {arr.size}; record a longer run"
        )
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"t must be finite, but t[{i}] = {float(arr[i])!r}; drop the non-finite samples first"
        )
    steps = np.diff(arr)
    back = np.flatnonzero(steps <= 0.0)
    if back.size:
        i = int(back[0])
        raise ValueError(
            f"t must be strictly increasing, but t[{i + 1}] = {float(arr[i + 1])!r} <= "
            f"t[{i}] = {float(arr[i])!r}; sort the samples by time and remove duplicate times"
        )
    return arr


def _as_samples(name: str, values: npt.ArrayLike, t: FloatArray) -> FloatArray:
    """Return ``values`` as a float array of one finite value per sample time."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an array of numbers: {exc}") from exc
    if arr.ndim != 1 or arr.shape != t.shape:
        raise ValueError(
            f"t and {name} must be 1-D arrays of the same length: t has shape {t.shape}, "
            f"{name} has shape {arr.shape}; pass one {name} value per sample time"
        )
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"{name} must be finite, but {name}[{i}] = {float(arr[i])!r} (at t = {float(t[i])!r}); "
            "drop or interpolate the non-finite samples first"
        )
    return arr


def _as_flags(name: str, values: npt.ArrayLike, t: FloatArray) -> BoolArray:
    """Return ``values`` as a bool array of one flag per sample time (bool or 0/1 input)."""
    arr = np.asarray(values)
    if arr.ndim != 1 or arr.shape != t.shape:
        raise ValueError(
            f"t and {name} must be 1-D arrays of the same length: t has shape {t.shape}, "
            f"{name} has shape {arr.shape}; pass one {name} flag per sample time"
        )
    if arr.dtype == np.bool_:
        return arr
    if not np.issubdtype(arr.dtype, np.number) or not np.all((arr == 0) | (arr == 1)):
        raise ValueError(
            f"{name} must hold booleans (or 0/1), got dtype {arr.dtype}; "
            f"pass e.g. np.asarray({name}, dtype=bool)"
        )
    return arr.astype(np.bool_)


def _check_scalar(name: str, value: float) -> float:
    """Return ``value`` as a float after checking it is finite."""
    out = float(value)
    if not math.isfinite(out):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return out


def _check_fraction(name: str, value: float) -> float:
    """Return ``value`` after checking ``0 < value <= 1``."""
    out = float(value)
    if not 0.0 < out <= 1.0:
        raise ValueError(f"{name} must be a fraction of the run in (0, 1], got {value!r}")
    return out


def _trapezoid(t: FloatArray, f: FloatArray) -> float:
    """Trapezoidal integral of ``f`` over ``t``."""
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(t)))


# --------------------------------------------------------------------------------------------
# Step metrics
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StepMetrics:
    """Time-domain metrics of one step response (times in s, errors in position units)."""

    rise_time: float  #: 10 % to 90 % of the step; inf if 90 % is never reached
    peak_time: float  #: time of the largest excursion in the step's direction
    settling_time: float  #: time after which y stays within the band; inf if it never does
    overshoot_pct: float  #: peak beyond the target, % of the step (>= 0)
    steady_state_error: float  #: mean |target - y| over the end window
    steady_state_error_pct: float  #: the same, % of the step

    def as_dict(self) -> dict[str, float]:
        """Return the metrics as a plain dict."""
        return asdict(self)


def step_metrics(
    t: npt.ArrayLike,
    y: npt.ArrayLike,
    reference: float,
    y0: float | None = None,
    final_value: float | None = None,
    settling_band: float = 0.02,
    rise_limits: tuple[float, float] = (0.1, 0.9),
    end_fraction: float = 0.1,
) -> StepMetrics:
    """Step metrics of a sampled response.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times in s, strictly increasing; times are reported from ``t[0]``.
    y : array_like, shape (n,)
        Output, in output units (e.g. rad or cm).
    reference : float
        The commanded final value, in output units.
    y0 : float, optional
        Output before the step; ``y[0]`` by default.
    final_value : float, optional
        Measure rise, overshoot and settling against this value instead of ``reference``
        (python-control's convention uses the final value of the response). The steady-state
        error is always measured against ``reference``.
    settling_band : float, default 0.02
        Half-width of the settling band as a fraction of the step (0.02 = ±2 %).
    rise_limits : tuple of float, default (0.1, 0.9)
        Fractions of the step that bound the rise time.
    end_fraction : float, default 0.1
        Fraction of the run, at its end, averaged for the steady-state error.

    Returns
    -------
    StepMetrics
        Times in s from ``t[0]`` (``inf`` when never reached), overshoot and error
        percentages of ``|reference - y0|``, steady-state error in output units.

    Raises
    ------
    ValueError
        If the samples are malformed, the step is zero or a parameter is out of range.
    """
    t = _as_times(t)
    y = _as_samples("y", y, t)
    reference = _check_scalar("reference", reference)
    start = float(y[0]) if y0 is None else _check_scalar("y0", y0)
    target = reference if final_value is None else _check_scalar("final_value", final_value)
    step = target - start
    if step == 0.0:
        raise ValueError(
            "the step is zero: reference (or final_value) equals y0; step metrics need a "
            "non-zero step (pass y0 explicitly if y[0] is already at the reference)"
        )
    if reference == start:
        raise ValueError(
            "the step is zero: reference equals y0, so percentages of the step are undefined"
        )
    if not settling_band > 0.0:
        raise ValueError(f"settling_band must be > 0 (a fraction of the step), got {settling_band}")
    lo, hi = (float(v) for v in rise_limits)
    if not 0.0 <= lo < hi:
        raise ValueError(f"rise_limits must satisfy 0 <= low < high, got {rise_limits!r}")
    end_fraction = _check_fraction("end_fraction", end_fraction)

    progress = (y - start) / step  # 0 at the start, 1 at the target, in the step's direction

    reached_lo = np.flatnonzero(progress >= lo)
    reached_hi = np.flatnonzero(progress >= hi)
    if reached_hi.size:
        rise_time = float(t[reached_hi[0]] - t[reached_lo[0]])
    else:
        rise_time = math.inf

    peak = int(np.argmax(progress))
    peak_time = float(t[peak] - t[0])
    overshoot_pct = max(0.0, float(progress[peak] - 1.0) * 100.0)

    outside = np.flatnonzero(np.abs(progress - 1.0) > settling_band)
    if outside.size == 0:
        settling_time = 0.0
    elif outside[-1] == t.size - 1:
        settling_time = math.inf
    else:
        settling_time = float(t[outside[-1] + 1] - t[0])

    tail = t >= t[-1] - end_fraction * (t[-1] - t[0])
    sse = float(np.mean(np.abs(reference - y[tail])))
    return StepMetrics(
        rise_time=rise_time,
        peak_time=peak_time,
        settling_time=settling_time,
        overshoot_pct=overshoot_pct,
        steady_state_error=sse,
        steady_state_error_pct=sse / abs(reference - start) * 100.0,
    )


# --------------------------------------------------------------------------------------------
# Integral criteria and effort
# --------------------------------------------------------------------------------------------


def iae(t: npt.ArrayLike, error: npt.ArrayLike) -> float:
    """Integral of the absolute error, ``∫ |e| dt``, by the trapezoidal rule.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times in s, strictly increasing.
    error : array_like, shape (n,)
        Tracking error ``reference - y`` at each sample, in output units.

    Returns
    -------
    float
        The IAE in output units × s.

    Raises
    ------
    ValueError
        If the samples are malformed (shapes, non-finite values, non-increasing ``t``).
    """
    times = _as_times(t)
    e = _as_samples("error", error, times)
    return _trapezoid(times, np.abs(e))


def itae(t: npt.ArrayLike, error: npt.ArrayLike) -> float:
    """Integral of the time-weighted absolute error, ``∫ (t - t[0]) |e| dt`` (trapezoidal).

    The time weight penalises error that persists late in the run (slow settling, a stuck
    offset, a limit cycle) more than the unavoidable error just after the step.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times in s, strictly increasing; the weight is the time since ``t[0]``.
    error : array_like, shape (n,)
        Tracking error ``reference - y`` at each sample, in output units.

    Returns
    -------
    float
        The ITAE in output units × s².

    Raises
    ------
    ValueError
        If the samples are malformed (shapes, non-finite values, non-increasing ``t``).
    """
    times = _as_times(t)
    e = _as_samples("error", error, times)
    return _trapezoid(times, (times - times[0]) * np.abs(e))


def control_effort(t: npt.ArrayLike, command: npt.ArrayLike) -> float:
    """RMS command over the run, ``sqrt((1 / T) ∫ u² dt)`` with ``T = t[-1] - t[0]``.

    The RMS rather than ``∫ u² dt`` or ``∫ |u| dt`` because it is in the command's own units
    (V, N, % duty), so it reads directly in a table next to the command limit, and because
    it is a time average, so runs of different lengths compare. It also grows with
    chattering, which an average of ``u`` would hide.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times in s, strictly increasing.
    command : array_like, shape (n,)
        Controller output at each sample, in command units.

    Returns
    -------
    float
        The RMS command, in command units (>= 0).

    Raises
    ------
    ValueError
        If the samples are malformed (shapes, non-finite values, non-increasing ``t``).
    """
    times = _as_times(t)
    u = _as_samples("command", command, times)
    return math.sqrt(_trapezoid(times, u * u) / float(times[-1] - times[0]))


# --------------------------------------------------------------------------------------------
# Limit cycle
# --------------------------------------------------------------------------------------------


def limit_cycle(
    t: npt.ArrayLike,
    y: npt.ArrayLike,
    center: float | None = None,
    hysteresis: float = 0.0,
    window: float = 0.5,
    min_cycles: int = 2,
) -> tuple[float, float]:
    """Amplitude and period of a sustained oscillation at the end of a run.

    The rule, applied to the samples in the last ``window`` fraction of the run:

    1. **Crossings.** A Schmitt trigger with thresholds ``center ± hysteresis`` turns *high*
       when ``y > center + hysteresis`` and *low* when ``y < center - hysteresis``; each
       change between high and low is a crossing (alternately up and down by construction).
       The trigger has no state until ``y`` first leaves the band, so that first exit is not
       a crossing. A crossing's time is interpolated linearly between the two samples at
       the threshold that was crossed.
    2. **Complete cycles.** With ``m`` crossings there are ``K = (m - 1) // 2`` complete
       cycles (a cycle runs from one crossing to the next one in the same direction). The
       last ``2K + 1`` crossings are kept; their time span is the *cycle span*. A cycle
       needs ``K >= min_cycles``, i.e. at least ``2 * min_cycles + 1`` crossings.
    3. **Sustained.** The peak-to-peak of ``y`` over the first and over the second half (in
       time) of the cycle span must be within a factor of 2 of each other, which rejects a
       decaying (or growing) oscillation; and the end of the run must come no later than
       1.5 mean periods after the last crossing, which rejects an oscillation that died out
       before the end.

    When all hold, ``amplitude`` is half the peak-to-peak of ``y`` over the cycle span and
    ``period`` the mean time between successive same-direction crossings in it.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times in s, strictly increasing (at least 3 samples).
    y : array_like, shape (n,)
        Output, in output units.
    center : float, optional
        Level the oscillation is measured around; the mean of ``y`` over the window by
        default.
    hysteresis : float, default 0.0
        Half-width of the trigger's dead band, in output units (>= 0). With the default 0
        every crossing of ``center`` counts, so sensor noise or quantisation around a
        stopped output can register as a cycle: set it above the noise amplitude (for
        example the sensor resolution). :func:`response_metrics` uses half the settling band.
    window : float, default 0.5
        Fraction of the run, at its end, that is searched (in (0, 1]).
    min_cycles : int, default 2
        Complete cycles needed to call the oscillation a limit cycle (>= 1).

    Returns
    -------
    amplitude : float
        Half the peak-to-peak of ``y`` over the complete cycles, in output units; 0.0 when
        there is no sustained cycle.
    period : float
        Mean period in s; nan when there is no sustained cycle.

    Raises
    ------
    ValueError
        If the samples are malformed or a parameter is out of range.
    """
    times = _as_times(t, min_samples=3)
    values = _as_samples("y", y, times)
    hysteresis = _check_scalar("hysteresis", hysteresis)
    if hysteresis < 0.0:
        raise ValueError(f"hysteresis must be >= 0 (a half-width in y units), got {hysteresis}")
    window = _check_fraction("window", window)
    if int(min_cycles) != min_cycles or min_cycles < 1:
        raise ValueError(f"min_cycles must be an integer >= 1, got {min_cycles!r}")
    none = (0.0, math.nan)

    inside = times >= times[-1] - window * (times[-1] - times[0])
    tw, yw = times[inside], values[inside]
    if tw.size < 3:
        return none
    c = float(np.mean(yw)) if center is None else _check_scalar("center", center)
    upper, lower = c + hysteresis, c - hysteresis

    # Schmitt trigger, vectorised: +1 above the band, -1 below, 0 inside; carry the last
    # non-zero state forward, and a crossing is where the carried state flips sign.
    raw = np.where(yw > upper, 1, np.where(yw < lower, -1, 0))
    last_set = np.maximum.accumulate(np.where(raw != 0, np.arange(raw.size), 0))
    state = raw[last_set]
    idx = np.flatnonzero(state[1:] * state[:-1] < 0) + 1  # sample after each crossing
    n_cycles = (idx.size - 1) // 2
    if n_cycles < min_cycles:
        return none
    idx = idx[idx.size - (2 * n_cycles + 1) :]
    level = np.where(state[idx] > 0, upper, lower)
    frac = (level - yw[idx - 1]) / (yw[idx] - yw[idx - 1])
    tc = tw[idx - 1] + frac * (tw[idx] - tw[idx - 1])

    period = float(np.mean(tc[2:] - tc[:-2]))
    if tw[-1] - tc[-1] > 1.5 * period:
        return none  # the oscillation stopped before the end of the run

    span = slice(int(idx[0]) - 1, int(idx[-1]) + 1)
    ts, ys = tw[span], yw[span]
    mid = 0.5 * (tc[0] + tc[-1])
    first, second = ys[ts <= mid], ys[ts >= mid]
    ptp1, ptp2 = float(np.ptp(first)), float(np.ptp(second))
    if max(ptp1, ptp2) > 2.0 * min(ptp1, ptp2):
        return none  # decaying or growing, not sustained
    return 0.5 * float(np.ptp(ys)), period


# --------------------------------------------------------------------------------------------
# Sticking
# --------------------------------------------------------------------------------------------


def time_stuck(t: npt.ArrayLike, stuck: npt.ArrayLike) -> float:
    """Time the body spent held by friction after it first moved.

    Sample ``i`` stands for the interval ``[t[i], t[i+1])`` (zero-order hold), so it
    contributes ``t[i+1] - t[i]``; the last sample is the end instant of the run and
    contributes 0. The rest before the first motion (breakaway) does not count, since a
    step response always starts at rest; if the body never moves, the whole run
    ``t[-1] - t[0]`` counts.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times in s, strictly increasing.
    stuck : array_like of bool, shape (n,)
        True at sample ``i`` when the body is at rest, held by friction, at ``t[i]``.

    Returns
    -------
    float
        Time stuck in s, between 0 and ``t[-1] - t[0]``.

    Raises
    ------
    ValueError
        If the samples are malformed or ``stuck`` is not boolean.
    """
    times = _as_times(t)
    flags = _as_flags("stuck", stuck, times)
    durations = np.append(np.diff(times), 0.0)
    moving = np.flatnonzero(~flags)
    if moving.size == 0:
        return float(times[-1] - times[0])
    after = flags[moving[0] :]
    return float(np.sum(durations[moving[0] :][after]))


# --------------------------------------------------------------------------------------------
# Everything for one run
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ResponseMetrics:
    """All metrics of one step run (times in s, errors in output units).

    The first six fields are those of :class:`StepMetrics`.
    """

    rise_time: float  #: 10 % to 90 % of the step; inf if 90 % is never reached
    peak_time: float  #: time of the largest excursion in the step's direction
    settling_time: float  #: time after which y stays within the band; inf if it never does
    overshoot_pct: float  #: peak beyond the reference, % of the step (>= 0)
    steady_state_error: float  #: mean |reference - y| over the end window
    steady_state_error_pct: float  #: the same, % of the step
    iae: float  #: ∫ |reference - y| dt, output units × s
    itae: float  #: ∫ (t - t[0]) |reference - y| dt, output units × s²
    control_effort: float  #: RMS command, command units; nan without command data
    limit_cycle_amplitude: float  #: half peak-to-peak of a sustained oscillation, else 0
    limit_cycle_period: float  #: its period in s; nan when there is none
    time_stuck: float  #: time held by friction after first moving, s; nan without stuck data

    def as_dict(self) -> dict[str, float]:
        """Return the metrics as a plain dict."""
        return asdict(self)


def response_metrics(
    t: npt.ArrayLike,
    y: npt.ArrayLike,
    reference: float,
    command: npt.ArrayLike | None = None,
    stuck: npt.ArrayLike | None = None,
    y0: float | None = None,
    settling_band: float = 0.02,
    rise_limits: tuple[float, float] = (0.1, 0.9),
    end_fraction: float = 0.1,
    cycle_window: float = 0.5,
    cycle_hysteresis: float | None = None,
) -> ResponseMetrics:
    """All metrics of one step run: :func:`step_metrics` plus the others of this module.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times in s, strictly increasing (at least 3 samples).
    y : array_like, shape (n,)
        Output, in output units.
    reference : float
        The commanded final value, in output units; the error is ``reference - y``.
    command : array_like, shape (n,), optional
        Controller output, in command units; ``control_effort`` is nan without it.
    stuck : array_like of bool, shape (n,), optional
        Stick flags (see :func:`time_stuck`); ``time_stuck`` is nan without them.
    y0 : float, optional
        Output before the step; ``y[0]`` by default.
    settling_band : float, default 0.02
        Half-width of the settling band as a fraction of the step.
    rise_limits : tuple of float, default (0.1, 0.9)
        Fractions of the step that bound the rise time.
    end_fraction : float, default 0.1
        Fraction of the run, at its end, averaged for the steady-state error.
    cycle_window : float, default 0.5
        Fraction of the run, at its end, searched for a limit cycle.
    cycle_hysteresis : float, optional
        Dead band half-width of the limit-cycle trigger, in output units. The default
        ``settling_band / 2 * |reference - y0|`` ignores oscillations that stay inside half
        the settling band, which rejects encoder and IR-sensor quantisation while catching
        any hunting large enough to keep the response out of the band.

    Returns
    -------
    ResponseMetrics
        Times in s from ``t[0]``, see the field comments for units and special values.

    Raises
    ------
    ValueError
        If the samples are malformed, the step is zero or a parameter is out of range.
    """
    times = _as_times(t, min_samples=3)
    values = _as_samples("y", y, times)
    step = step_metrics(
        times,
        values,
        reference,
        y0=y0,
        settling_band=settling_band,
        rise_limits=rise_limits,
        end_fraction=end_fraction,
    )
    start = float(values[0]) if y0 is None else float(y0)
    error = float(reference) - values
    if cycle_hysteresis is None:
        cycle_hysteresis = 0.5 * settling_band * abs(float(reference) - start)
    amplitude, period = limit_cycle(times, values, hysteresis=cycle_hysteresis, window=cycle_window)
    return ResponseMetrics(
        **step.as_dict(),
        iae=iae(times, error),
        itae=itae(times, error),
        control_effort=math.nan if command is None else control_effort(times, command),
        limit_cycle_amplitude=amplitude,
        limit_cycle_period=period,
        time_stuck=math.nan if stuck is None else time_stuck(times, stuck),
    )
