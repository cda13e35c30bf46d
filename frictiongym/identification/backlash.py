"""The reversal test: estimate a play between motor and load from the load's position alone.

**Experiment** (:meth:`~frictiongym.identification.experiments.Runner.reversals`). From rest,
a constant command beyond break-away is held until the pair slides steadily, then the command
reverses, several times in both directions. While the pair slides, the motor presses the load
on one face of the play, so the state before a reversal does not depend on the play. After
it, the motor leaves that face, crosses the play with its own share of the inertia and
friction while the load runs on with its own, and the two meet on the other face (docs/
physics.md, "Backlash"). The load's path after the reversal depends on the play only
through that crossing.

**Estimator** (:func:`estimate_backlash`). The identified rigid model (``J``, ``B``, the
paper's law) is split into motor and load by assumed shares (the device preset's, from its
description: they cannot be measured with the load's sensor alone), and the recorded command
is replayed on plants with candidate widths ``W``. Each reversal gets a window from the middle
of the leg before it to the middle of the leg after it, with its own position offset; the
misfit is the sum of squared residuals in the sensor's reading (encoder: position; IR
sensor: readout counts, where its noise is uniform). The response is not smooth in ``W``
everywhere (a crossing that ends before or after a sample, a separation that does or does
not happen), so a coarse grid over the search range comes first, a fine grid around its best
point second, and a bounded scalar minimisation between the fine grid's neighbours last.

**Uncertainty.** Each reversal is also fitted alone (the minimum of its own misfit on the
grids, refined by a parabola): the reversals are repeats from the same steady state, so the
standard error of the pooled estimate is their scatter over ``sqrt(n)``. It covers the noise,
not a bias of the rigid model or of the shares.

**Resolution.** The smallest play the test can resolve is the smallest width whose simulated
path after a reversal departs from the rigid one by one sensor step (an encoder count, one
readout count): below it the play hides in the quantisation. An estimate below that bound,
or within two standard errors of zero, is reported as not resolved, with the bound.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import minimize_scalar

from frictiongym import devices
from frictiongym.controllers.rollout import Rollout
from frictiongym.identification.experiments import Runner
from frictiongym.identification.refine import LinearReading, Reading
from frictiongym.params import DeviceParams, device_physics
from frictiongym.plants.plant import Plant, PlantParams

FloatArray = npt.NDArray[np.float64]

#: Why a run gives no window to fit.
NO_WINDOWS = (
    "the run holds no reversal with a leg of at least three valid samples on each side: run "
    "Runner.reversals, with a hold of several control periods"
)
#: Gauss-Newton iterations of each window's position offset (one is exact for an encoder).
_OFFSET_ITERATIONS = 4
_TINY = 1e-300


@dataclass(frozen=True)
class ReversalPlan:
    """The reversal test of one device.

    Attributes
    ----------
    level : float
        Command of each leg as a multiple of that direction's break-away level.
    hold : float
        Longest leg, s: several time constants, so each reversal starts from steady sliding.
    reversals : int
        Reversals of the command (half in each direction).
    max_width : float
        Widest play searched, position units.
    resolution : float
        One sensor step in reading units: an encoder count (position units), or one readout
        count of a :class:`~frictiongym.identification.refine.ReciprocalReading`.
    band : tuple of float, optional
        Output range (env units) the legs stay in: a leg also reverses when it reaches the
        end it moves toward (a sensor of short range).
    grid : int
        Widths on each of the two grids.
    shares : (float, float), optional
        The load's shares of the inertia and of the friction and damping the estimate assumes
        (default: the device preset's). They cannot be measured with the load's sensor, and the
        estimate depends on them.
    """

    level: float
    hold: float
    reversals: int
    max_width: float
    resolution: float
    band: tuple[float, float] | None = None
    grid: int = 41
    shares: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        problems = [
            f"{name}={value!r} must be {rule}"
            for name, value, rule, good in (
                ("level", self.level, "> 1 (a multiple of break-away)", self.level > 1.0),
                ("hold", self.hold, "> 0 s", self.hold > 0.0),
                ("reversals", self.reversals, "an integer >= 1", self.reversals >= 1),
                ("max_width", self.max_width, "> 0", self.max_width > 0.0),
                ("resolution", self.resolution, "> 0", self.resolution > 0.0),
                # Fewer points snap each reversal's own fit to the grid: a false scatter.
                ("grid", self.grid, "an integer >= 11", self.grid >= 11),
            )
            if not good
        ]
        if self.shares is not None:
            psi, phi = self.shares
            if not (0.0 < psi < 1.0 and 0.0 <= phi <= 1.0):
                problems.append(
                    f"shares={self.shares!r} must be (load_inertia, load_friction) with "
                    "0 < load_inertia < 1 and 0 <= load_friction <= 1"
                )
        if problems:
            raise ValueError(f"ReversalPlan: {'; '.join(problems)}")

    @classmethod
    def for_device(cls, device: str | devices.Device) -> ReversalPlan:
        """Return the reversal test of ``device`` (any spelling of :func:`devices.get`).

        It is the ``reversal`` entry of the device's ``identification`` settings: this class's
        fields, ``band`` and ``shares`` as tuples.

        Raises
        ------
        ValueError
            If the device has no reversal test.
        """
        described = devices.get(device)
        settings = described.identification.get("reversal")
        if not settings:
            raise ValueError(
                f"{described.name} has no reversal test: its Device.identification "
                "(frictiongym/devices.py) has no 'reversal' entry; give a ReversalPlan"
            )
        return cls(**settings)


@dataclass(frozen=True, kw_only=True)
class ReversalEstimate:
    """One quantity fitted to a reversal run (:func:`fit_scalar`): a play's, a zone's width.

    ``width`` is the best fit whether or not it is resolved; :attr:`value` is it only when
    it is. Residuals are in reading units.
    """

    width: float  #: pooled estimate
    stderr: float  #: scatter of the per-reversal estimates over sqrt(n) (nan: one reversal)
    resolved: bool  #: at least ``bound``, two standard errors from zero, inside the search
    bound: float  #: smallest value the test resolves: one sensor step of effect (inf: none)
    upper: float  #: when too small to resolve, the value is below this; nan otherwise
    per_reversal: tuple[float, ...]  #: each reversal's own estimate
    rms: float  #: residual RMS at ``width``
    rms_rigid: float  #: residual RMS at 0 (no play, no zone)
    search: tuple[float, float]  #: the values searched
    unit: str  #: of the width
    trace: Rollout = field(compare=False, repr=False)  #: the reversal run
    note: str = ""  #: why the number was not resolved
    #: the width the output-error refinement fitted with the rigid model (plans that refine;
    #: a cross-check from other runs, nan otherwise)
    refinement_width: float = math.nan

    @property
    def value(self) -> float | None:
        """The width if resolved, else None."""
        return self.width if self.resolved else None

    def _describe(self, name: str, symbol: str, detail: str, tail: str) -> str:
        """One line: ``name symbol = width ± s.e. detail``, or why it is not resolved."""
        if self.resolved:
            return (
                f"{name} {symbol} = {self.width:.4g} {self.unit} ± {self.stderr:.2g} {detail}{tail}"
            )
        if math.isnan(self.upper):
            return f"{name} not resolved: {self.note} (best fit {self.width:.3g}){tail}"
        return (
            f"{name} not resolved: {symbol} < {self.upper:.3g} {self.unit} (best fit "
            f"{self.width:.3g}; {self.note}){tail}"
        )

    def record(self) -> dict[str, Any]:
        """Metadata of the estimate for the parameter file."""
        return {
            "resolved": self.resolved,
            "width": self.width,
            "stderr": self.stderr,
            "bound": self.bound,
            "upper": self.upper,
            "note": self.note,
            "per_reversal": list(self.per_reversal),
            "rms": self.rms,
            "rms_rigid": self.rms_rigid,
            "search": list(self.search),
            "refinement_width": self.refinement_width,
        }


@dataclass(frozen=True, kw_only=True)
class BacklashEstimate(ReversalEstimate):
    """The result of a reversal test: the play's full width ``W``, position units."""

    directions: tuple[float, ...]  #: sign of the command after each reversal
    load_inertia: float  #: the assumed load share of J
    load_friction: float  #: the assumed load share of friction and damping
    shares_from: str  #: where the shares come from (an assumption either way)
    dead_time: float  #: of the replayed plant, s
    #: widths of the earlier rounds, each before the rigid model was refitted with the play
    earlier: tuple[float, ...] = ()

    def describe(self) -> str:
        """One line: the width and its standard error, or the bound, and the assumptions."""
        shares = (
            f", assuming the load carries {self.load_inertia:g} of J and "
            f"{self.load_friction:g} of the friction ({self.shares_from}, not measured; W "
            "depends on them)"
        )
        detail = "(1 s.e. of the noise, not of the rigid model's errors)"
        return self._describe("play", "W", detail, shares)

    def record(self) -> dict[str, Any]:
        """Metadata of the test for the parameter file."""
        return {
            **super().record(),
            "assumed_shares": {
                "load_inertia": self.load_inertia,
                "load_friction": self.load_friction,
                "source": f"{self.shares_from}, not measured",
            },
            "directions": list(self.directions),
            "dead_time": self.dead_time,
            "earlier_rounds": list(self.earlier),
            "settings": dict(self.trace.settings),
        }


def reversal_test(
    runner: Runner,
    rigid: DeviceParams,
    breakaway: tuple[float, float],
    plan: ReversalPlan,
    *,
    reading: Reading | None = None,
    dead_time: float | None = None,
) -> BacklashEstimate:
    """Run the reversal experiment through ``runner`` and estimate the play.

    Parameters
    ----------
    runner : Runner
        The identification's runner (its env and span).
    rigid : DeviceParams
        The rigid identification: ``J``, ``B`` and the law (with the event-exact step).
    breakaway : (float, float)
        Break-away levels forward and backward, magnitudes.
    plan : ReversalPlan
    reading, dead_time
        See :func:`estimate_backlash`.
    """
    limit = 0.95 * runner.spec.limit
    up, down = (min(plan.level * level, limit) for level in breakaway)
    trace = runner.reversals(up, down, plan.hold, plan.reversals, band=plan.band)
    return estimate_backlash(
        trace, rigid, plan, reading=reading, dead_time=dead_time, dt=runner.spec.dt
    )


def estimate_backlash(
    trace: Rollout,
    rigid: DeviceParams,
    plan: ReversalPlan,
    *,
    dt: float,
    reading: Reading | None = None,
    dead_time: float | None = None,
) -> BacklashEstimate:
    """Fit the play's width to a reversal run (the module's description has the method).

    Parameters
    ----------
    trace : Rollout
        The reversal run (:meth:`Runner.reversals`).
    rigid : DeviceParams
        The rigid identification; its ``device`` names the device whose preset supplies
        the plant's other settings and, by default, the shares.
    plan : ReversalPlan
        Search range, grid, sensor step and the assumed shares.
    dt : float
        Control period of the run, s.
    reading : Reading, optional
        What the sensor reads at an output (default: the output itself).
    dead_time : float, optional
        Of the replayed plant, s (default: the device preset's; the Altino's refinement
        measures one).

    Raises
    ------
    ValueError
        If the run holds no reversal, the law has no event-exact step, or a share is bad.
    """
    if rigid.device is None:
        raise ValueError("the rigid identification names no device: set DeviceParams.device")
    device = devices.get(rigid.device)
    _, law, _, base = device_physics(device, dt, params=replace(rigid, backlash=None))
    if not law.exact:
        raise ValueError(
            f"the reversal test replays the law with the event-exact step (paper with a linear "
            f"decay, or coulomb), got {law!r}"
        )
    preset = (device.plant.load_inertia, device.plant.load_friction)
    psi, phi = preset if plan.shares is None else plan.shares
    base = replace(
        base,
        end_stop=math.inf,  # the run stays inside its band; offsets place it
        dead_time=base.dead_time if dead_time is None else round(dead_time / dt) * dt,
        load_inertia=psi,  # PlantParams checks the shares
        load_friction=phi,
    )
    data = ReversalData(trace, reading or LinearReading())
    if not data.windows:
        raise ValueError(NO_WINDOWS)

    def simulate(widths: FloatArray) -> FloatArray:
        params = [replace(base, backlash=float(w)) for w in widths]
        return replay(data.command, params, law, dt)

    fit = fit_scalar(
        data,
        simulate,
        plan,
        plan.max_width,
        "the play is at least this wide, and biases the rigid parameters: raise "
        "--max-backlash (ReversalPlan.max_width)",
        device.position_unit,
    )
    return BacklashEstimate(
        **fit.fields(search=(0.0, plan.max_width), unit=device.position_unit, trace=trace),
        directions=tuple(data.directions),
        load_inertia=psi,
        load_friction=phi,
        shares_from="the device preset's" if plan.shares is None else "ReversalPlan.shares",
        dead_time=base.dead_time,
    )


@dataclass(frozen=True)
class ScalarFit:
    """One quantity fitted to a reversal run by :func:`fit_scalar`."""

    value: float  #: pooled best fit
    stderr: float  #: scatter of the per-reversal fits over sqrt(n) (nan: one reversal)
    per_reversal: tuple[float, ...]  #: each reversal's own fit
    bound: float  #: smallest value whose effect reaches one sensor step (inf: none)
    upper: float  #: when not resolved, the value is below this; nan otherwise
    note: str  #: why the value is not resolved ("" if it is)
    rms: float  #: residual RMS at ``value``, reading units
    rms_zero: float  #: residual RMS at 0 (no play, no zone)

    def fields(self, **context: Any) -> dict[str, Any]:
        """Return the :class:`ReversalEstimate` fields of this fit, and ``context``'s."""
        return {
            "width": self.value,
            "stderr": self.stderr,
            "resolved": not self.note,
            "bound": self.bound,
            "upper": self.upper,
            "per_reversal": self.per_reversal,
            "rms": self.rms,
            "rms_rigid": self.rms_zero,
            "note": self.note,
            **context,
        }


def fit_scalar(
    data: ReversalData,
    simulate: Callable[[FloatArray], FloatArray],
    plan: ReversalPlan,
    high: float,
    end_hint: str,
    unit: str,
) -> ScalarFit:
    """Fit one quantity in ``[0, high]`` whose 0 is the rigid model (a play's width, a zone).

    ``simulate`` maps candidate values to replayed positions ``(samples, values)``. A coarse
    grid, a fine grid around its best point and a bounded minimisation between the fine
    grid's neighbours give the pooled fit; each reversal is fitted alone on the grids for
    the standard error, and the effect of each coarse value on the path gives the
    resolution bound (the module's description). ``end_hint`` says what a best fit at
    ``high`` means, ``unit`` is the quantity's.
    """
    coarse = np.linspace(0.0, high, plan.grid)
    coarse_positions = simulate(coarse)
    coarse_costs = data.costs(coarse_positions)  # (windows, values)
    best = int(np.argmin(coarse_costs.sum(axis=0)))
    step = coarse[1] - coarse[0]
    fine = np.linspace(max(coarse[best] - step, 0.0), min(coarse[best] + step, high), plan.grid)
    fine_costs = data.costs(simulate(fine))
    # Both grids, sorted, each value once (the fine grid's ends are coarse points).
    values, first = np.unique(np.concatenate([coarse, fine]), return_index=True)
    costs = np.concatenate([coarse_costs, fine_costs], axis=1)[:, first]
    # Pooled: a bounded minimisation between the neighbours of the fine grid's best point.
    i = int(np.argmin(fine_costs.sum(axis=0)))
    low, top = fine[max(i - 1, 0)], fine[min(i + 1, fine.size - 1)]
    result = minimize_scalar(
        lambda w: float(data.costs(simulate(np.array([w]))).sum()),
        bounds=(low, top),
        method="bounded",
        options={"xatol": 1e-3 * (fine[1] - fine[0])},
    )
    pooled, misfit = float(fine[i]), float(fine_costs.sum(axis=0)[i])
    if result.fun <= misfit:
        pooled, misfit = float(result.x), float(result.fun)
    per_reversal = tuple(_parabola_min(values, c) for c in costs)
    n = len(per_reversal)
    stderr = float(np.std(per_reversal, ddof=1) / math.sqrt(n)) if n > 1 else math.nan
    bound = _resolution_bound(coarse, data.effects(coarse_positions), plan.resolution)
    note, upper = "", math.nan
    if pooled >= high - (fine[1] - fine[0]):
        note = f"the best fit lies at the end of the search range, {high:g} {unit}: {end_hint}"
    elif not math.isfinite(bound):
        note = "no value in the search range moves the load by one sensor step"
    elif pooled < bound or (n > 1 and pooled <= 2.0 * stderr):
        note = (
            "its effect on the load's path is below one sensor step"
            if pooled < bound
            else "within two standard errors of zero"
        )
        upper = max(bound, pooled + 2.0 * (stderr if n > 1 else 0.0))
    samples = data.samples
    return ScalarFit(
        value=pooled,
        stderr=stderr,
        per_reversal=per_reversal,
        bound=bound,
        upper=upper,
        note=note,
        rms=math.sqrt(misfit / samples),
        rms_zero=math.sqrt(float(coarse_costs[:, 0].sum()) / samples),
    )


def replay(command: FloatArray, params: Sequence[PlantParams], law: Any, dt: float) -> FloatArray:
    """Positions ``(samples, plants)`` before each command, every plant from rest at 0."""
    plant = Plant(list(params), law, dt, num_plants=len(params), parallel=False)
    out = np.empty((command.size, len(params)))
    u = np.empty(len(params))
    for k, level in enumerate(command):
        out[k] = plant.position
        u[:] = level
        plant.step(u)
    return out


class ReversalData:
    """The measured run cut into one window per reversal, and the misfit of simulations."""

    def __init__(self, trace: Rollout, reading: Reading) -> None:
        self.command = np.asarray(trace.signal("command"), dtype=np.float64)
        self.reading = reading
        self.direction = trace.direction
        measured = trace.plant_output()
        valid = np.asarray(trace.signal("valid"), dtype=bool)
        sign = np.sign(self.command)
        moving = np.flatnonzero(sign)
        turns = moving[1:][sign[moving[1:]] != sign[moving[:-1]]]  # first sample of each leg
        edges = np.concatenate([[0], turns, [self.command.size]])
        middles = (edges[:-1] + edges[1:]) // 2
        # Window j: from the middle of the leg before reversal j to the middle of the next.
        # (Shorter windows were tried: they lose samples without making the estimate less
        # sensitive to the rigid model, whose errors act on the overshoot itself.)
        self.windows: list[tuple[npt.NDArray[np.int64], int]] = []
        self.directions: list[float] = []
        for j, turn in enumerate(turns):
            idx = np.arange(middles[j], middles[j + 1])
            idx = idx[valid[idx]]
            if idx.size > 2:
                self.windows.append((idx, int(turn)))
                self.directions.append(float(sign[turn]))
        self.measured = measured
        self.observed = reading.value(self.direction * measured)
        self.samples = sum(idx.size for idx, _ in self.windows)

    def _offset(self, target: FloatArray, simulated: FloatArray) -> FloatArray:
        """Per width (columns), the offset that best lays ``simulated`` on ``target`` readings."""
        d = self.direction
        weight = np.maximum(self.reading.slope(d * target)[:, None] ** 2, _TINY)
        offset = (weight * (target[:, None] - simulated)).sum(0) / weight.sum(0)
        observed = self.reading.value(d * target)[:, None]
        for _ in range(_OFFSET_ITERATIONS):
            where = d * (simulated + offset)
            residual = observed - self.reading.value(where)
            grad = -d * self.reading.slope(where)
            offset -= (grad * residual).sum(0) / np.maximum((grad * grad).sum(0), _TINY)
        return offset

    def costs(self, positions: FloatArray) -> FloatArray:
        """Sum of squared reading residuals per window and width: ``(windows, widths)``."""
        out = np.empty((len(self.windows), positions.shape[1]))
        for j, (idx, _) in enumerate(self.windows):
            simulated = positions[idx]
            offset = self._offset(self.measured[idx], simulated)
            where = self.direction * (simulated + offset)
            residual = self.observed[idx, None] - self.reading.value(where)
            out[j] = (residual * residual).sum(0)
        return out

    def effects(self, positions: FloatArray) -> FloatArray:
        """Per window and width, the largest departure after the reversal from the rigid path.

        The first column is the rigid plant. Each path is laid on the measured one before
        the reversal (where play and rigid agree), and the departure is read in the
        sensor's units there.
        """
        out = np.empty((len(self.windows), positions.shape[1]))
        for j, (idx, turn) in enumerate(self.windows):
            before, after = idx[idx < turn], idx[idx >= turn]
            if before.size == 0 or after.size == 0:
                out[j] = 0.0
                continue
            offset = self._offset(self.measured[before], positions[before])
            where = self.direction * (positions[after] + offset)
            read = self.reading.value(where)
            out[j] = np.abs(read - read[:, :1]).max(axis=0)
        return out


def _parabola_min(widths: FloatArray, cost: FloatArray) -> float:
    """Minimum of ``cost`` over ``widths`` (sorted), refined by a parabola through three."""
    i = int(np.argmin(cost))
    if i == 0 or i == widths.size - 1:
        return float(widths[i])
    x, y = widths[i - 1 : i + 2], cost[i - 1 : i + 2]
    denominator = (x[0] - x[1]) * (x[0] - x[2]) * (x[1] - x[2])
    a = (x[2] * (y[1] - y[0]) + x[1] * (y[0] - y[2]) + x[0] * (y[2] - y[1])) / denominator
    b = (x[2] ** 2 * (y[0] - y[1]) + x[1] ** 2 * (y[2] - y[0]) + x[0] ** 2 * (y[1] - y[2])) / (
        denominator
    )
    if a <= 0.0:
        return float(widths[i])
    return float(np.clip(-b / (2.0 * a), x[0], x[2]))


def _resolution_bound(widths: FloatArray, effects: FloatArray, step: float) -> float:
    """Smallest width whose typical (median over reversals) effect reaches one sensor step."""
    typical = np.median(effects, axis=0)
    above = np.flatnonzero(typical >= step)
    if above.size == 0:
        return math.inf
    k = int(above[0])
    if k == 0:
        return 0.0
    # Linear between the last width below one step and the first at or above it.
    w0, w1, e0, e1 = widths[k - 1], widths[k], typical[k - 1], typical[k]
    return float(w0 + (step - e0) * (w1 - w0) / max(e1 - e0, _TINY))
