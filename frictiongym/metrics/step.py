"""Step-response metrics (rise, peak, settling, overshoot, steady-state error).

One core, :func:`step_metrics_batch`, measures a batch of responses at once (one column per
response, e.g. every candidate of a random-search tuning run); :func:`step_metrics` measures a
single response through the same core, so the two agree exactly, column by column.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np
import numpy.typing as npt

from frictiongym.metrics._checks import (
    FloatArray,
    as_samples,
    as_times,
    check_fraction,
    check_scalar,
)


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


@dataclass(frozen=True)
class StepMetricsBatch:
    """The fields of :class:`StepMetrics` for a batch of N responses, as arrays of shape (N,)."""

    rise_time: FloatArray
    peak_time: FloatArray
    settling_time: FloatArray
    overshoot_pct: FloatArray
    steady_state_error: FloatArray
    steady_state_error_pct: FloatArray

    def __len__(self) -> int:
        return int(self.rise_time.size)

    def __getitem__(self, index: int) -> StepMetrics:
        """Return the metrics of response ``index``."""
        return StepMetrics(**{f.name: float(getattr(self, f.name)[index]) for f in fields(self)})

    def take(self, index: npt.ArrayLike) -> StepMetricsBatch:
        """Return the metrics of the responses ``index`` (integer array or boolean mask)."""
        return StepMetricsBatch(**{f.name: getattr(self, f.name)[index] for f in fields(self)})


def step_progress(y: FloatArray, start: float | FloatArray, step: float | FloatArray) -> FloatArray:
    """Progress of the step, ``(y - start) / step``: 0 at the start, 1 at the target.

    The one definition every step metric is computed from (and that an early stop of a batched
    simulation must use to stay exact).
    """
    return np.asarray((y - start) / step, dtype=np.float64)


def step_metrics_batch(
    t: npt.ArrayLike,
    y: npt.ArrayLike,
    reference: float,
    y0: float | npt.ArrayLike | None = None,
    final_value: float | None = None,
    settling_band: float = 0.02,
    rise_limits: tuple[float, float] = (0.1, 0.9),
    end_fraction: float = 0.1,
) -> StepMetricsBatch:
    """Step metrics of N sampled responses at once (see :func:`step_metrics`).

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times in s, strictly increasing, shared by all responses.
    y : array_like, shape (n, N)
        One response per column, in output units.
    reference : float
        The commanded final value, shared by all responses.
    y0 : float or array_like of shape (N,), optional
        Output before the step; ``y[0]`` by default.
    final_value, settling_band, rise_limits, end_fraction
        As in :func:`step_metrics`.

    Returns
    -------
    StepMetricsBatch
        Arrays of shape (N,); column ``j`` equals ``step_metrics(t, y[:, j], ...)`` exactly.

    Raises
    ------
    ValueError
        If the samples are malformed, a step is zero or a parameter is out of range.
    """
    times = as_times(t)
    try:
        values = np.asarray(y, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"y must be an array of numbers: {exc}") from exc
    if values.ndim != 2 or values.shape[0] != times.size:
        raise ValueError(
            f"y must have shape (len(t), N) = ({times.size}, N), one response per column; "
            f"got {values.shape}"
        )
    if not np.all(np.isfinite(values)):
        bad = np.argwhere(~np.isfinite(values))[0]
        raise ValueError(
            f"y must be finite, but y[{bad[0]}, {bad[1]}] = {values[bad[0], bad[1]]!r}; drop or "
            "interpolate the non-finite samples first"
        )
    reference = check_scalar("reference", reference)
    if y0 is None:
        start = values[0].copy()
    else:
        start = np.broadcast_to(np.asarray(y0, dtype=np.float64), values.shape[1:]).copy()
        if not np.all(np.isfinite(start)):
            raise ValueError(f"y0 must be finite, got {y0!r}")
    target = reference if final_value is None else check_scalar("final_value", final_value)
    step = target - start
    if np.any(step == 0.0):
        raise ValueError(
            "the step is zero: reference (or final_value) equals y0; step metrics need a "
            "non-zero step (pass y0 explicitly if y[0] is already at the reference)"
        )
    if np.any(reference == start):
        raise ValueError(
            "the step is zero: reference equals y0, so percentages of the step are undefined"
        )
    if not settling_band > 0.0:
        raise ValueError(f"settling_band must be > 0 (a fraction of the step), got {settling_band}")
    lo, hi = (float(v) for v in rise_limits)
    if not 0.0 <= lo < hi:
        raise ValueError(f"rise_limits must satisfy 0 <= low < high, got {rise_limits!r}")
    end_fraction = check_fraction("end_fraction", end_fraction)

    progress = step_progress(values, start, step)  # 0 at the start, 1 at the target
    columns = np.arange(values.shape[1])

    above_lo, above_hi = progress >= lo, progress >= hi
    first_lo, first_hi = np.argmax(above_lo, axis=0), np.argmax(above_hi, axis=0)
    rise_time = np.where(above_hi[first_hi, columns], times[first_hi] - times[first_lo], math.inf)

    peak = np.argmax(progress, axis=0)
    peak_time = times[peak] - times[0]
    overshoot_pct = np.maximum(0.0, (progress[peak, columns] - 1.0) * 100.0)

    outside = np.abs(progress - 1.0) > settling_band
    last = values.shape[0] - 1 - np.argmax(outside[::-1], axis=0)  # last sample outside the band
    after = np.minimum(last + 1, values.shape[0] - 1)
    settling_time = np.where(last == values.shape[0] - 1, math.inf, times[after] - times[0])
    settling_time = np.where(outside[last, columns], settling_time, 0.0)

    tail = times >= times[-1] - end_fraction * (times[-1] - times[0])
    # Row-contiguous so each response is summed as np.mean sums a 1-D array (pairwise).
    sse = np.ascontiguousarray(np.abs(reference - values[tail]).T).mean(axis=1)
    return StepMetricsBatch(
        rise_time=rise_time,
        peak_time=peak_time,
        settling_time=settling_time,
        overshoot_pct=overshoot_pct,
        steady_state_error=sse,
        steady_state_error_pct=sse / np.abs(reference - start) * 100.0,
    )


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

    See Also
    --------
    step_metrics_batch : the same for N responses at once.
    """
    times = as_times(t)
    values = as_samples("y", y, times)
    batch = step_metrics_batch(
        times,
        values[:, np.newaxis],
        reference,
        y0,
        final_value,
        settling_band,
        rise_limits,
        end_fraction,
    )
    return batch[0]
