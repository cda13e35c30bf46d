"""The tuner's model and its batched step-response simulation with exact early stopping.

The model is the sampled-data loop the controller really runs: the batched :class:`Plant`
(exact zero-order hold over the control period, with or without friction) closed by the
:class:`PID` law itself (backward-Euler integral, derivative on the measured velocity and
clamping anti-windup at the plant's command limit), driven by a unit step of the reference
from rest. The velocity is the plant's true one (an ideal tachometer) by default, or the
QUBE's filtered estimate of the angle (``TuningModel.velocity``). Every candidate is one plant
of the batch with its own gains.

Early stopping. Most random candidates fail a spec early and provably: a response that has
not reached 90 % of the step before the peak-time limit either never does (rise time
infinite) or does later with a larger value (peak time over the limit); one that passes
``1 + overshoot/100`` has failed the overshoot spec; one outside the settling band at a sample
whose settling time would already exceed the limit has failed settling. Such candidates are
dropped from the batch at checkpoints. Each test uses only samples already simulated and the
same expressions as :func:`~frictiongym.metrics.step_metrics_batch`, and no other candidate
is affected (each plant and PID entry evolves on its own, bit for bit), so the feasible set
and the metrics of every candidate simulated to the horizon are exactly those of a full
evaluation (``tests/test_tuning.py`` checks this).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, cast

import numpy as np
import numpy.typing as npt

from frictiongym._validation import real_number
from frictiongym.controllers.base import LoopSpec
from frictiongym.controllers.pid import PID, PIDGains
from frictiongym.devices import ROTARY, Device
from frictiongym.friction import FrictionModel, NoFriction
from frictiongym.metrics import iae, itae
from frictiongym.metrics.step import StepMetricsBatch, step_metrics_batch, step_progress
from frictiongym.plants.plant import Plant, PlantParams
from frictiongym.plants.sensors import SENSOR_ENCODER, FilteredDerivative
from frictiongym.tuning.specs import StepSpecs

if TYPE_CHECKING:
    from frictiongym.params import DeviceParams

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: The reference step: from rest at 0 to 1 (rad for the servo), as in the paper's Fig. 6.
STEP = 1.0

#: The paper's gains (§3.1), the servo's baseline: evaluated in every run.
PAPER_GAINS: tuple[float, float, float] = tuple(  # type: ignore[assignment]
    ROTARY.paper_gains["pid"][k] for k in ("kp", "ki", "kd")
)

#: Why a candidate was dropped before the horizon (``Evaluation.stop_reason``).
STOP_REASONS = {0: "none", 1: "rise/peak", 2: "overshoot", 3: "settling"}

#: Samples between early-stop checks after the first, at the peak-time limit: 50 samples =
#: 0.1 s at 2 ms. Assumed; any value gives the same result. With the paper's specs nearly every
#: infeasible candidate is dropped at the first check, so the interval hardly matters for speed
#: (10, 50, 250 samples and no later check ran within 10 % of one another on 65 536 candidates).
CHECK_EVERY = 50


@dataclass(frozen=True)
class TuningModel:
    """The loop the tuner simulates: plant, friction in the plant, and control period.

    Parameters
    ----------
    plant : PlantParams, default ``ROTARY.plant``
        The paper's Eq. (2) servo, ``J = 7.143e-3``, ``B = 0.0446``, ±10 V.
    friction : FrictionModel, default NoFriction()
        ``NoFriction()`` is the paper's nominal model (it tuned on Eq. (2)).
    dt : float, default ``ROTARY.dt``
        Control period, s (2 ms: Quanser's QUBE rate, plants/presets.py).
    name : str, default "nominal"
        Short name for reports.
    source : str, optional
        The params file the model was read from.
    velocity : {"ideal", "filtered"}, default "ideal"
        The D term's velocity: the plant's true velocity (an ideal tachometer, the paper's
        Eq. (2) loop), or the QUBE's estimate ``w s / (s + w)`` of the sampled angle
        (:class:`~frictiongym.plants.sensors.FilteredDerivative`, what the env observes).
    velocity_cutoff : float, default ``ROTARY.velocity_cutoff``
        ``w`` of the filtered estimate, rad/s (50: Quanser's QUBE models).
    step : float, default STEP
        The reference step from rest at 0, position units (the device's demo step).
    baseline : tuple of float, default PAPER_GAINS
        ``(kp, ki, kd)`` evaluated beside the search: the paper's, or a device file's PID.
    device : str, default "RotaryServo"
        Name of the device (units of reports and figures).
    """

    plant: PlantParams = ROTARY.plant
    friction: FrictionModel = field(default_factory=NoFriction)
    dt: float = ROTARY.dt
    name: str = "nominal"
    source: str | None = None
    velocity: Literal["ideal", "filtered"] = "ideal"
    velocity_cutoff: float = cast(float, ROTARY.velocity_cutoff)  # the servo has its filter
    step: float = STEP
    baseline: tuple[float, float, float] = PAPER_GAINS
    device: str = ROTARY.name

    def __post_init__(self) -> None:
        real_number("TuningModel.dt", self.dt, "> 0", unit=" s")
        if self.velocity not in ("ideal", "filtered"):
            raise ValueError(
                f"TuningModel.velocity must be 'ideal' or 'filtered', got {self.velocity!r}"
            )
        if self.velocity == "filtered" and not math.isfinite(self.velocity_cutoff):
            raise ValueError(
                f"{self.device} has no velocity filter (its velocity_cutoff): tune with the "
                "ideal velocity"
            )
        real_number("TuningModel.step", self.step, "> 0")

    @classmethod
    def paper(cls, with_friction: bool = False) -> TuningModel:
        """Return the paper's servo: nominal Eq. (2), or with its friction (its paper preset)."""
        if with_friction:
            return cls(friction=ROTARY.paper_friction, name="friction")
        return cls()

    @classmethod
    def for_device(cls, device: Device, with_friction: bool = False) -> TuningModel:
        """Return the loop of ``device`` (an encoder device): its plant, period and step.

        The servo's is :meth:`paper`'s model. Raises ValueError for a device whose task is
        not a step from rest at 0 (the Altino's starts 30 cm from the wall).
        """
        if device.sensor != SENSOR_ENCODER:
            raise ValueError(
                f"tune simulates a step from rest at 0 of an encoder device; {device.title} "
                "reads its position otherwise (its task starts away from 0)"
            )
        gains = device.paper_gains["pid"]
        return cls(
            plant=device.plant,
            friction=device.paper_friction if with_friction else NoFriction(),
            dt=device.dt,
            name="friction" if with_friction else "nominal",
            velocity_cutoff=device.velocity_cutoff or math.inf,
            step=float(device.references["step"]["value"]),
            baseline=(float(gains["kp"]), float(gains["ki"]), float(gains["kd"])),
            device=device.name,
        )

    def with_params(self, params: DeviceParams, with_friction: bool = True) -> TuningModel:
        """Return this loop with ``J``, ``B`` (and friction) of identified ``DeviceParams``."""
        plant = params.plant(self.plant)
        friction = params.plant_friction() if with_friction else NoFriction()
        name = "params" if with_friction else "params-nominal"
        return dataclasses.replace(self, plant=plant, friction=friction, name=name)

    @classmethod
    def from_params(
        cls, params: DeviceParams, with_friction: bool = True, source: str | None = None
    ) -> TuningModel:
        """Return the servo with ``J``, ``B`` (and friction) of identified ``DeviceParams``."""
        return dataclasses.replace(cls().with_params(params, with_friction), source=source)

    def replace(self, **changes: Any) -> TuningModel:
        """Return a copy with ``changes`` (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def record(self) -> dict[str, Any]:
        """Return the model as a JSON-ready dict."""
        return {
            "name": self.name,
            "plant": {  # an infinite end stop (none) is left out: JSON has no infinity
                k: v for k, v in dataclasses.asdict(self.plant).items() if v != math.inf
            },
            "friction": {"law": self.friction.name, **_law_fields(self.friction)},
            "dt": self.dt,
            "velocity": self.velocity,
            "velocity_cutoff": self.velocity_cutoff if self.velocity == "filtered" else None,
            "source": self.source,
            "device": self.device,
            "step": self.step,
            "baseline": dict(zip(("kp", "ki", "kd"), self.baseline, strict=True)),
        }


def _law_fields(law: FrictionModel) -> dict[str, Any]:
    if dataclasses.is_dataclass(law):
        return dataclasses.asdict(law)
    return {}


def horizon_steps(horizon: float, dt: float) -> int:
    """Control periods in ``horizon`` s (rounded to the nearest whole period, at least 1)."""
    return max(1, round(horizon / dt))


@dataclass(frozen=True)
class Evaluation:
    """Step responses of N candidates (arrays of shape (N,) unless noted).

    Metrics are NaN for candidates stopped early (``complete`` False); ``iae`` and ``itae``
    (of the error ``1 - y``, trapezoidal) only for feasible candidates.
    """

    t: FloatArray  #: sample times, shape (n + 1,), s
    metrics: StepMetricsBatch
    feasible: BoolArray
    complete: BoolArray  #: simulated to the horizon
    stopped_at: FloatArray  #: time of the early stop, s; NaN if complete
    stop_reason: npt.NDArray[np.int8]  #: key of STOP_REASONS
    peak_command: FloatArray  #: largest |command| while simulated, command units
    iae: FloatArray
    itae: FloatArray
    traces: FloatArray | None  #: y, shape (n + 1, N), if asked for; NaN after an early stop


def _gains(gains: npt.ArrayLike) -> FloatArray:
    g = np.asarray(gains, dtype=np.float64)
    if g.ndim != 2 or g.shape[1] != 3 or g.shape[0] < 1:
        raise ValueError(
            f"gains must have shape (N, 3), one (kp, ki, kd) row per candidate; got {g.shape}"
        )
    if not np.all(np.isfinite(g)) or np.any(g < 0.0):
        raise ValueError("gains must be finite and >= 0")
    return g


def simulate(
    gains: npt.ArrayLike,
    model: TuningModel,
    specs: StepSpecs,
    horizon: float,
    *,
    early_stop: bool = True,
    keep_traces: bool = False,
    parallel: bool | None = None,
) -> Evaluation:
    """Simulate the unit step of N candidates at once and judge them against ``specs``.

    Parameters
    ----------
    gains : array_like, shape (N, 3)
        ``(kp, ki, kd)`` per candidate.
    model : TuningModel
    specs : StepSpecs
    horizon : float
        Simulated time, s; must exceed the settling-time spec.
    early_stop : bool, default True
        Drop candidates that have provably failed (module docstring); the feasible set and
        the metrics of complete candidates do not change. Off when the plant has dead time.
    keep_traces : bool, default False
        Return the responses (memory ``8 (n + 1) N`` bytes).
    parallel : bool, optional
        The batched plant's kernel, as :class:`Plant`'s ``parallel``: by default the adaptive
        choice (:mod:`frictiongym.plants.threads`), which keeps what it learns as early stops
        shrink the batch; results are the same whichever kernel runs.

    Returns
    -------
    Evaluation
    """
    g = _gains(gains)
    if not (math.isfinite(horizon) and horizon > specs.settling_time):
        raise ValueError(
            f"horizon must be longer than the settling-time spec ({specs.settling_time} s) so "
            f"settling can be judged, got {horizon!r} s"
        )
    size, dt = g.shape[0], model.dt
    n = horizon_steps(horizon, dt)
    t = np.asarray(np.arange(n + 1) * dt, dtype=np.float64)
    plant = Plant(model.plant, model.friction, dt, num_plants=size, parallel=parallel)
    pid = PID(LoopSpec(dt=dt, limit=model.plant.command_limit), PIDGains(*g.T.copy()))
    early_stop = early_stop and plant.delay_steps == 0
    checks = _Checks(t, specs, model.step) if early_stop else None
    tach = (
        None
        if model.velocity == "ideal"
        else FilteredDerivative(model.velocity_cutoff, dt, (size,))
    )
    v = plant.velocity

    active = np.arange(size)
    stopped_at = np.full(size, math.nan)
    reason = np.zeros(size, dtype=np.int8)
    peak_u = np.zeros(size)
    peak_active = np.zeros(size)
    blocks: list[FloatArray] = []
    rows = [plant.position.copy()]
    for k in range(1, n + 1):
        v = plant.velocity if tach is None else tach.update(plant.position)
        u = pid.update(model.step, plant.position, v)
        np.maximum(peak_active, np.abs(u), out=peak_active)
        plant.step(u)
        rows.append(plant.position.copy())
        if checks is None or k == n or not checks.due(k):
            continue
        blocks.append(np.stack(rows))
        rows = []
        fail = checks.run(blocks[-1], k)
        if not fail.any():
            continue
        keep = fail == 0
        dropped = active[~keep]
        stopped_at[dropped], reason[dropped] = t[k], fail[~keep]
        peak_u[dropped] = peak_active[~keep]
        active, peak_active = active[keep], peak_active[keep]
        if active.size == 0:
            break
        if tach is not None:  # continue from the last sample fed and the last estimate
            fed = blocks[-1][-2] if blocks[-1].shape[0] > 1 else blocks[-2][-1]
            tach = FilteredDerivative(model.velocity_cutoff, dt, (active.size,))
            tach.reset(position=fed[keep], velocity=v[keep])
        blocks = [b[:, keep] for b in blocks]
        checks.keep(keep)
        plant.keep(keep)
        pid = pid.take(keep)
    peak_u[active] = peak_active

    nan = np.full(size, math.nan)
    columns = {f.name: nan.copy() for f in dataclasses.fields(StepMetricsBatch)}
    feasible = np.zeros(size, dtype=bool)
    iae_v, itae_v = nan.copy(), nan.copy()
    traces = np.full((n + 1, size), math.nan) if keep_traces else None
    if active.size:
        y = np.concatenate([*blocks, np.stack(rows)]) if rows else np.concatenate(blocks)
        done = step_metrics_batch(
            t,
            y,
            model.step,
            y0=0.0,
            settling_band=specs.settling_band,
            rise_limits=specs.rise_limits,
        )
        for name, values in columns.items():
            values[active] = getattr(done, name)
        ok = specs.feasible(done)
        feasible[active] = ok
        for j in np.flatnonzero(ok):
            error = model.step - y[:, j]
            iae_v[active[j]], itae_v[active[j]] = iae(t, error), itae(t, error)
        if traces is not None:
            traces[:, active] = y
    complete = np.zeros(size, dtype=bool)
    complete[active] = True
    return Evaluation(
        t=t,
        metrics=StepMetricsBatch(**columns),
        feasible=feasible,
        complete=complete,
        stopped_at=stopped_at,
        stop_reason=reason,
        peak_command=peak_u,
        iae=iae_v,
        itae=itae_v,
        traces=traces,
    )


class _Checks:
    """The early-stop tests at checkpoints, with the running per-candidate statistics."""

    def __init__(self, t: FloatArray, specs: StepSpecs, step: float) -> None:
        self.t, self.specs, self.step = t, specs, step
        # First sample whose time reaches the peak-time limit: a peak there or later fails.
        self.k_peak = int(np.searchsorted(t - t[0], specs.peak_time, side="left"))
        # First sample i whose settling time t[i + 1] - t[0] reaches the limit (or the last).
        after = int(np.searchsorted(t - t[0], specs.settling_time, side="left"))
        self.i_settle = min(after - 1, t.size - 1)
        self.max_before = np.zeros(0)
        self.max_after = np.zeros(0)
        self.first = True

    def due(self, k: int) -> bool:
        return k >= self.k_peak and (k - self.k_peak) % CHECK_EVERY == 0

    def keep(self, keep: BoolArray) -> None:
        self.max_before, self.max_after = self.max_before[keep], self.max_after[keep]

    def run(self, block: FloatArray, k: int) -> npt.NDArray[np.int8]:
        """Failure codes (0: none) of the active candidates given samples up to ``k``."""
        s = self.specs
        start = k + 1 - block.shape[0]  # sample index of the block's first row
        progress = step_progress(block, 0.0, self.step)
        fail = np.zeros(block.shape[1], dtype=np.int8)
        if self.first:  # the block holds samples 0..k_peak: rise is decided before k_peak
            self.first = False
            before = progress[: self.k_peak]
            self.max_before = before.max(axis=0)
            self.max_after = np.full(block.shape[1], -math.inf)
            above_lo, above_hi = before >= s.rise_limits[0], before >= s.rise_limits[1]
            first_lo, first_hi = np.argmax(above_lo, axis=0), np.argmax(above_hi, axis=0)
            reached = above_hi.any(axis=0)
            rise = np.where(reached, self.t[first_hi] - self.t[first_lo], math.inf)
            fail[~(rise < s.rise_time)] = 1
            progress, start = progress[self.k_peak :], self.k_peak
        self.max_after = np.maximum(self.max_after, progress.max(axis=0))
        fail[(fail == 0) & (self.max_after > self.max_before)] = 1
        top = np.maximum(self.max_before, self.max_after)
        fail[(fail == 0) & ~((top - 1.0) * 100.0 < s.overshoot_pct)] = 2
        late = max(self.i_settle - start, 0)
        if late < progress.shape[0]:
            outside = (np.abs(progress[late:] - 1.0) > s.settling_band).any(axis=0)
            fail[(fail == 0) & outside] = 3
        return fail
