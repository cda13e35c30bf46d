"""The identification procedure: experiments in order, then the fits, then a parameter file.

1. A fast **probe** ramp finds a rough break-away level, which scales everything after it
   (so the same plan serves volts and the Altino's motor units).
2. Slow **ramps** from rest in each direction give the break-away levels ``u_s±``.
3. **Constant levels** above break-away in each direction give the steady map ``u(v)``
   (the paper's Fig. 8(a)/10(a)).
4. **Velocity steps** between two fast levels give ``J`` and ``B`` (first-order fits, the
   paper's identification of Eq. (2)). Where the sensor's range is too short for them,
   **relay runs** drive back and forth inside it instead.
5. The ramps' onsets are corrected with ``J`` and the map's slope at rest, and the laws are
   fitted to the map (:mod:`~frictiongym.identification.fit`). Optionally an output-error
   fit of every sample refines the paper's law, ``J`` and ``B``
   (:mod:`~frictiongym.identification.refine`).
6. Optionally (``backlash=``), a **reversal test** estimates a play between motor and load
   from the rigid model and the device's assumed shares
   (:mod:`~frictiongym.identification.backlash`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym import devices, envs
from frictiongym.controllers.rollout import Rollout
from frictiongym.envs import ENV_IDS  # importing the envs registers their ids
from frictiongym.identification import estimates as est
from frictiongym.identification.backlash import (
    BacklashEstimate,
    ReversalPlan,
)
from frictiongym.identification.dead_zone import (
    DeadZoneEstimate,
)
from frictiongym.identification.drivetrain import dead_zone_fit, refined_law, reversal_rounds
from frictiongym.identification.experiments import Runner, Span
from frictiongym.identification.fit import LAWS, LawFit, fit_law, inertia_from_map, rest_slope
from frictiongym.identification.refine import Reading, ReciprocalReading, Refinement
from frictiongym.params import Backlash, DeviceParams

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Plan:
    """The experiments of one identification, in units of the probe's break-away level.

    The schedule (``levels`` to ``probe_duration``) has no defaults: each device's is in its
    description (:meth:`for_device`); the other fields default to no relay runs, no
    refinement, the whole sensor range and no env arguments.

    Attributes
    ----------
    levels : tuple of float
        Constant levels as multiples of the rough break-away (each held in both directions).
    constant_duration : float
        Longest constant run, s (at least five time constants of the slowest approach).
    ramp_repeats : int
        Slow ramps per direction.
    ramp_from, ramp_to : float
        Ramp start and end as multiples of the rough break-away.
    ramp_duration : float
        Time of one slow ramp from ``ramp_from`` to ``ramp_to``, s.
    step_levels : tuple of float
        The velocity step's two levels as multiples of the rough break-away.
    step_time, step_duration : float
        When the level steps and how long the run lasts, s.
    step_repeats : int
        Velocity steps per direction.
    probe_to, probe_duration : float
        The probe ramp's end (fraction of the command limit) and duration, s.
    relay_levels : tuple of float
        Relay runs (:meth:`~frictiongym.identification.experiments.Runner.relay`), one per
        level, a multiple of the break-away level in each direction; none by default.
    relay_band : tuple of float, optional
        Output range (env units) a relay run drives back and forth across.
    relay_duration : float
        Length of one relay run, s (with ``relay_levels``).
    refine : bool
        Refine ``J``, ``B`` and the paper's law against every sample by an output-error fit
        (:mod:`~frictiongym.identification.refine`), for sensors whose range is too short for
        the runs to reach a steady speed.
    reading : Reading, optional
        What the sensor reads at an output, where its noise is uniform: the refinement's
        residuals are taken there (default: the output itself).
    span : Span, optional
        Usable range of the measured output; runs start inside it and stop at its ends.
    ramp_positions : tuple of float, optional
        Start positions (env units) of the ramps with a positive and with a negative command
        (default: the span's start); where the sensor resolves small motions best.
    env_kwargs : dict
        Keyword arguments the plan needs from ``gym.make`` (e.g. a wider safety limit).
    """

    levels: tuple[float, ...]
    constant_duration: float
    ramp_repeats: int
    ramp_from: float
    ramp_to: float
    ramp_duration: float
    step_levels: tuple[float, float]
    step_time: float
    step_duration: float
    step_repeats: int
    probe_to: float
    probe_duration: float
    relay_levels: tuple[float, ...] = ()
    relay_band: tuple[float, float] | None = None
    relay_duration: float = 0.0
    refine: bool = False
    reading: Reading | None = None
    span: Span | None = None
    ramp_positions: tuple[float, float] | None = None
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def for_device(cls, device: str | devices.Device) -> Plan:
        """Return the plan of ``device`` (any spelling of :func:`frictiongym.devices.get`).

        It is the device's ``identification`` settings, whose ``span`` and ``reading`` (a
        :class:`ReciprocalReading`) are given as tuples of their fields.

        Raises
        ------
        ValueError
            If the settings lack a field of the schedule: the device has no plan.
        """
        described = devices.get(device)
        settings = dict(described.identification)
        settings.pop("reversal", None)  # the reversal test's (ReversalPlan.for_device)
        required = [f.name for f in fields(cls) if MISSING is f.default is f.default_factory]
        missing = [name for name in required if name not in settings]
        if missing:
            where = (
                f"its file's [identification] table ({described.source})"
                if described.source
                else "its Device.identification (frictiongym/devices.py)"
            )
            raise ValueError(
                f"{described.name} has no identification plan: {where} lacks "
                f"{', '.join(missing)} (docs/devices.md); --from-log still works without one"
            )
        if "span" in settings:
            settings["span"] = Span(*settings["span"])
        if "reading" in settings:
            settings["reading"] = ReciprocalReading(*settings["reading"])
        return cls(**settings)


#: Episode length of an identification env: longer than any run the plans hold.
_NO_EPISODE_LIMIT = 1_000_000


@dataclass(frozen=True)
class Identification:
    """Everything an identification measured and fitted."""

    device: str
    env_id: str | None
    breakaways: list[est.Breakaway]
    points: list[est.SteadyPoint]
    steps: list[est.StepResponse]
    fits: dict[str, LawFit]
    inertia: tuple[float, float]  #: J and its standard error
    damping: tuple[float, float]  #: B (total linear damping) and its standard error
    breakaway: dict[str, tuple[float, float]]  #: us_pos/us_neg: (value, standard error)
    traces: list[Rollout]
    refinement: Refinement | None
    env_steps: int
    seconds: float
    plan: Plan | None  #: the experiments run; None when fitted to recorded data
    backlash: BacklashEstimate | None = None  #: the reversal test, if it ran
    dead_zone: DeadZoneEstimate | None = None  #: the dead-zone fit, if it ran
    #: Recorded data it was fitted to instead of experiments (``identify --from-log``):
    #: what the data was and what it could not give
    source: Mapping[str, Any] | None = None

    def params(self, law: str = "paper") -> DeviceParams:
        """Return the parameters with ``law`` (``"best"``: lowest AIC) as a file's content.

        A resolved play (:attr:`backlash`) is written with the shares it assumed, and a
        resolved dead zone (:attr:`dead_zone`) with the levels lowered by it; both were
        estimated with the paper's law, so they need ``law="paper"``.
        """
        name = min(self.fits.values(), key=lambda f: f.aic).law if law == "best" else law
        if name not in self.fits:
            raise ValueError(f"no fit of law {law!r}; choose one of best, {', '.join(self.fits)}")
        fit = self.fits[name]
        errors = {**fit.stderr, "J": self.inertia[1], "B": self.damping[1]}
        play = None
        resolved = [e for e in (self.backlash, self.dead_zone) if e is not None and e.resolved]
        if resolved and name != "paper":
            what = " and the ".join(
                "play" if isinstance(e, BacklashEstimate) else "dead zone" for e in resolved
            )
            raise ValueError(
                f"the {what} was estimated with the paper law, not {name!r}: write law "
                "'paper' with it (or identify without the reversal test)"
            )
        if self.backlash is not None and self.backlash.resolved:
            estimate = self.backlash
            play = Backlash(estimate.width, estimate.load_inertia, estimate.load_friction)
            errors["backlash"] = estimate.stderr
        params = DeviceParams.from_model(
            fit.model,
            inertia=self.inertia[0],
            damping=self.damping[0],
            device=self.device,
            env_id=self.env_id,
            uncertainty={k: v for k, v in errors.items() if math.isfinite(v)},
            metadata=self.record(name),
            backlash=play,
        )
        return params if self.dead_zone is None else self.dead_zone.apply(params)

    def record(self, law: str) -> dict[str, Any]:
        """Metadata of the run for the parameter file: experiments, fits, timing."""
        return {
            "law_fitted": law,
            "fits": {
                f.law: {"rms": f.rms, "aic": f.aic, "points": f.points, "values": f.values}
                for f in self.fits.values()
            },
            "breakaway_ramps": [
                {"sign": b.sign, "level": b.level, "detected": b.detected} for b in self.breakaways
            ],
            "map": [
                {"level": p.level, "sign": p.sign, "velocity": p.velocity, "moved": p.moved}
                for p in self.points
            ],
            "velocity_steps": [
                {"first": s.first, "second": s.second, "tau": s.tau, "J": s.inertia, "B": s.damping}
                for s in self.steps
            ],
            "refinement": None
            if self.refinement is None
            else {
                k: v for k, v in asdict(self.refinement).items() if k not in ("values", "stderr")
            },
            **({} if self.backlash is None else {"backlash": self.backlash.record()}),
            **({} if self.dead_zone is None else {"dead_zone": self.dead_zone.record()}),
            **({} if self.source is None else {"source": dict(self.source)}),
            "experiments": len(self.traces),
            "env_steps": self.env_steps,
            "seconds": self.seconds,
        }


def _mean_se(values: list[float]) -> tuple[float, float]:
    arr = np.asarray(values, dtype=np.float64)
    se = float(arr.std(ddof=1) / math.sqrt(arr.size)) if arr.size > 1 else math.nan
    return float(arr.mean()), se


def identify(
    env: Any,
    plan: Plan | None = None,
    *,
    seed: int | None = None,
    laws: tuple[str, ...] = tuple(LAWS),
    progress: Callable[[str], None] | None = None,
    backlash: bool | ReversalPlan = False,
    dead_zone: bool = False,
) -> Identification:
    """Identify the friction map, break-away levels, ``J`` and ``B`` of the device behind ``env``.

    Parameters
    ----------
    env : gymnasium.Env
        A frictiongym env, made with the plan's ``env_kwargs`` and an episode limit longer
        than any run (:func:`make_env` does both).
    plan : Plan, optional
        The experiments; the device's (:meth:`Plan.for_device`) by default.
    seed : int, optional
        Seed of the first reset (the simulator's noise).
    laws : tuple of str
        Laws to fit (keys of :data:`~frictiongym.identification.fit.LAWS`).
    progress : callable, optional
        Called with a short label before each experiment.
    backlash : bool or ReversalPlan
        Also run a reversal test and estimate a play between motor and load
        (:mod:`~frictiongym.identification.backlash`): ``True`` runs the device's
        (:meth:`ReversalPlan.for_device`). Off by default.
    dead_zone : bool
        Also fit an actuator dead zone to the reversal run
        (:mod:`~frictiongym.identification.dead_zone`; the run is the play's, with the same
        plan, if ``backlash`` is on). A resolved zone lowers the paper law's levels by its
        width, and a play is then estimated again with the zone held. Off by default.
    """
    started = time.perf_counter()
    device = devices.device_of(env)
    plan = plan or Plan.for_device(device)
    reversal = None  # checked before any experiment runs
    if backlash or dead_zone:
        if "paper" not in laws:
            raise ValueError("the reversal test replays the paper law: keep 'paper' in laws")
        reversal = (
            backlash if isinstance(backlash, ReversalPlan) else ReversalPlan.for_device(device)
        )
    runner = Runner(env, plan.span, seed)
    limit = runner.spec.limit
    note = progress or (lambda _: None)
    traces: list[Rollout] = []

    def keep(trace: Rollout) -> Rollout:
        traces.append(trace)
        return trace

    # 1. Probe: a fast ramp to a fraction of the command limit, once per direction.
    rough = {}
    start = dict(zip((1.0, -1.0), plan.ramp_positions or (None, None), strict=True))
    for sign in (1.0, -1.0):
        note(f"probe ramp {'+' if sign > 0 else '-'}")
        rate = plan.probe_to * limit / plan.probe_duration
        probe = keep(runner.ramp(sign, 0.0, rate, plan.probe_duration, start_at=start[sign]))
        if probe.t[-1] >= plan.probe_duration - 2 * runner.spec.dt:
            raise est.IdentificationError(
                f"the probe ramp to {plan.probe_to * limit:g} did not move the body in the "
                f"{'positive' if sign > 0 else 'negative'} direction: the body breaks away above "
                "it (more friction, or a wider dead zone, than the plan was made for); raise "
                "Plan.probe_to (identify(env, replace(Plan.for_device(...), probe_to=...)))"
            )
        rough[sign] = est.breakaway_level(probe).detected
    # 2. Slow ramps from below break-away.
    ramps: list[Rollout] = []
    for sign in (1.0, -1.0):
        for i in range(plan.ramp_repeats):
            note(f"ramp {'+' if sign > 0 else '-'} {i + 1}/{plan.ramp_repeats}")
            lo, hi = plan.ramp_from * rough[sign], plan.ramp_to * rough[sign]
            rate = (hi - lo) / plan.ramp_duration
            ramps.append(
                keep(runner.ramp(sign, lo, rate, plan.ramp_duration, start_at=start[sign]))
            )
    first_pass = {
        s: _mean_se([est.breakaway_level(r).level for r in ramps if r.settings["sign"] == s])[0]
        for s in (1.0, -1.0)
    }
    # 3. The steady map (samples weighted by the sensor's resolution, if the plan knows it).
    weight = None if plan.reading is None else _resolution(plan.reading, runner.spec.direction)
    points: list[est.SteadyPoint] = []
    for sign in (1.0, -1.0):
        for m in plan.levels:
            level = min(m * first_pass[sign], 0.95 * limit)
            note(f"constant {sign * level:+.4g}")
            trace = keep(runner.constant(sign * level, plan.constant_duration))
            points.append(est.steady_velocity(trace, weight=weight))
    # 4. Velocity steps.
    steps: list[est.StepResponse] = []
    for sign in (1.0, -1.0):
        a, b = (min(m * first_pass[sign], 0.95 * limit) for m in plan.step_levels)
        for i in range(plan.step_repeats):
            note(f"velocity step {'+' if sign > 0 else '-'} {i + 1}/{plan.step_repeats}")
            trace = keep(runner.step(sign * a, sign * b, plan.step_time, plan.step_duration))
            steps.append(est.velocity_step(trace))
    # 4b. Relay runs inside the sensor's range (for the output-error refinement).
    if plan.relay_levels and plan.relay_band is not None:
        for i, m in enumerate(plan.relay_levels):
            note(f"relay {i + 1}/{len(plan.relay_levels)}")
            up, down = (min(m * first_pass[s], 0.95 * limit) for s in (1.0, -1.0))
            keep(runner.relay(up, down, plan.relay_band, plan.relay_duration))
    # 5. Break-away with the onset correction, then the fits. Without velocity steps (a sensor
    #    range too short for them), J comes from the constant runs' approach and B from the
    #    map's slope, refined once the break-away levels are corrected.
    rough_us = {"us_pos": (first_pass[1.0], math.nan), "us_neg": (first_pass[-1.0], math.nan)}
    if steps:
        inertia = _mean_se([s.inertia for s in steps])
        damping = _mean_se([s.damping for s in steps])
    else:
        fit = fit_law(points, rough_us, "paper")
        inertia = inertia_from_map(points, fit)
        if not math.isfinite(inertia[0]):  # no clear transient: every run's, as a start
            inertia = inertia_from_map(points, fit, min_transient=0.0)
        damping = (fit.values["viscous"], fit.stderr["viscous"])
    if not math.isfinite(inertia[0]):
        raise est.IdentificationError(
            "no experiment determined the inertia J: add velocity steps to the plan "
            "(Plan.step_repeats) or constant runs that show their approach to steady speed"
        )
    slopes = {sign: rest_slope(points, sign) for sign in (1.0, -1.0)}
    breakaways = [est.breakaway_level(r, inertia[0], slopes[r.settings["sign"]]) for r in ramps]
    breakaway = {
        key: _mean_se([b.level for b in breakaways if b.sign == sign])
        for sign, key in ((1.0, "us_pos"), (-1.0, "us_neg"))
    }
    if not steps:
        fit = fit_law(points, breakaway, "paper")
        inertia = inertia_from_map(points, fit, min_transient=0.0)
        damping = (fit.values["viscous"], fit.stderr["viscous"])
    fits = {law: fit_law(points, breakaway, law) for law in laws}
    refinement = None
    if plan.refine and "paper" in fits:
        note("output-error refinement")
        fits["paper"], refinement = refined_law(
            fits["paper"], traces, inertia, damping, runner, plan.reading
        )
        inertia, damping = refinement.estimate("J"), refinement.estimate("B")
        breakaway = {k: refinement.estimate(k) for k in breakaway}
    play = zone = None
    if reversal is not None and backlash:
        note("reversal test")
        play, joint = reversal_rounds(
            runner,
            reversal,
            plan.reading,
            traces,
            (fits["paper"], inertia, damping, breakaway, refinement),
            note,
        )
        if joint is not None:  # the rigid model refitted together with the play
            fits["paper"], refinement = joint
            inertia, damping = refinement.estimate("J"), refinement.estimate("B")
            breakaway = {k: refinement.estimate(k) for k in breakaway}
    if reversal is not None and dead_zone:
        note("dead zone")
        zone, play, zone_joint = dead_zone_fit(
            runner,
            reversal,
            (fits["paper"], inertia[0], damping[0]),
            breakaway,
            play,
            plan.reading,
            refinement,
            traces,
            note,
        )
        if zone_joint is not None:  # the rigid model refitted with the zone
            fits["paper"], refinement = zone_joint
            inertia, damping = refinement.estimate("J"), refinement.estimate("B")
            breakaway = {k: refinement.estimate(k) for k in breakaway}
    return Identification(
        device=device.name,
        env_id=getattr(getattr(env, "spec", None), "id", None),
        breakaways=breakaways,
        points=points,
        steps=steps,
        fits=fits,
        inertia=inertia,
        damping=damping,
        breakaway=breakaway,
        traces=traces,
        refinement=refinement,
        env_steps=runner.steps,
        seconds=time.perf_counter() - started,
        plan=plan,
        backlash=play,
        dead_zone=zone,
    )


def _resolution(reading: Reading, direction: float) -> Callable[[FloatArray], FloatArray]:
    """Weights of positions (plant direction) by the sensor's resolution there, squared."""

    def weight(y: FloatArray) -> FloatArray:
        return np.maximum(reading.slope(direction * y) ** 2, 1e-300)

    return weight


def plan_for(env_id: str) -> Plan:
    """Return the plan of the device behind a registered env id (:meth:`Plan.for_device`)."""
    if env_id not in ENV_IDS:
        envs.device_of_id(env_id, ENV_IDS)  # a description file, or the error that lists ids
    return Plan.for_device(env_id)


def make_env(env_id: str, plan: Plan | None = None, **kwargs: Any) -> Any:
    """``gym.make(env_id, ...)`` with what the device's plan needs (episode length, guards).

    Each run ends by its own duration, so the episode limit only has to stay out of the way.
    """
    plan = plan or plan_for(env_id)
    return envs.make(env_id, max_episode_steps=_NO_EPISODE_LIMIT, **{**plan.env_kwargs, **kwargs})
