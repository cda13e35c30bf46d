"""Integral, effort, limit-cycle and stick metrics of a run."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from frictiongym._validation import real_number
from frictiongym.metrics._checks import (
    as_flags,
    as_samples,
    as_times,
    check_fraction,
    check_scalar,
    trapezoid,
)


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
    times = as_times(t)
    e = as_samples("error", error, times)
    return trapezoid(times, np.abs(e))


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
    times = as_times(t)
    e = as_samples("error", error, times)
    return trapezoid(times, (times - times[0]) * np.abs(e))


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
    times = as_times(t)
    u = as_samples("command", command, times)
    return math.sqrt(trapezoid(times, u * u) / float(times[-1] - times[0]))


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
    times = as_times(t, min_samples=3)
    values = as_samples("y", y, times)
    hint = " (a half-width in y units)"
    hysteresis = real_number("hysteresis", float(hysteresis), ">= 0", hint=hint)
    window = check_fraction("window", window)
    if int(min_cycles) != min_cycles or min_cycles < 1:
        raise ValueError(f"min_cycles must be an integer >= 1, got {min_cycles!r}")
    none = (0.0, math.nan)

    inside = times >= times[-1] - window * (times[-1] - times[0])
    tw, yw = times[inside], values[inside]
    if tw.size < 3:
        return none
    c = float(np.mean(yw)) if center is None else check_scalar("center", center)
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
    times = as_times(t)
    flags = as_flags("stuck", stuck, times)
    durations = np.append(np.diff(times), 0.0)
    moving = np.flatnonzero(~flags)
    if moving.size == 0:
        return float(times[-1] - times[0])
    after = flags[moving[0] :]
    return float(np.sum(durations[moving[0] :][after]))
