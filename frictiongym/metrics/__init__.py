"""Closed-loop performance metrics from raw sampled data.

Every function takes the raw samples of one run (1-D array_like, one value per sample time),
checks them (same length, finite, strictly increasing ``t``, enough samples) and raises a
``ValueError`` that says what is wrong and how to fix it. Times are measured from ``t[0]``.

Contents
--------
:func:`step_metrics` → :class:`StepMetrics`
    Rise time, peak time, settling time, overshoot and steady-state error of a step.
:func:`step_metrics_batch` → :class:`StepMetricsBatch`
    The same for N responses at once (one per column), column by column equal.
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
from dataclasses import dataclass

import numpy.typing as npt

from frictiongym.metrics._checks import as_samples, as_times
from frictiongym.metrics.signals import control_effort, iae, itae, limit_cycle, time_stuck
from frictiongym.metrics.step import StepMetrics, StepMetricsBatch, step_metrics, step_metrics_batch

__all__ = [
    "ResponseMetrics",
    "StepMetrics",
    "StepMetricsBatch",
    "control_effort",
    "iae",
    "itae",
    "limit_cycle",
    "response_metrics",
    "step_metrics",
    "step_metrics_batch",
    "time_stuck",
]


@dataclass(frozen=True)
class ResponseMetrics(StepMetrics):
    """All metrics of one step run (times in s, errors in output units).

    The first six fields are those of :class:`StepMetrics`.
    """

    iae: float  #: ∫ |reference - y| dt, output units × s
    itae: float  #: ∫ (t - t[0]) |reference - y| dt, output units × s²
    control_effort: float  #: RMS command, command units; nan without command data
    limit_cycle_amplitude: float  #: half peak-to-peak of a sustained oscillation, else 0
    limit_cycle_period: float  #: its period in s; nan when there is none
    time_stuck: float  #: time held by friction after first moving, s; nan without stuck data


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
    times = as_times(t, min_samples=3)
    values = as_samples("y", y, times)
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
