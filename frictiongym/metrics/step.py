"""Step-response metrics (rise, peak, settling, overshoot, steady-state error)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt

from frictiongym.metrics._checks import (
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
    t = as_times(t)
    y = as_samples("y", y, t)
    reference = check_scalar("reference", reference)
    start = float(y[0]) if y0 is None else check_scalar("y0", y0)
    target = reference if final_value is None else check_scalar("final_value", final_value)
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
    end_fraction = check_fraction("end_fraction", end_fraction)

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
