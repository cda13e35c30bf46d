"""Output-error refinement: fit the whole model to every recorded sample at once.

Where the sensor's range is too short for the body to reach a steady speed (the Altino's IR
sensor sees 16 cm of usable track), the steady map is biased. This step simulates every
recorded run with the plant (the same compiled stick/slip kernel the envs run) under candidate
``J``, ``B`` and friction levels, and moves them by ``least_squares`` until the simulated
output matches the measured one.

* **Residuals in the sensor's own units.** A :class:`Reading` maps the output to what the
  sensor reads, where its noise is uniform: the IR's readout ``x = 966/d - 45`` has 2 counts
  of noise at every distance, which is 0.05 cm at 5 cm and 0.8 cm at 20 cm. Fitting readouts
  weights every sample by its resolution (the maximum-likelihood fit under white readout
  noise); fitting distances would let the far, coarse samples dominate.
* **Position offsets.** The measured start of a run is not known exactly, so each run gets
  its own offset, solved by Gauss-Newton inside every residual evaluation.
* **Stages.** A relay run drives back and forth for 20 s: a small error in the parameters
  piles up over its reversals, which makes the fit very precise near the optimum but its
  residual rugged far from it. The first stage therefore cuts every run where its command
  reverses and gives each segment its own offset. From the first stage's best few distinct
  minima, the next stages join 2, 4 and 8 segments under one offset, and the last has one
  offset per run; each starts from the previous one's result (a continuation). The first
  stage's many offsets bias it by a few per cent, sometimes by more than the last stage's
  basin is wide; the steps in between bridge that.
* **Multi-start.** In the first stage, parameter sets spread over broad ranges around the
  start (a scrambled Sobol sequence, fixed seed) are screened at each dead time of 0 to
  ``max_delay_steps`` periods, in one batched simulation per dead time; local fits start
  from the best few of each, and the lowest final residual wins. The residual of the
  paper's law has local minima: a kink ``v_0`` pushed beyond the measured speeds turns the
  low-speed branch into a straight line, and a lower ``B`` makes up for it; a kink at zero
  speed turns the decay into a sudden drop. So from the best two minima each direction's
  kink is also moved (along its low-speed branch, or at its Coulomb level), and fitted
  again from the best place.
* **Restarts.** Each local fit restarts from its own result until it stops improving: the
  stick/slip residual is only piecewise smooth, and a trust region shrunk on one kink can
  stop the solver early.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares
from scipy.stats import qmc

from frictiongym.controllers.rollout import Rollout
from frictiongym.friction import StictionCoulomb
from frictiongym.plants.plant import Plant, PlantParams
from frictiongym.plants.sensors import IR_MAX_READOUT, IR_NUMERATOR, IR_OFFSET, SENSOR_IR

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: Order of the refined parameters.
NAMES = ("J", "B", "us_pos", "us_neg", "uc_pos", "uc_neg", "v0_pos", "v0_neg")
#: Indices of the Coulomb-to-break-away ratios in the fitted vector (bounded by 1).
_RATIOS = (4, 5)
#: Gauss-Newton iterations of each segment's offset.
_OFFSET_ITERATIONS = 5
#: Segments sharing a position offset at each stage (0: one offset per run): the first stage
#: has one per segment, the last one per run.
_JOINS = (1, 2, 4, 8, 0)
#: Most runs of ``least_squares`` in one local fit (each from the last one's result).
_RESTARTS = 4
_TINY = 1e-300


class Reading(Protocol):
    """What a sensor reads at an output ``d`` (env units), with noise uniform in the reading."""

    def value(self, d: FloatArray) -> FloatArray:
        """Return the reading at ``d``."""
        ...

    def slope(self, d: FloatArray) -> FloatArray:
        """Return ``d value / d d``."""
        ...


@dataclass(frozen=True)
class LinearReading:
    """The output itself is read (an encoder): residuals in output units."""

    def value(self, d: FloatArray) -> FloatArray:
        """Return ``d`` itself."""
        return d

    def slope(self, d: FloatArray) -> FloatArray:
        """Return 1."""
        return np.ones_like(d)


@dataclass(frozen=True)
class ReciprocalReading:
    """A readout ``x = numerator / d - offset`` saturating at 0 and ``maximum``.

    The Altino's IR sensor (paper Eq. (1)): ``numerator`` 966, ``offset`` 45, ``maximum``
    800 (:mod:`frictiongym.plants.sensors`).
    """

    numerator: float
    offset: float
    maximum: float

    def _inside(self, d: FloatArray) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
        nearest = self.numerator / (self.maximum + self.offset)  # where it reads ``maximum``
        farthest = self.numerator / self.offset  # where it reads 0
        return np.clip(d, nearest, farthest), (d > nearest) & (d < farthest)

    def value(self, d: FloatArray) -> FloatArray:
        """Return the readout at ``d`` (``maximum`` at and below the nearest distance it reads)."""
        clipped, _ = self._inside(d)
        return self.numerator / clipped - self.offset

    def slope(self, d: FloatArray) -> FloatArray:
        """Return ``-numerator / d²`` inside the range, 0 where the readout saturates."""
        clipped, inside = self._inside(d)
        return np.where(inside, -self.numerator / clipped**2, 0.0)


def sensor_reading(device: Any) -> Reading | None:
    """Return what a device's sensor reads, where its noise is uniform (None: its output).

    The IR sensor's readout (paper Eq. (1)); an encoder reads the output itself.
    """
    if device.sensor == SENSOR_IR:
        return ReciprocalReading(IR_NUMERATOR, IR_OFFSET, IR_MAX_READOUT)
    return None


@dataclass(frozen=True)
class Refinement:
    """Result of the output-error fit."""

    values: dict[str, float]  #: the keys of :data:`NAMES` (and ``"W"`` with ``fit_play``)
    stderr: dict[str, float]
    dead_time: float  #: chosen dead time, s
    rms: float  #: residual RMS, reading units (the sensor's, see :class:`Reading`)
    rms_start: float  #: residual RMS of the starting values at the chosen dead time
    rms_split: float  #: first-stage residual RMS (an offset per segment) of the chosen minimum
    starts: int  #: local fits run in the first stage (multi-start)
    evaluations: int  #: simulations of all runs, screening and Jacobians included

    def estimate(self, name: str) -> tuple[float, float]:
        """Return the value of ``name`` and its standard error."""
        return self.values[name], self.stderr[name]

    def law(self, shape: str) -> StictionCoulomb:
        """Return the fitted paper law of decay ``shape``, ``B`` as its viscous slope."""
        v = self.values
        return StictionCoulomb(
            v["us_pos"],
            v["us_neg"],
            v["uc_pos"],
            v["uc_neg"],
            v["v0_pos"],
            v["v0_neg"],
            v["B"],
            shape,  # type: ignore[arg-type]
        )


def segments(command: FloatArray) -> IntArray:
    """Segment index of each sample: it grows by one where the command reverses its sign."""
    sign = np.sign(command)
    moving = sign[sign != 0.0]  # a zero command between two signs is no reversal
    reversal = np.zeros(command.size, dtype=np.int64)
    reversal[np.flatnonzero(sign)[1:][moving[1:] != moving[:-1]]] = 1
    return np.cumsum(reversal)


class _Simulator:
    """All traces replayed on batches of plants, one batch per parameter set or several."""

    def __init__(
        self,
        traces: Sequence[Rollout],
        dt: float,
        limit: float,
        shape: str,
        reading: Reading,
        direction: float,
        join: int,
        drivetrain: tuple[float, float, float] | None = None,
        zone: tuple[float, bool] = (0.0, False),
    ) -> None:
        self.dt = dt
        self.drivetrain = drivetrain
        self.zone = zone  # a dead zone's half-width, and whether x carries it last
        self.limit = limit
        self.shape = shape
        self.reading = reading
        self.direction = direction
        self.runs = len(traces)
        length = max(t.t.size for t in traces)
        self.commands = np.zeros((length, self.runs))
        mask = np.zeros((length, self.runs), dtype=bool)
        measured = np.zeros((length, self.runs))
        group = np.zeros((length, self.runs), dtype=np.int64)
        first = 0
        for j, trace in enumerate(traces):
            n = trace.t.size
            self.commands[:n, j] = trace.signal("command")
            mask[:n, j] = trace.signal("valid")
            measured[:n, j] = trace.plant_output()
            # ``join`` consecutive segments share an offset; 0: one offset for the whole run.
            ids = segments(trace.signal("command")) // join if join else np.zeros(n, dtype=np.int64)
            group[:n, j] = first + ids
            first += int(ids[-1]) + 1 if n else 0
        self.mask = mask
        self.measured = measured[mask]  # plant direction
        self.observed = reading.value(direction * self.measured)
        self.group = group[mask]
        self.groups = first
        # Start of each offset's Gauss-Newton: weights of the sensor's resolution.
        self.weight = np.maximum(reading.slope(direction * self.measured) ** 2, _TINY)
        self.weight_sum = np.bincount(self.group, self.weight, first)
        self.samples = int(self.measured.size)
        self.evaluations = 0

    def positions(self, xs: FloatArray, delay: int) -> FloatArray:
        """Simulate every valid sample for each parameter set: positions ``(P, samples)``."""
        params: list[PlantParams] = []
        frictions: list[StictionCoulomb] = []
        for x in np.atleast_2d(xs):
            inertia, damping, us_p, us_n, ratio_p, ratio_n, v0_p, v0_n = (
                float(v) for v in x[: len(NAMES)]
            )
            law = StictionCoulomb(
                us_p,
                us_n,
                min(ratio_p, 1.0) * us_p,
                min(ratio_n, 1.0) * us_n,
                v0_p,
                v0_n,
                0.0,
                self.shape,  # type: ignore[arg-type]
            )
            width_d, fitted = self.zone
            plant = PlantParams(
                inertia,
                damping,
                self.limit,
                dead_time=delay * self.dt,
                dead_zone=float(x[-1]) if fitted else width_d,
            )
            if self.drivetrain is not None:
                width, load_inertia, load_friction = self.drivetrain
                if x.size > len(NAMES) + fitted:  # the play is fitted: its width follows NAMES
                    width = float(x[len(NAMES)])
                plant = replace(
                    plant,
                    backlash=width,
                    load_inertia=load_inertia,
                    load_friction=load_friction,
                )
            params += [plant] * self.runs
            frictions += [law] * self.runs
        count = len(params) // self.runs
        plant_batch = Plant(params, frictions, self.dt, num_plants=len(params), parallel=False)
        commands = np.tile(self.commands, (1, count))
        out = np.empty((self.commands.shape[0], len(params)))
        for k in range(commands.shape[0]):
            out[k] = plant_batch.position
            plant_batch.step(commands[k])
        self.evaluations += count
        per_set = out.reshape(-1, count, self.runs).transpose(1, 0, 2)
        return np.stack([p[self.mask] for p in per_set])

    def residuals(self, positions: FloatArray) -> FloatArray:
        """Return reading residuals ``(P, samples)``, each segment's offset by Gauss-Newton."""
        out = np.empty_like(positions)
        g, n = self.group, self.groups
        for i, p in enumerate(positions):
            # Start: the offset in output units, weighted by the sensor's resolution.
            offset = np.bincount(g, self.weight * (self.measured - p), n) / self.weight_sum
            for _ in range(_OFFSET_ITERATIONS):
                d = self.direction * (offset[g] + p)
                r = self.observed - self.reading.value(d)
                grad = -self.direction * self.reading.slope(d)
                offset -= np.bincount(g, grad * r, n) / np.maximum(
                    np.bincount(g, grad * grad, n), _TINY
                )
            out[i] = self.observed - self.reading.value(self.direction * (offset[g] + p))
        return out

    def residual(self, x: FloatArray, delay: int) -> FloatArray:
        return self.residuals(self.positions(x[None, :], delay))[0]

    def jacobian(self, x: FloatArray, delay: int, rel_step: float = 1e-4) -> FloatArray:
        """Forward differences, all parameter sets in one batched simulation."""
        h = rel_step * np.maximum(np.abs(x), 1e-3)
        for i in _RATIOS:  # keep the ratios at or below 1
            if x[i] + h[i] > 1.0:
                h[i] = -h[i]
        xs = np.vstack([x, x + np.diag(h)])
        r = self.residuals(self.positions(xs, delay))
        return ((r[1:] - r[0]) / h[:, None]).T


def _candidates(x0: FloatArray, count: int, seed: int) -> FloatArray:
    """``x0`` and ``count - 1`` parameter sets spread over broad ranges around it.

    ``B`` within a factor of 4 of the start, the time constant ``J/B`` anywhere in 0.02–2 s
    (the map's ``J`` is the least reliable start value), ``u_s±`` within 5 %, the Coulomb
    levels at 30–98 % of break-away, the kinks ``v_0`` at a tenth to three times the speed
    scale ``u_s/B``. The sets are a scrambled Sobol sequence (``seed``), which covers the
    8-dimensional box more evenly than independent draws.
    """
    unit = qmc.Sobol(d=len(NAMES), scramble=True, seed=seed).random(count)

    def spread(column: int, low: float, high: float) -> FloatArray:
        return np.exp(math.log(low) + unit[:, column] * math.log(high / low))

    c = np.empty((count, x0.size))
    c[:, 1] = x0[1] * spread(1, 0.25, 4.0)
    c[:, 0] = c[:, 1] * spread(0, 0.02, 2.0)
    c[:, 2] = x0[2] * (0.95 + 0.1 * unit[:, 2])
    c[:, 3] = x0[3] * (0.95 + 0.1 * unit[:, 3])
    c[:, 4:6] = 0.3 + 0.68 * unit[:, 4:6]
    c[:, 6] = spread(6, 0.1, 3.0) * c[:, 2] / c[:, 1]
    c[:, 7] = spread(7, 0.1, 3.0) * c[:, 3] / c[:, 1]
    c[:, len(NAMES) :] = x0[len(NAMES) :]  # a fitted play starts where it is
    c[0] = x0
    return c


def _kink_moves(x: FloatArray, ratio_index: int, count: int = 24) -> FloatArray:
    """Parameter sets that move one direction's kink ``v_0`` and leave the rest of ``x``.

    Two families, each over kinks at a tenth to three times the speed scale ``u_s/B``:

    * along the low-speed branch: its slope ``(u_s - u_c)/v_0`` is kept (so
      ``u_c = u_s - slope v_0``), which changes the law above the old kink only;
    * at the same Coulomb level ``u_c``.

    They leave the degenerate minima of the paper's law: a kink beyond the measured speeds (a
    straight branch, a lower ``B`` making up for it), or at zero speed (a sudden drop).
    """
    us_index, v0_index = ratio_index - 2, ratio_index + 2
    us, ratio, v0 = x[us_index], x[ratio_index], x[v0_index]
    kinks = np.geomspace(0.1, 3.0, count) * us / x[1]
    along = 1.0 - (1.0 - ratio) * kinks / v0
    ratios = np.concatenate([along, np.full(count, ratio)])
    kinks = np.concatenate([kinks, kinks])
    keep = (ratios > 0.05) & (ratios < 0.999)
    moved = np.repeat(x[None, :], int(np.count_nonzero(keep)), axis=0)
    moved[:, ratio_index] = ratios[keep]
    moved[:, v0_index] = kinks[keep]
    return moved


def _distinct(found: list[tuple[float, int, Any]]) -> list[tuple[float, int, Any]]:
    """Return the minima of ``found`` (sorted by cost) whose costs differ by more than 1e-6."""
    distinct: list[tuple[float, int, Any]] = []
    for item in found:
        if all(abs(item[0] - other[0]) > 1e-6 * other[0] for other in distinct):
            distinct.append(item)
    return distinct


def _local_fit(
    sim: _Simulator, x0: FloatArray, delay: int, lower: FloatArray, upper: FloatArray
) -> Any:
    """``least_squares`` from ``x0`` at one dead time, with the batched Jacobian.

    The fit is restarted from its own result until that no longer lowers the residual: the
    stick/slip residual is only piecewise smooth, and a trust region that has shrunk on one
    kink can stop the solver (``ftol``) far from the minimum.
    """
    best: Any = None
    x = np.clip(x0, lower, upper)
    for _ in range(_RESTARTS):
        result = least_squares(
            lambda x: sim.residual(x, delay),
            x,
            jac=lambda x: sim.jacobian(x, delay),
            bounds=(lower, upper),
            x_scale="jac",
            max_nfev=100,
        )
        improved = best is None or result.cost < (1.0 - 1e-6) * best.cost
        if best is None or result.cost < best.cost:
            best = result
        if not improved:
            break
        x = result.x
    return best


def refine(
    traces: Sequence[Rollout],
    start: dict[str, float],
    dt: float,
    limit: float,
    shape: str = "linear",
    max_delay_steps: int = 3,
    reading: Reading | None = None,
    direction: float = 1.0,
    candidates: int = 128,
    local_fits: int = 2,
    polish: int = 3,
    seed: int = 0,
    drivetrain: tuple[float, float, float] | None = None,
    fit_play: bool = False,
    dead_zone: float | None = None,
    fit_zone: bool = False,
) -> Refinement:
    """Refine ``J``, ``B`` and the friction levels against every sample of ``traces``.

    Parameters
    ----------
    traces : sequence of Rollout
        Recorded runs (constant, ramp, relay; velocity steps work too).
    start : dict
        Starting values for :data:`NAMES` (from the map and the ramps).
    dt, limit : float
        Control period (s) and command limit of the device.
    shape : str, default "linear"
        Decay shape of the paper's law.
    max_delay_steps : int, default 3
        Dead times of 0 to this many periods are tried.
    reading : Reading, optional
        What the sensor reads at an output (residuals are taken there); the output itself
        by default.
    direction : float, default 1.0
        Sign that turns a trace's position (plant direction) into the env's output.
    candidates : int, default 128
        Parameter sets screened per dead time, the start included (a power of 2 keeps the
        Sobol sequence balanced).
    local_fits : int, default 2
        Local fits run from the best screened sets of each dead time.
    polish : int, default 3
        First-stage minima (the best distinct ones) continued through the later stages.
    seed : int, default 0
        Seed of the candidates' scrambling (fixed: the result does not depend on the env's
        seed).
    drivetrain : (float, float, float), optional
        A play in the simulated plant: its width and the load's shares of inertia and of
        friction (:mod:`~frictiongym.identification.backlash`); none by default.
    fit_play : bool, default False
        Fit the play's width too (from ``drivetrain``'s, as ``"W"`` in the result); the
        shares stay fixed.
    dead_zone : float, optional
        An actuator dead zone's half-width in the simulated plant (the levels are then the
        friction's own; :mod:`~frictiongym.identification.dead_zone`); none by default.
    fit_zone : bool, default False
        Fit the zone's half-width too (from ``dead_zone``, as ``"d"`` in the result).
    """
    if min(candidates, local_fits, polish) < 1:
        raise ValueError(
            f"candidates, local_fits and polish must be >= 1, got {candidates}, {local_fits}, "
            f"{polish}"
        )
    if not traces:
        raise ValueError("refine needs at least one trace")
    if fit_play and drivetrain is None:
        raise ValueError("fit_play needs a drivetrain: its width starts the fit, its shares stay")
    if fit_zone and dead_zone is None:
        raise ValueError("fit_zone needs a dead_zone: its half-width starts the fit")
    names = (*NAMES, *(("W",) if fit_play else ()), *(("d",) if fit_zone else ()))
    reading = reading or LinearReading()
    zone = (dead_zone or 0.0, fit_zone)
    ladder = [
        _Simulator(traces, dt, limit, shape, reading, direction, j, drivetrain, zone)
        for j in _JOINS
    ]
    sim, whole = ladder[0], ladder[-1]
    # Coulomb levels as fractions of break-away, bounded by 1, so every trial law is valid.
    x0 = np.array([start[n] for n in NAMES], dtype=np.float64)
    if drivetrain is not None and fit_play:
        x0 = np.append(x0, drivetrain[0])
    if dead_zone is not None and fit_zone:
        x0 = np.append(x0, max(dead_zone, 1e-6))  # the bounds keep it positive
    x0[4] = min(max(start["uc_pos"] / start["us_pos"], 0.05), 0.99)
    x0[5] = min(max(start["uc_neg"] / start["us_neg"], 0.05), 0.99)
    # A kink far beyond the speed scale us/B is a straight branch: no data can place it.
    x0[6:8] = np.clip(x0[6:8], 1e-3 * x0[2:4] / x0[1], 10.0 * x0[2:4] / x0[1])
    # Bounds: positive (a start far off must not bound the fit), the ratios at most 1.
    lower = np.full(x0.size, 1e-9)
    upper = np.full(x0.size, np.inf)
    upper[list(_RATIOS)] = 1.0
    pool = _candidates(x0, candidates, seed)
    found: list[tuple[float, int, Any]] = []  # first stage: (cost, delay, result)
    for delay in range(max_delay_steps + 1):
        costs = np.sum(sim.residuals(sim.positions(pool, delay)) ** 2, axis=1)
        costs = np.where(np.isfinite(costs), costs, np.inf)
        for i in np.argsort(costs, kind="stable")[:local_fits]:
            result = _local_fit(sim, pool[i], delay, lower, upper)
            found.append((float(result.cost), delay, result))
    found.sort(key=lambda item: item[0])
    # Move each direction's kink from the best two distinct minima.
    for _, delay, result in _distinct(found)[:2]:
        for ratio_index in _RATIOS:
            moved = _kink_moves(result.x, ratio_index)
            if moved.size:
                costs = np.sum(sim.residuals(sim.positions(moved, delay)) ** 2, axis=1)
                better = _local_fit(sim, moved[int(np.nanargmin(costs))], delay, lower, upper)
                found.append((float(better.cost), delay, better))
    found.sort(key=lambda item: item[0])
    # The later stages from the best distinct first-stage minima, through ever fewer offsets
    # to one per run (a continuation: each stage's minimum lies in the next one's basin); the
    # lowest final residual wins.
    distinct = _distinct(found)
    best: Any = None
    best_delay = 0
    first: Any = None
    for _, delay, result in distinct[:polish]:
        polished = result
        for step in ladder[1:]:
            polished = _local_fit(step, polished.x, delay, lower, upper)
        if best is None or polished.cost < best.cost:
            best, best_delay, first = polished, delay, result
    start_residual = whole.residual(x0, best_delay)
    resid = best.fun
    n, k = resid.size, x0.size
    ssr = float(resid @ resid)
    try:
        cov = np.linalg.inv(best.jac.T @ best.jac) * (ssr / max(n - k - whole.groups, 1))
    except np.linalg.LinAlgError:
        cov = np.full((k, k), math.nan)
    x = best.x
    # Back to levels: uc = ratio * us, its variance by the delta method.
    values = dict(zip(names, (float(v) for v in x), strict=True))
    se = dict(zip(names, (math.sqrt(max(float(c), 0.0)) for c in np.diag(cov)), strict=True))
    for i, j, direction_name in zip(_RATIOS, (2, 3), ("pos", "neg"), strict=True):
        grad = np.zeros(k)
        grad[i], grad[j] = x[j], x[i]
        values[f"uc_{direction_name}"] = float(x[i] * x[j])
        se[f"uc_{direction_name}"] = math.sqrt(max(float(grad @ cov @ grad), 0.0))
    return Refinement(
        values=values,
        stderr=se,
        dead_time=best_delay * dt,
        rms=math.sqrt(ssr / n),
        rms_start=math.sqrt(float(start_residual @ start_residual) / n),
        rms_split=math.sqrt(2.0 * float(first.cost) / n),
        starts=len(found),
        evaluations=sum(step.evaluations for step in ladder),
    )
