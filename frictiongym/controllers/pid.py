"""Discrete PID with derivative on the measurement, a derivative filter and anti-windup.

Batched: one object drives one env or a vector of them (its state is an array per env).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from frictiongym._validation import check_finite, check_nonnegative, real_number
from frictiongym.controllers.base import Controller, FloatArray, LoopSpec, reset_mask

AntiWindup = Literal["clamping", "back-calculation", "none"]
Derivative = Literal["velocity", "difference"]


@dataclass(frozen=True)
class PIDGains:
    """PID gains in per-second form.

    ``kp`` is in command units per output unit, ``ki`` per output unit and second, ``kd`` per
    output unit per second (volts per rad, per rad·s, per rad/s for the servo).

    Each gain is a number, or a numpy array of one gain per env of a batch (arrays broadcast
    against each other and against the batch: ``kp`` of shape ``(N,)`` gives each of N envs its
    own ``kp``; random-search tuning evaluates N candidates this way). Array gains are stored
    as read-only float64 arrays; such a ``PIDGains`` cannot be hashed or compared with ``==``.
    """

    kp: float | FloatArray
    ki: float | FloatArray = 0.0
    kd: float | FloatArray = 0.0

    def __post_init__(self) -> None:
        if not self.batched:
            check_finite(self, "kp", "ki", "kd")
            check_nonnegative(self, "kp", "ki", "kd")
            return
        try:
            arrays = np.broadcast_arrays(*(np.asarray(g, dtype=np.float64) for g in self))
        except ValueError as error:
            shapes = ", ".join(str(np.shape(g)) for g in self)
            raise ValueError(
                f"PIDGains arrays must broadcast to one batch shape, got shapes {shapes}"
            ) from error
        for name, value in zip(("kp", "ki", "kd"), arrays, strict=True):
            if not np.all(np.isfinite(value)):
                raise ValueError(f"PIDGains.{name} must be finite, got {value!r}")
            if np.any(value < 0.0):
                raise ValueError(f"PIDGains.{name} must be >= 0, got {value!r}")
            stored = value.copy()
            stored.flags.writeable = False
            object.__setattr__(self, name, stored)

    def __iter__(self) -> Iterator[float | FloatArray]:
        """Iterate over ``kp, ki, kd``."""
        return iter((self.kp, self.ki, self.kd))

    @property
    def batched(self) -> bool:
        """Whether the gains are arrays (one set per env) rather than numbers."""
        return any(isinstance(g, np.ndarray) for g in self)

    @property
    def shape(self) -> tuple[int, ...]:
        """Batch shape of the gains: ``()`` for numbers."""
        return np.broadcast_shapes(*(np.shape(g) for g in self))

    def take(self, index: npt.ArrayLike) -> PIDGains:
        """Return the gains of the batch entries ``index`` (integer array or boolean mask)."""
        if not self.batched:
            return self
        idx = np.asarray(index)
        arrays = np.broadcast_arrays(*(np.asarray(g) for g in self))
        kp, ki, kd = (np.asarray(a[idx], dtype=np.float64) for a in arrays)
        return PIDGains(kp, ki, kd)


def _tracking_time(gains: PIDGains) -> float | FloatArray | None:
    """Åström & Hägglund's default ``T_t``: ``sqrt(T_i T_d)``, or ``T_i`` without D.

    None (numbers) or NaN (per env of array gains) where it is undefined (``ki`` or ``kp`` 0).
    """
    p, i, d = np.broadcast_arrays(*(np.asarray(g, dtype=np.float64) for g in gains))
    with np.errstate(divide="ignore", invalid="ignore"):
        integral_time = p / i
        tracking = np.where(d > 0.0, np.sqrt(integral_time * d / p), integral_time)
    tt = np.where((i > 0.0) & (p > 0.0), tracking, np.nan)
    if gains.batched:
        return tt
    return None if np.isnan(tt) else float(tt)


class PID(Controller):
    """Discrete PID ``u = direction · (kp e + ki I - kd ŷ')`` with ``e = r - y``.

    * Integral: backward Euler, ``I_k = I_(k-1) + e_k dt``.
    * Derivative on the measurement, so a reference step does not kick the command. With
      ``derivative="velocity"`` the rate is the observation's velocity entry (the QUBE's
      filtered tachometer ``50 s/(s + 50)``, the Altino's backward difference); with
      ``"difference"`` it is the measurement's backward difference through a first-order
      filter ``1/(tau s + 1)`` (ramp-invariant discretisation; ``tau = 0``: none).
    * Saturation at the spec's limit, with anti-windup: ``clamping`` freezes the integral while
      the output is saturated in the direction of the error; ``back-calculation`` bleeds the
      excess ``(u_sat - u)/(ki T_t)`` back into the integral with tracking time ``T_t``
      (default ``sqrt(T_i T_d)``, or ``T_i`` without D, Åström & Hägglund's rule); ``none``
      integrates regardless (for comparison).

    Parameters
    ----------
    spec : LoopSpec
        The loop (``PID.for_env(env, gains)`` reads it from an env).
    gains : PIDGains
        Numbers, or arrays of one gain set per env of the batch (random-search tuning runs N
        candidates as N envs); :meth:`take` keeps a subset of the batch.
    derivative : {"velocity", "difference"}, default "velocity"
        Where the D term's rate comes from; ``velocity`` needs a velocity entry in the spec.
    derivative_tau : float, default 0.0
        Filter time constant of the ``difference`` rate, s.
    anti_windup : {"clamping", "back-calculation", "none"}, default "clamping"
    tracking_time : float, optional
        ``T_t`` of back-calculation, s.
    """

    def __init__(
        self,
        spec: LoopSpec,
        gains: PIDGains,
        *,
        derivative: Derivative = "velocity",
        derivative_tau: float = 0.0,
        anti_windup: AntiWindup = "clamping",
        tracking_time: float | None = None,
    ) -> None:
        if derivative not in ("velocity", "difference"):
            raise ValueError(f"derivative must be 'velocity' or 'difference', got {derivative!r}")
        if derivative == "velocity" and spec.velocity is None:
            raise ValueError(
                "derivative='velocity' needs a velocity entry in the observation; this spec "
                "has none: use derivative='difference'"
            )
        if anti_windup not in ("clamping", "back-calculation", "none"):
            raise ValueError(
                f"anti_windup must be 'clamping', 'back-calculation' or 'none', got {anti_windup!r}"
            )
        real_number("derivative_tau", derivative_tau, ">= 0", unit=" s")
        tt: float | FloatArray | None = (
            _tracking_time(gains) if tracking_time is None else tracking_time
        )
        if anti_windup == "back-calculation":
            needed = np.asarray(gains.ki) > 0.0
            valid = not np.any(needed) or (
                tt is not None
                and bool(np.all(~needed | (np.isfinite(tt) & (np.asarray(tt) > 0.0))))
            )
            if not valid:
                raise ValueError(
                    f"back-calculation needs a tracking_time > 0 s, got {tt!r} "
                    "(give one when kp is 0)"
                )
        self.spec = spec
        self.gains = gains
        self.derivative = derivative
        self.derivative_tau = float(derivative_tau)
        self.anti_windup = anti_windup
        self.tracking_time = tt
        self._pole = math.exp(-spec.dt / derivative_tau) if derivative_tau > 0.0 else 0.0
        self.reset()

    def reset(self, mask: npt.ArrayLike | None = None) -> None:
        """Forget the integral and the derivative history (of the masked envs)."""
        if mask is not None and hasattr(self, "integral") and self.integral.ndim > 0:
            m = reset_mask(mask, self.integral.size)
            self.integral[m] = 0.0
            self._rate[m] = 0.0
            self._previous[m] = np.nan
        elif mask is None or np.any(mask):  # a fresh or single-env (scalar) state
            self.integral: FloatArray = np.zeros(())
            self._rate: FloatArray = np.zeros(())
            self._previous: FloatArray = np.full((), np.nan)  # NaN: no previous sample

    def _state_for(self, shape: tuple[int, ...]) -> None:
        """Give the state the batch shape on first use (it starts as scalars)."""
        if self.integral.shape != shape:
            if self.integral.shape != ():
                raise ValueError(
                    f"the controller runs a batch of shape {self.integral.shape} but got "
                    f"{shape}: call reset() before switching batch sizes"
                )
            self.integral = np.broadcast_to(self.integral, shape).copy()
            self._rate = np.broadcast_to(self._rate, shape).copy()
            self._previous = np.broadcast_to(self._previous, shape).copy()

    def update(
        self,
        reference: npt.ArrayLike,
        measurement: npt.ArrayLike,
        velocity: npt.ArrayLike | None = None,
    ) -> FloatArray:
        """Return the saturated command for the newest measurement (the PID's core).

        Parameters
        ----------
        reference, measurement : float or array_like
            Set point and measured output.
        velocity : float or array_like, optional
            Measured rate of the output; without it the D term uses the filtered difference.
        """
        r = np.asarray(reference, dtype=np.float64)
        y = np.asarray(measurement, dtype=np.float64)
        self._state_for(np.broadcast_shapes(r.shape, y.shape, self.gains.shape))
        error = r - y
        if velocity is not None:
            self._rate = np.broadcast_to(np.asarray(velocity, dtype=np.float64), y.shape).copy()
        else:
            slope = (y - self._previous) / self.spec.dt
            filtered = self._pole * self._rate + (1.0 - self._pole) * slope
            self._rate = np.where(np.isnan(self._previous), self._rate, filtered)
        self._previous = np.broadcast_to(y, self._previous.shape).copy()
        g, limit = self.gains, self.spec.limit
        integral = self.integral + error * self.spec.dt
        raw = g.kp * error + g.ki * integral - g.kd * self._rate
        command = np.clip(raw, -limit, limit)
        if self.anti_windup == "clamping":
            # Keep the new integral only where it does not push further into saturation.
            winding = (raw != command) & (np.sign(error) == np.sign(raw))
            integral = np.where(winding, self.integral, integral)
        elif self.anti_windup == "back-calculation" and self.tracking_time is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                bleed = (command - raw) * self.spec.dt / (g.ki * self.tracking_time)
            # Envs without an integral (ki = 0) have nothing to bleed.
            integral = integral + np.where(np.asarray(g.ki) > 0.0, bleed, 0.0)
        self.integral = np.asarray(integral, dtype=np.float64)
        return np.asarray(self.spec.direction * command, dtype=np.float64)

    def command(self, observation: FloatArray) -> FloatArray:  # noqa: D102
        reference, output, rate = self.spec.split(observation)
        return self.update(reference, output, rate if self.derivative == "velocity" else None)

    def take(self, index: npt.ArrayLike) -> PID:
        """Return a PID for the batch entries ``index`` only, with their gains and state.

        ``index`` is an integer array or boolean mask of the batch (the last axis of the state).
        The new PID continues exactly where these entries of this one stand, e.g. to stop
        stepping envs that are done.
        """
        if self.integral.ndim == 0:
            raise ValueError("take() needs a batched PID: call update() on a batch first")
        idx = np.asarray(index)
        pid = copy.copy(self)
        tt = self.tracking_time
        if self.gains.batched:
            pid.gains = self.gains.take(idx)
            if isinstance(tt, np.ndarray):
                pid.tracking_time = np.broadcast_to(tt, self.gains.shape)[idx]
        pid.integral = self.integral[..., idx]
        pid._rate = self._rate[..., idx]
        pid._previous = self._previous[..., idx]
        return pid

    def __repr__(self) -> str:
        g = self.gains
        if g.batched:
            return f"PID(batch of {int(np.prod(g.shape))} gain sets)"
        return f"PID(kp={g.kp:g}, ki={g.ki:g}, kd={g.kd:g})"
