"""The paper's performance requirements and gain bounds for the servo PID (§3.1)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym._validation import check_positive
from frictiongym.metrics.step import StepMetricsBatch

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: The four specs, in the paper's order: (field of StepSpecs and StepMetrics, label, unit).
SPEC_FIELDS = (
    ("rise_time", "rise time", "s"),
    ("peak_time", "peak time", "s"),
    ("settling_time", "settling time", "s"),
    ("overshoot_pct", "overshoot", "%"),
)


@dataclass(frozen=True)
class StepSpecs:
    """Upper limits on the unit-step metrics; a candidate is feasible if it is below all four.

    Parameters
    ----------
    rise_time, peak_time, settling_time : float, defaults 0.05, 0.1, 1.5
        s; the paper's requirements (§3.1: ``t_r < 0.05 s``, ``t_p < 0.1 s``, ``t_s < 1.5 s``).
    overshoot_pct : float, default 20.0
        %; the paper's ``PO < 20 %``.
    settling_band : float, default 0.02
        Half-width of the settling band as a fraction of the step. The paper does not state
        it; 2 % is the default of MATLAB's ``stepinfo``, which the paper used, and of
        python-control's ``step_info``.
    rise_limits : tuple of float, default (0.1, 0.9)
        The rise time's fractions of the step: ``stepinfo``'s and ``step_info``'s default.
    """

    rise_time: float = 0.05
    peak_time: float = 0.1
    settling_time: float = 1.5
    overshoot_pct: float = 20.0
    settling_band: float = 0.02
    rise_limits: tuple[float, float] = (0.1, 0.9)

    def __post_init__(self) -> None:
        check_positive(
            self, "rise_time", "peak_time", "settling_time", "overshoot_pct", "settling_band"
        )
        lo, hi = self.rise_limits
        if not 0.0 <= lo < hi:
            raise ValueError(f"StepSpecs.rise_limits must satisfy 0 <= low < high, got {lo, hi}")

    def failures(self, metrics: StepMetricsBatch) -> dict[str, BoolArray]:
        """Per spec, which responses fail it (NaN metrics fail)."""
        return {name: ~(getattr(metrics, name) < getattr(self, name)) for name, _, _ in SPEC_FIELDS}

    def feasible(self, metrics: StepMetricsBatch) -> BoolArray:
        """Which responses meet all four specs."""
        return ~np.logical_or.reduce(list(self.failures(metrics).values()))

    def margin(self, metrics: StepMetricsBatch) -> FloatArray:
        """Worst-case relative margin ``min_i (1 - metric_i / limit_i)``; > 0 when feasible."""
        ratios = [getattr(metrics, name) / getattr(self, name) for name, _, _ in SPEC_FIELDS]
        return np.asarray(1.0 - np.max(ratios, axis=0), dtype=np.float64)

    def record(self) -> dict[str, Any]:
        """Return the specs as a JSON-ready dict (limits are strict upper bounds)."""
        out = asdict(self)
        out["rise_limits"] = list(self.rise_limits)
        return out


@dataclass(frozen=True)
class GainBounds:
    """Open intervals the random search draws each gain from, uniformly and independently.

    Parameters
    ----------
    kp, ki, kd : tuple of float, defaults (0, 10), (0, 5), (0, 0.5)
        The paper's bounds (§3.1: ``0 < Kp < 10``, ``0 < Ki < 5``, ``0 < Kd < 0.5``), in V/rad,
        V/(rad·s) and V·s/rad.
    """

    kp: tuple[float, float] = (0.0, 10.0)
    ki: tuple[float, float] = (0.0, 5.0)
    kd: tuple[float, float] = (0.0, 0.5)

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo < hi):
                raise ValueError(
                    f"GainBounds.{name} must be (low, high) with 0 <= low < high, got {lo, hi}"
                )

    @property
    def low(self) -> FloatArray:
        """Lower bounds ``(kp, ki, kd)``."""
        return np.array([self.kp[0], self.ki[0], self.kd[0]])

    @property
    def high(self) -> FloatArray:
        """Upper bounds ``(kp, ki, kd)``."""
        return np.array([self.kp[1], self.ki[1], self.kd[1]])

    def sample(self, rng: np.random.Generator, n: int) -> FloatArray:
        """``n`` candidates, shape (n, 3): uniform in the box (a draw on a bound is redrawn)."""
        gains = rng.uniform(self.low, self.high, size=(n, 3))
        on_edge = np.any(gains <= self.low, axis=1)  # uniform() can return the low end
        while on_edge.any():
            gains[on_edge] = rng.uniform(self.low, self.high, size=(int(on_edge.sum()), 3))
            on_edge = np.any(gains <= self.low, axis=1)
        return gains

    def contains(self, gains: npt.ArrayLike) -> BoolArray:
        """Which rows ``(kp, ki, kd)`` lie strictly inside the bounds."""
        g = np.asarray(gains, dtype=np.float64).reshape(-1, 3)
        return np.all((g > self.low) & (g < self.high), axis=1)

    def record(self) -> dict[str, list[float]]:
        """Return the bounds as a JSON-ready dict."""
        return {k: list(v) for k, v in asdict(self).items()}
