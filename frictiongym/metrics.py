"""Step-response metrics from raw ``(t, y)`` data.

Modelled on python-control's ``step_info``, with one deliberate difference: amplitudes are
measured against the **reference** step (``reference - y0``), not the final value, because
with friction the final value is exactly what is in question. Pass ``final_value`` to measure
against the final value instead.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt


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
    t, y : array_like, shape (n,)
        Sample times (increasing) and output.
    reference : float
        The commanded final value.
    y0 : float, optional
        Output before the step; ``y[0]`` by default.
    final_value : float, optional
        Measure rise, overshoot and settling against this value instead of ``reference``
        (python-control's convention uses the final value of the response).
    settling_band : float, default 0.02
        Settling band as a fraction of the step.
    rise_limits : tuple of float, default (0.1, 0.9)
        Fractions of the step that bound the rise time.
    end_fraction : float, default 0.1
        Fraction of the run, at its end, averaged for the steady-state error.

    Returns
    -------
    StepMetrics
    """
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if t.ndim != 1 or t.shape != y.shape or t.size < 2:
        raise ValueError("t and y must be 1-D arrays of the same length (at least 2 samples)")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise ValueError("t and y must be finite")
    start = float(y[0]) if y0 is None else float(y0)
    target = float(reference) if final_value is None else float(final_value)
    step = target - start
    if step == 0.0:
        raise ValueError("the step is zero: reference (or final_value) equals y0")
    progress = (y - start) / step  # 0 at the start, 1 at the target, in the step's direction

    lo, hi = rise_limits
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
