"""Output-error refinement: fit the whole model to every recorded sample at once.

Where the sensor's range is too short for the body to reach a steady speed (the Altino's IR
sensor sees 18 cm of usable track), the steady map is biased. This step simulates every
constant run and ramp with the plant (the same compiled stick/slip kernel the envs run) under
candidate ``J``, ``B`` and friction levels, and moves them by ``least_squares`` until the
simulated positions match the measured ones. Each run gets its own position offset (the
measured start is quantised), removed in closed form. The dead time, a whole number of
periods, is chosen by the smallest residual.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from frictiongym.friction import StictionCoulomb
from frictiongym.identification.experiments import Trace
from frictiongym.plants.plant import Plant, PlantParams

FloatArray = npt.NDArray[np.float64]

#: Order of the refined parameters.
NAMES = ("J", "B", "us_pos", "us_neg", "uc_pos", "uc_neg", "v0_pos", "v0_neg")


@dataclass(frozen=True)
class Refinement:
    """Result of the output-error fit."""

    values: dict[str, float]  #: the keys of :data:`NAMES`
    stderr: dict[str, float]
    dead_time: float  #: chosen dead time, s
    rms: float  #: residual RMS, output units
    rms_start: float  #: residual RMS of the starting values


class _Simulator:
    """All traces replayed on one batch of plants."""

    def __init__(self, traces: Sequence[Trace], dt: float, limit: float, shape: str) -> None:
        self.traces = list(traces)
        self.dt = dt
        self.limit = limit
        self.shape = shape
        length = max(t.t.size for t in self.traces)
        self.commands = np.zeros((length, len(self.traces)))
        self.mask = np.zeros((length, len(self.traces)), dtype=bool)
        self.measured = np.zeros((length, len(self.traces)))
        for j, trace in enumerate(self.traces):
            n = trace.t.size
            self.commands[:n, j] = trace.command
            self.mask[:n, j] = trace.valid
            self.measured[:n, j] = trace.position
        self.count = np.maximum(self.mask.sum(axis=0), 1)

    def residual(self, x: FloatArray, delay_steps: int) -> FloatArray:
        inertia, damping, us_p, us_n, ratio_p, ratio_n, v0_p, v0_n = (float(v) for v in x)
        friction = StictionCoulomb(
            us_p,
            us_n,
            ratio_p * us_p,
            ratio_n * us_n,
            v0_p,
            v0_n,
            0.0,
            self.shape,  # type: ignore[arg-type]
        )
        params = PlantParams(inertia, damping, self.limit, dead_time=delay_steps * self.dt)
        plant = Plant(params, friction, self.dt, num_plants=len(self.traces), parallel=False)
        simulated = np.empty_like(self.measured)
        for k in range(self.commands.shape[0]):
            simulated[k] = plant.position
            plant.step(self.commands[k])
        error = np.where(self.mask, self.measured - simulated, 0.0)
        error -= np.where(self.mask, error.sum(axis=0) / self.count, 0.0)  # per-run offset
        return error[self.mask]


def refine(
    traces: Sequence[Trace],
    start: dict[str, float],
    dt: float,
    limit: float,
    shape: str = "linear",
    max_delay_steps: int = 3,
) -> Refinement:
    """Refine ``J``, ``B`` and the friction levels against every sample of ``traces``.

    Parameters
    ----------
    traces : sequence of Trace
        Constant runs and ramps (velocity steps work too).
    start : dict
        Starting values for :data:`NAMES` (from the map and the ramps).
    dt, limit : float
        Control period (s) and command limit of the device.
    shape : str, default "linear"
        Decay shape of the paper's law.
    max_delay_steps : int, default 3
        Dead times of 0 to this many periods are tried.
    """
    sim = _Simulator(traces, dt, limit, shape)
    # Coulomb levels as fractions of break-away, bounded by 1, so every trial law is valid.
    x0 = np.array([start[n] for n in NAMES], dtype=np.float64)
    x0[4] = min(start["uc_pos"] / start["us_pos"], 0.99)
    x0[5] = min(start["uc_neg"] / start["us_neg"], 0.99)
    lower = np.full(x0.size, 1e-9) * np.abs(x0)
    upper = np.full(x0.size, np.inf)
    upper[4:6] = 1.0

    def fitted(delay: int) -> Any:
        return least_squares(
            lambda x: sim.residual(x, delay), x0, bounds=(lower, upper), x_scale="jac",
            diff_step=1e-4,
        )  # fmt: skip

    # A local fit per dead time; the smallest final residual chooses it.
    delay, result = 0, fitted(0)
    for other in range(1, max_delay_steps + 1):
        candidate = fitted(other)
        if candidate.cost < result.cost:
            delay, result = other, candidate
    start_residual = sim.residual(x0, delay)
    resid = result.fun
    n, k = resid.size, x0.size
    ssr = float(resid @ resid)
    try:
        cov = np.linalg.inv(result.jac.T @ result.jac) * (ssr / max(n - k, 1))
    except np.linalg.LinAlgError:
        cov = np.full((k, k), math.nan)
    x = result.x
    # Back to levels: uc = ratio * us, its variance by the delta method.
    values = dict(zip(NAMES, (float(v) for v in x), strict=True))
    se = dict(zip(NAMES, (math.sqrt(max(float(c), 0.0)) for c in np.diag(cov)), strict=True))
    for i, direction in ((4, "pos"), (5, "neg")):
        j = 2 if direction == "pos" else 3
        grad = np.zeros(k)
        grad[i], grad[j] = x[j], x[i]
        values[f"uc_{direction}"] = float(x[i] * x[j])
        se[f"uc_{direction}"] = math.sqrt(max(float(grad @ cov @ grad), 0.0))
    return Refinement(
        values=values,
        stderr=se,
        dead_time=delay * dt,
        rms=math.sqrt(ssr / n),
        rms_start=math.sqrt(float(start_residual @ start_residual) / n),
    )
