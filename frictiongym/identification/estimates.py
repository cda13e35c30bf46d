"""What each experiment measures: a steady velocity, a break-away level, a first-order step.

Every estimator takes one experiment's :class:`~frictiongym.controllers.Rollout` and uses
only its valid samples. The models are the ones a first-order plant ``J v' + b v = u - F`` gives in
one sliding branch of friction (docs/identification.md):

* a constant input from rest ends on ``y = a + v t + c exp(-t / tau)``, whatever happened
  before (break-away, the decay from ``u_s``), once the body is in one branch;
* a ramp ``rho t`` breaks the body free when it reaches ``u_s``; after that
  ``J v' + b' v = rho s`` with ``b'`` the slope of the friction map at rest;
* a step between two levels in one branch is first order with ``tau = J / b``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import brentq, minimize_scalar

from frictiongym.controllers.rollout import Rollout
from frictiongym.identification.experiments import REST_SAMPLES, rest_scatter

FloatArray = npt.NDArray[np.float64]


class IdentificationError(ValueError):
    """An experiment's data cannot give the estimate asked for (says what to change)."""


@dataclass(frozen=True)
class ExponentialFit:
    """``y = a + v t + c exp(-(t - t0) / tau)`` fitted by separable least squares."""

    velocity: float  #: final velocity ``v``, output units per s
    velocity_se: float  #: its standard error
    tau: float  #: time constant, s
    offset: float
    amplitude: float
    start: float  #: ``t0``: first time of the window, s
    rms: float  #: residual RMS, output units
    samples: int


def _basis(t: FloatArray, t0: float, tau: float) -> FloatArray:
    return np.column_stack([np.ones_like(t), t - t0, np.exp(-(t - t0) / tau)])


def fit_exponential(
    t: FloatArray, y: FloatArray, tau_max: float, weight: FloatArray | None = None
) -> ExponentialFit:
    """Fit ``a + v (t - t0) + c exp(-(t - t0)/tau)`` to samples, ``tau`` in ``(0, tau_max]``.

    For each ``tau`` the other three parameters are linear; ``tau`` minimises the residual.
    ``weight`` (one per sample, default 1) weights the squared residuals: the inverse noise
    variance of each sample, for a sensor whose resolution varies along the run.
    """
    if t.size < 6:
        raise IdentificationError(
            f"{t.size} valid samples are too few for a first-order fit (need 6 or more): "
            "lengthen the run or, for a short sensor range, lower the command level"
        )
    t0 = float(t[0])
    span = float(t[-1] - t0)
    dt = span / (t.size - 1)
    root = np.ones_like(y) if weight is None else np.sqrt(weight / np.mean(weight))

    def residual(log_tau: float) -> float:
        basis = _basis(t, t0, math.exp(log_tau)) * root[:, None]
        coef, *_ = np.linalg.lstsq(basis, y * root, rcond=None)
        return float(np.sum((basis @ coef - y * root) ** 2))

    lo, hi = math.log(0.5 * dt), math.log(tau_max)
    best = minimize_scalar(residual, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    tau = math.exp(float(best.x))
    basis = _basis(t, t0, tau) * root[:, None]
    coef, *_ = np.linalg.lstsq(basis, y * root, rcond=None)
    resid = basis @ coef - y * root
    dof = max(t.size - 4, 1)
    sigma2 = float(resid @ resid) / dof
    cov = np.linalg.pinv(basis.T @ basis) * sigma2
    return ExponentialFit(
        velocity=float(coef[1]),
        velocity_se=math.sqrt(max(float(cov[1, 1]), 0.0)),
        tau=tau,
        offset=float(coef[0]),
        amplitude=float(coef[2]),
        start=t0,
        rms=math.sqrt(float(resid @ resid) / t.size),
        samples=int(t.size),
    )


@dataclass(frozen=True)
class SteadyPoint:
    """One point of the steady-state friction map: the level held and the speed it reached."""

    level: float  #: command magnitude, command units
    velocity: float  #: steady speed magnitude, output units per s (0: it never moved)
    velocity_se: float
    tau: float  #: time constant of the approach, s (nan when it never moved)
    moved: bool
    sign: float
    transient: float = 0.0  #: size of the fitted transient over the residual RMS


def steady_velocity(
    trace: Rollout,
    skip: float = 0.4,
    tau_max: float = 2.0,
    weight: Callable[[FloatArray], FloatArray] | None = None,
) -> SteadyPoint:
    """Steady speed of a constant-input run (magnitude, in the level's direction).

    Parameters
    ----------
    trace : Rollout
        A ``constant`` experiment.
    skip : float, default 0.4
        Fraction of the valid samples, from the start, left out of the fit: early on the body
        may still be in the low-speed branch of the friction curve. A run whose output moved
        less than ten times the scatter of its first samples is reported as stuck.
    tau_max : float, default 2.0
        Largest time constant considered, s.
    weight : callable, optional
        ``weight(positions)``: each sample's weight in the fit (its inverse noise variance,
        up to a factor); equal weights by default.
    """
    level, sign = abs(trace.settings["level"]), trace.settings["sign"]
    y = trace.plant_output()
    index = np.flatnonzero(trace.signal("valid"))
    if index.size < 6:  # (almost) nothing in the sensor's range
        return SteadyPoint(level, 0.0, 0.0, math.nan, False, sign)
    head = y[index[: min(5, index.size)]]
    tail = y[index[-min(10, index.size) :]]
    scatter = rest_scatter(head, y[index])
    if abs(tail.mean() - head.mean()) <= 10.0 * scatter:
        return SteadyPoint(level, 0.0, 0.0, math.nan, False, sign)
    index = index[int(skip * index.size) :]
    w = None if weight is None else weight(y[index])
    fit = fit_exponential(trace.t[index], y[index], tau_max, w)
    transient = abs(fit.amplitude) / max(fit.rms, 1e-300)
    return SteadyPoint(level, sign * fit.velocity, fit.velocity_se, fit.tau, True, sign, transient)


def onset_displacement(s: float, rate: float, inertia: float, slope: float) -> float:
    """Displacement ``s`` seconds after break-away under a ramp of ``rate`` (command units/s).

    Solves ``J v' + b' v = rate s`` from rest: ``(rate/b')(s²/2 - tau s + tau² (1 -
    exp(-s/tau)))`` with ``tau = J/b'``; ``rate s³ / (6 J)`` when ``b' <= 0`` is negligible.
    """
    if slope <= 0.0 or s * slope / inertia < 1e-6:
        return rate * s**3 / (6.0 * inertia)
    tau = inertia / slope
    return (rate / slope) * (0.5 * s * s - tau * s - tau * tau * math.expm1(-s / tau))


@dataclass(frozen=True)
class Breakaway:
    """Break-away level of one ramp."""

    level: float  #: command magnitude at which the body broke free
    detected: float  #: command magnitude when the motion was first detected
    sign: float


def breakaway_level(
    trace: Rollout,
    inertia: float | None = None,
    slope: float = 0.0,
    thresholds: tuple[float, ...] = (6.0, 9.0, 12.0),
) -> Breakaway:
    """Break-away level of a ramp from rest.

    The motion is detected when the displacement from rest first exceeds each of
    ``thresholds`` (multiples of the rest scatter). Each detection time is moved back to the
    onset by :func:`onset_displacement` (with ``inertia`` and the map's slope at rest
    ``slope``); without ``inertia`` the detection itself is taken, which over-estimates the
    level by about ``rate`` times the detection delay.
    """
    rate, start = trace.settings["rate"], trace.settings["start"]
    y = trace.plant_output()
    rest = y[:REST_SAMPLES]
    if y.size < REST_SAMPLES + 5:
        raise IdentificationError(
            "the ramp moved the body within its first 20 samples: start it lower (a smaller "
            "ramp 'start' level) so the rest position can be measured"
        )
    scatter = max(rest_scatter(rest, y), 1e-12)
    base = float(rest.mean())
    displacement = np.abs(y - base)
    onsets: list[float] = []
    detected = math.nan
    for factor in thresholds:
        level = factor * scatter
        above = np.flatnonzero(trace.signal("valid") & (displacement > level))
        if above.size == 0 or above[0] == 0:
            continue
        k = int(above[0])
        d0, d1 = displacement[k - 1], displacement[k]
        t_cross = trace.t[k - 1] + (level - d0) / (d1 - d0) * (trace.t[k] - trace.t[k - 1])
        if math.isnan(detected):
            detected = start + rate * t_cross
        delay = 0.0
        if inertia is not None:
            s_max = max(1.0, 10.0 * t_cross)
            delay = brentq(
                lambda s, x=level: onset_displacement(s, rate, inertia, slope) - x, 0.0, s_max
            )
        onsets.append(t_cross - delay)
    if not onsets:
        raise IdentificationError(
            "the ramp ended before the body moved: raise the ramp's end level or its duration"
        )
    return Breakaway(float(start + rate * np.mean(onsets)), float(detected), trace.settings["sign"])


@dataclass(frozen=True)
class StepResponse:
    """A velocity step between two levels in one sliding branch."""

    first: float  #: command before the step (signed)
    second: float  #: command after it (signed)
    velocity_before: float  #: steady speed before the step (signed)
    velocity_after: float
    tau: float  #: time constant after the step, s

    @property
    def damping(self) -> float:
        """``b = du / dv``: the total linear damping the step sees, command units per speed."""
        return (self.second - self.first) / (self.velocity_after - self.velocity_before)

    @property
    def inertia(self) -> float:
        """``J = tau b``."""
        return self.tau * self.damping


def velocity_step(trace: Rollout, tau_max: float = 2.0) -> StepResponse:
    """First-order response of a ``step`` experiment (both levels in the high-speed branch)."""
    step_time = trace.settings["step_time"]
    valid = trace.signal("valid")
    before = np.flatnonzero(valid & (trace.t < step_time) & (trace.t >= 0.5 * step_time))
    after = np.flatnonzero(valid & (trace.t >= step_time))
    if before.size < 6 or after.size < 6:
        raise IdentificationError(
            "the velocity step left too few valid samples before or after the step: lengthen "
            "the run, or lower the levels so the body stays in the sensor's range"
        )
    fit_before = fit_exponential(trace.t[before], trace.plant_output()[before], tau_max)
    fit_after = fit_exponential(trace.t[after], trace.plant_output()[after], tau_max)
    return StepResponse(
        first=trace.settings["first"],
        second=trace.settings["second"],
        velocity_before=fit_before.velocity,
        velocity_after=fit_after.velocity,
        tau=fit_after.tau,
    )
