"""Discrete PID with derivative on the measurement and clamping anti-windup, batched.

Works on floats and on arrays (one loop per element), so the same controller drives one plant
or a batch of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from frictiongym._validation import check_finite, check_nonnegative

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PIDGains:
    """PID gains, in command units per position unit.

    ``ki`` is per position unit and second, ``kd`` per velocity unit.
    """

    kp: float
    ki: float = 0.0
    kd: float = 0.0

    def __post_init__(self) -> None:
        check_finite(self, "kp", "ki", "kd")
        check_nonnegative(self, "kp", "ki", "kd")


class PID:
    """Discrete PID ``u = kp e + ki I + kd d(-y)/dt`` with ``e = r - y``.

    * Integral: backward Euler, ``I_k = I_(k-1) + e_k dt``.
    * Derivative on the measurement (no kick on reference steps), through a first-order filter
      ``s / (tau s + 1)`` discretised ramp-invariantly, or taken from a velocity measurement
      passed to :meth:`update`.
    * Saturation at ``±limit``; the integrator is frozen while the output is saturated in the
      direction of the error (clamping anti-windup).

    Parameters
    ----------
    gains : PIDGains
    dt : float
        Control period, s.
    limit : float, default inf
        Output saturation, command units.
    derivative_tau : float, default 0.0
        Time constant of the derivative filter, s (0: plain backward difference).
    direction : float, default 1.0
        ``-1.0`` when a positive command decreases the measurement (the Altino: driving forward
        reduces the distance to the wall).
    """

    def __init__(
        self,
        gains: PIDGains,
        dt: float,
        limit: float = math.inf,
        derivative_tau: float = 0.0,
        direction: float = 1.0,
    ) -> None:
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        if not limit > 0.0:
            raise ValueError(f"limit must be > 0, got {limit!r}")
        if direction not in (1.0, -1.0):
            raise ValueError(f"direction must be 1.0 or -1.0, got {direction!r}")
        self.gains = gains
        self.dt = float(dt)
        self.limit = float(limit)
        self.direction = float(direction)
        self._pole = math.exp(-self.dt / derivative_tau) if derivative_tau > 0.0 else 0.0
        self.reset()

    def reset(self) -> None:
        """Forget the integral and the derivative history."""
        self.integral: FloatArray | float = 0.0
        self._rate: FloatArray | float = 0.0
        self._previous: FloatArray | float | None = None

    def update(
        self,
        reference: float | npt.ArrayLike,
        measurement: float | npt.ArrayLike,
        velocity: float | npt.ArrayLike | None = None,
    ) -> FloatArray:
        """Return the command for the newest measurement.

        Parameters
        ----------
        reference, measurement : float or array_like
            Set point and measured position.
        velocity : float or array_like, optional
            Measured velocity; when given it replaces the filtered difference of the
            measurement in the derivative term.
        """
        r = np.asarray(reference, dtype=np.float64)
        y = np.asarray(measurement, dtype=np.float64)
        error = r - y
        if velocity is not None:
            self._rate = np.asarray(velocity, dtype=np.float64)
        elif self._previous is not None:
            slope = (y - self._previous) / self.dt
            self._rate = self._pole * self._rate + (1.0 - self._pole) * slope
        self._previous = y
        g = self.gains
        integral = self.integral + error * self.dt
        raw = g.kp * error + g.ki * integral - g.kd * self._rate
        command = np.clip(raw, -self.limit, self.limit)
        # Clamping: keep the integral only where it does not push further into saturation.
        winding = (raw != command) & (np.sign(error) == np.sign(raw))
        self.integral = np.where(winding, self.integral, integral)
        return np.asarray(self.direction * command, dtype=np.float64)
