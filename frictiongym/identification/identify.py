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
from dataclasses import MISSING, asdict, dataclass, field, fields, replace
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from frictiongym import devices
from frictiongym.controllers.rollout import Rollout
from frictiongym.envs import ENV_IDS  # importing the envs registers their ids
from frictiongym.friction import StictionCoulomb
from frictiongym.identification import estimates as est
from frictiongym.identification.backlash import (
    BacklashEstimate,
    ReversalPlan,
    estimate_backlash,
    reversal_test,
)
from frictiongym.identification.dead_zone import (
    LEVELS,
    DeadZoneEstimate,
    estimate_dead_zone,
    joint_start,
    without_zone,
)
from frictiongym.identification.experiments import Runner, Span
from frictiongym.identification.fit import LAWS, LawFit, fit_law, inertia_from_map, rest_slope
from frictiongym.identification.refine import Reading, ReciprocalReading, Refinement, refine
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
            raise ValueError(
                f"{described.name} has no identification plan: its Device.identification "
                f"(frictiongym/devices.py) lacks {', '.join(missing)}"
            )
        if "span" in settings:
            settings["span"] = Span(*settings["span"])
        if "reading" in settings:
            settings["reading"] = ReciprocalReading(*settings["reading"])
        return cls(**settings)


#: Episode length of an identification env: longer than any run the plans hold.
_NO_EPISODE_LIMIT = 1_000_000
#: Rounds of the refinement with the play's width free, each followed by the reversal test's
#: fit again, on a plan that refines (:func:`_reversal_test`). One is enough: on the Altino
#: with plays of 0.2 and 0.5 cm a second round left the estimate as it was.
PLAY_ROUNDS = 1


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
    plan: Plan
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
                f"{'positive' if sign > 0 else 'negative'} direction: raise Plan.probe_to"
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
        fits["paper"], refinement = _refined(
            fits["paper"], traces, inertia, damping, runner, plan.reading
        )
        inertia = (refinement.values["J"], refinement.stderr["J"])
        damping = (refinement.values["B"], refinement.stderr["B"])
        breakaway = {k: (refinement.values[k], refinement.stderr[k]) for k in breakaway}
    play = zone = None
    if reversal is not None and backlash:
        note("reversal test")
        play, joint = _reversal_test(
            runner,
            reversal,
            plan,
            traces,
            (fits["paper"], inertia, damping, breakaway, refinement),
            note,
        )
        if joint is not None:  # the rigid model refitted together with the play
            fits["paper"], refinement = joint
            inertia = (refinement.values["J"], refinement.stderr["J"])
            damping = (refinement.values["B"], refinement.stderr["B"])
            breakaway = {k: (refinement.values[k], refinement.stderr[k]) for k in breakaway}
    if reversal is not None and dead_zone:
        note("dead zone")
        zone, play, zone_joint = _dead_zone_fit(
            runner,
            reversal,
            (fits["paper"], inertia[0], damping[0]),
            breakaway,
            play,
            plan,
            refinement,
            traces,
            note,
        )
        if zone_joint is not None:  # the rigid model refitted with the zone
            fits["paper"], refinement = zone_joint
            inertia = (refinement.values["J"], refinement.stderr["J"])
            damping = (refinement.values["B"], refinement.stderr["B"])
            breakaway = {k: (refinement.values[k], refinement.stderr[k]) for k in breakaway}
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


def _dead_zone_fit(
    runner: Runner,
    reversal: ReversalPlan,
    rigid_model: tuple[LawFit, float, float],
    breakaway: dict[str, tuple[float, float]],
    play: BacklashEstimate | None,
    plan: Plan,
    refinement: Refinement | None,
    traces: list[Rollout],
    note: Callable[[str], None],
) -> tuple[DeadZoneEstimate, BacklashEstimate | None, tuple[LawFit, Refinement] | None]:
    """Fit a dead zone to the reversal run (the play's, or a new one), then the play again.

    ``rigid_model`` is the paper's fit, ``J`` and ``B``. With a ``play`` estimate, the zone is
    fitted on its run with the play held at the width where both fit best together
    (:func:`~frictiongym.identification.dead_zone.joint_start`: both weaken the braking after
    a reversal, so either alone takes up the other), and the play is then estimated again
    with the zone held. On a plan
    that refines, the refinement is run again with the zone free first. Returns the zone,
    the play and, after such a refit, the law and the refinement (levels as the body shows
    them while driven, raised by the zone as the rigid model's are) that replace the rigid
    ones.
    """
    device = devices.device_of(runner.env)
    fit, inertia, damping = rigid_model
    rigid = DeviceParams.from_model(fit.model, inertia=inertia, damping=damping, device=device.name)
    dt, reading = runner.spec.dt, plan.reading
    dead_time = None if refinement is None else refinement.dead_time
    held = None
    if play is None:
        limit = 0.95 * runner.spec.limit
        levels = (breakaway["us_pos"][0], breakaway["us_neg"][0])
        up, down = (min(reversal.level * level, limit) for level in levels)
        trace = runner.reversals(up, down, reversal.hold, reversal.reversals, band=reversal.band)
    else:  # the play's run; the zone's fit holds the play where both fit best together
        trace, shares = play.trace, (play.load_inertia, play.load_friction)
        width, _ = joint_start(
            trace, rigid, reversal, shares, dt=dt, reading=reading, dead_time=dead_time
        )
        held = Backlash(width, *shares) if width > 0.0 else None
        rigid = replace(rigid, backlash=held)
    zone = estimate_dead_zone(trace, rigid, reversal, dt=dt, reading=reading, dead_time=dead_time)
    joint = None
    if refinement is not None:
        # The relay runs brake too, so the rigid refinement took up part of the zone (on the
        # Altino with a zone of 50 units: the zone fitted 0, J 4.5 % high): refit it with the
        # zone free (the reversal run added), then the zone again on that rigid model.
        note("refinement with the dead zone")
        drivetrain = None if held is None else (held.width, held.load_inertia, held.load_friction)
        refit, refined = _refined(
            fit,
            [*traces, trace],
            (refinement.values["J"], refinement.stderr["J"]),
            (refinement.values["B"], refinement.stderr["B"]),
            runner,
            plan.reading,
            drivetrain,
            refinement,
            zone=zone.width,
        )
        width = refined.values["d"]
        raised = {k: v + width if k in LEVELS else v for k, v in refined.values.items()}
        refined = replace(refined, values=raised)
        refit = replace(
            refit,
            model=without_zone(refit.model, -width),
            values={k: v + width if k in LEVELS else v for k, v in refit.values.items()},
        )
        joint = (refit, refined)
        rigid = DeviceParams.from_model(
            refit.model, inertia=raised["J"], damping=raised["B"], device=device.name, backlash=held
        )
        dead_time = refined.dead_time
        zone = estimate_dead_zone(
            trace, rigid, reversal, dt=dt, reading=reading, dead_time=dead_time
        )
        zone = replace(zone, refinement_width=width)
    if play is not None and zone.resolved:
        zoned = replace(zone.apply(rigid), backlash=None)
        again = estimate_backlash(
            trace, zoned, reversal, dt=dt, reading=reading, dead_time=dead_time
        )
        play = replace(
            again, earlier=(*play.earlier, play.width), refinement_width=play.refinement_width
        )
    return zone, play, joint if zone.resolved else None


def _resolution(reading: Reading, direction: float) -> Callable[[FloatArray], FloatArray]:
    """Weights of positions (plant direction) by the sensor's resolution there, squared."""

    def weight(y: FloatArray) -> FloatArray:
        return np.maximum(reading.slope(direction * y) ** 2, 1e-300)

    return weight


def _reversal_test(
    runner: Runner,
    reversal: ReversalPlan,
    plan: Plan,
    traces: list[Rollout],
    rigid_model: tuple[
        LawFit,
        tuple[float, float],
        tuple[float, float],
        dict[str, tuple[float, float]],
        Refinement | None,
    ],
    note: Callable[[str], None],
) -> tuple[BacklashEstimate, tuple[LawFit, Refinement] | None]:
    """Run the reversal test on the rigid model; where the plan refines, refit both.

    A plan that refines on relay runs fits the rigid model to runs that reverse, so a play
    biases it (on the Altino with a 0.2 cm play: ``u_c-`` 3.6 % low, and the play 24 % low;
    with 0.5 cm, rounds that held the play fixed crept toward it by a few per cent each).
    Then the refinement is run again with the play's width free (the reversal run added),
    and the play estimated again with the rigid model it gives, :data:`PLAY_ROUNDS` times.
    ``rigid_model`` is the paper's fit, ``J`` and ``B`` (each with its standard error), the
    break-away levels and the refinement (or None). Returns the estimate and, if the play is
    resolved in the end, the refitted law and refinement (else the rigid model stands).
    """
    fit, inertia, damping, breakaway, refinement = rigid_model
    device = devices.device_of(runner.env)

    def rigid(law: LawFit, total_inertia: float, total_damping: float) -> DeviceParams:
        return DeviceParams.from_model(
            law.model, inertia=total_inertia, damping=total_damping, device=device.name
        )

    levels = (breakaway["us_pos"][0], breakaway["us_neg"][0])
    dead_time = None if refinement is None else refinement.dead_time
    play = reversal_test(
        runner,
        rigid(fit, inertia[0], damping[0]),
        levels,
        reversal,
        reading=plan.reading,
        dead_time=dead_time,
    )
    if refinement is None or play.width <= 0.0:
        return play, None
    earlier = []
    for round_ in range(PLAY_ROUNDS):
        note(f"refinement with the play {round_ + 1}/{PLAY_ROUNDS}")
        earlier.append(play.width)
        free = (play.width, play.load_inertia, play.load_friction)
        fit, refinement = _refined(
            fit,
            [*traces, play.trace],
            (refinement.values["J"], refinement.stderr["J"]),
            (refinement.values["B"], refinement.stderr["B"]),
            runner,
            plan.reading,
            free,
            refinement,
        )
        play = estimate_backlash(
            play.trace,
            rigid(fit, refinement.values["J"], refinement.values["B"]),
            reversal,
            dt=runner.spec.dt,
            reading=plan.reading,
            dead_time=refinement.dead_time,
        )
    play = replace(play, earlier=tuple(earlier), refinement_width=refinement.values["W"])
    return play, (fit, refinement) if play.resolved else None


def _refined(
    fit: LawFit,
    traces: list[Rollout],
    inertia: tuple[float, float],
    damping: tuple[float, float],
    runner: Runner,
    reading: Reading | None,
    drivetrain: tuple[float, float, float] | None = None,
    previous: Refinement | None = None,
    zone: float | None = None,
) -> tuple[LawFit, Refinement]:
    """Return the paper's law after the output-error fit, and the refinement itself.

    With a play (``drivetrain``), its width is fitted too, on the reversal runs as well.
    With a dead zone (``zone``, its starting half-width), the zone is fitted instead and a
    play is held; the law's levels are then the friction's own.
    With a ``previous`` refinement, the fit starts from its result alone at its dead time or
    less: a continuation, without the multi-start.
    """
    shape = fit.model.shape if isinstance(fit.model, StictionCoulomb) else "linear"
    start = {"J": inertia[0], "B": damping[0], **fit.values}
    reversals = drivetrain is not None or zone is not None
    kinds = ("constant", "ramp", "relay", *(("reversal",) if reversals else ()))
    runs = [t for t in traces if t.settings["kind"] in kinds]
    options: dict[str, Any] = {}
    if previous is not None:
        steps = round(previous.dead_time / runner.spec.dt)
        options = {"candidates": 1, "local_fits": 1, "polish": 1, "max_delay_steps": steps}
    result = refine(
        runs,
        start,
        runner.spec.dt,
        runner.spec.limit,
        shape,
        reading=reading,
        direction=runner.spec.direction,
        drivetrain=drivetrain,
        fit_play=drivetrain is not None and zone is None,
        dead_zone=zone,
        fit_zone=zone is not None,
        **options,
    )
    v = result.values
    model = StictionCoulomb(
        v["us_pos"],
        v["us_neg"],
        v["uc_pos"],
        v["uc_neg"],
        v["v0_pos"],
        v["v0_neg"],
        v["B"],
        shape,
    )
    values = {**{k: v[k] for k in fit.values if k != "viscous"}, "viscous": v["B"]}
    stderr = {k: result.stderr[k] for k in values if k != "viscous"}
    stderr["viscous"] = result.stderr["B"]
    refined = replace(fit, model=model, values=values, stderr=stderr, rms=math.nan)
    return refined, result


def plan_for(env_id: str) -> Plan:
    """Return the plan of the device behind a registered env id (:meth:`Plan.for_device`)."""
    if env_id not in ENV_IDS:
        raise ValueError(f"unknown env id {env_id!r}; choose one of {', '.join(ENV_IDS)}")
    return Plan.for_device(env_id)


def make_env(env_id: str, plan: Plan | None = None, **kwargs: Any) -> Any:
    """``gym.make(env_id, ...)`` with what the device's plan needs (episode length, guards).

    Each run ends by its own duration, so the episode limit only has to stay out of the way.
    """
    plan = plan or plan_for(env_id)
    return gym.make(env_id, max_episode_steps=_NO_EPISODE_LIMIT, **{**plan.env_kwargs, **kwargs})
