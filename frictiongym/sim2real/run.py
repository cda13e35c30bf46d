"""Run one controller on a device and on simulated models of it, and measure the gap.

:func:`run_sim2real` runs the controller ``repeats`` times on the device (its own spread is the
noise floor), once on each simulated model (the nominal plant without friction, and the
friction-augmented or identified one), and compares what the controller saw: the measured
output, the estimated velocity and the applied command.

A device run can end early: the env's safety limit (or the Altino's distance guard) ends it, or
the device's watchdog stops the motor because the host loop stalled. Such a run is recorded
with how and when it ended (:class:`DeviceRun`), left out of the comparison, and the remaining
runs go on: a watchdog trip is a hiccup of the host, not of the device, and the next run
re-arms it. The comparison uses the complete runs only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym import devices, envs
from frictiongym._validation import real_number
from frictiongym.controllers import PID, Controller, FrictionCompensator, PIDGains, Rollout, rollout
from frictiongym.envs import ENV_IDS
from frictiongym.hardware.errors import (
    DeviceDisconnectedError,
    DeviceTimeoutError,
    WatchdogTripError,
)
from frictiongym.hardware.protocol import Status
from frictiongym.hardware.realtime import realtime_priority
from frictiongym.hardware.runlog import Timing
from frictiongym.plants.sensors import SENSOR_IR, ir_estimate

FloatArray = npt.NDArray[np.float64]

CONTROLLERS = ("pid", "compensated")
#: Signals compared, as (name, unit key): the controller's view of the loop.
SIGNALS = ("output", "velocity", "command")
#: The :class:`~frictiongym.controllers.Rollout` field each compared signal is recorded in.
RECORDED = {"output": "measured", "velocity": "rate", "command": "command"}
#: How a device run ended (:attr:`DeviceRun.ended`): its full length; the env's safety limit;
#: the device's own limit (the Altino's distance guard); the device's watchdog; the link (no
#: state frame in time, or one too old); the device gone (the runs after it are not tried).
COMPLETE = "complete"
SAFETY_LIMIT = "safety limit"
DEVICE_LIMIT = "device limit"
WATCHDOG = "watchdog"
LINK = "link"
DISCONNECTED = "disconnect"


@dataclass(frozen=True)
class DeviceRun:
    """One run on the device: how it ended and its trace (None if the device stopped it)."""

    run: int  #: 1 for the first
    steps: int  #: steps done
    ended: str  #: one of :data:`COMPLETE`, :data:`SAFETY_LIMIT`, ... :data:`DISCONNECTED`
    detail: str  #: one line: what ended it
    trace: Rollout | None

    @property
    def complete(self) -> bool:
        """Whether the run lasted its full length."""
        return self.ended == COMPLETE


#: How the progress line and the report name each fault that ends a run.
FAULT_TEXT = {
    WATCHDOG: "the device's watchdog",
    LINK: "the link",
    DISCONNECTED: "a disconnect",
}


def _fault_kind(error: BaseException) -> str:
    """Return how a device error ends a run (:data:`WATCHDOG`, :data:`LINK`, ...)."""
    if isinstance(error, WatchdogTripError):
        return WATCHDOG
    return LINK if isinstance(error, DeviceTimeoutError) else DISCONNECTED


def _steps_before_fault(session: Any, faults_before: int) -> int:
    """Return the steps a run completed before its fault (0 when it came in the reset)."""
    if len(session.faults) <= faults_before:  # not recorded by a step
        return 0
    return max(int(session.faults[-1]["step"]) - 1, 0)


def signal(trace: Rollout, name: str) -> FloatArray:
    """Return the compared signal ``name`` (one of :data:`SIGNALS`) of a run."""
    return trace.signal(RECORDED[name])


def rmse(a: FloatArray, b: FloatArray) -> float:
    """Root mean square of ``a - b`` over their common length."""
    n = min(a.size, b.size)
    return float(np.sqrt(np.mean((a[:n] - b[:n]) ** 2))) if n else math.nan


def fit_percent(model: FloatArray, measured: FloatArray) -> float:
    """NRMSE fit, % (MATLAB's ``compare``): 100 (1 - |y - ŷ| / |y - mean y|); 100 is exact."""
    n = min(model.size, measured.size)
    spread = float(np.linalg.norm(measured[:n] - measured[:n].mean()))
    if n == 0 or spread == 0.0:
        return math.nan
    return 100.0 * (1.0 - float(np.linalg.norm(measured[:n] - model[:n])) / spread)


@dataclass
class Sim2RealResult:
    """What :func:`run_sim2real` measured."""

    env_id: str
    backend: str
    controller: str
    gains: dict[str, float]
    device: list[Rollout]
    models: dict[str, Rollout]
    model_descriptions: dict[str, str]
    timing: Timing | None
    periods: FloatArray = field(default_factory=lambda: np.zeros(0))
    log_dir: str | None = None
    #: Every device run in order, complete or not (:attr:`device` holds the complete ones).
    runs: list[DeviceRun] = field(default_factory=list)
    #: The host loop's scheduling during the device runs (``realtime_priority``).
    priority: str = ""

    @property
    def stopped(self) -> list[DeviceRun]:
        """The device runs that ended early."""
        return [run for run in self.runs if not run.complete]

    def device_mean(self, name: str) -> FloatArray:
        """Mean over the device runs of a signal (over their common length)."""
        n = min(trace.t.size for trace in self.device)
        return np.mean([signal(trace, name)[:n] for trace in self.device], axis=0)

    def spread(self, name: str) -> float:
        """Return the device's spread: mean RMSE of each run against the mean of the others."""
        if len(self.device) < 2:
            return math.nan
        n = min(trace.t.size for trace in self.device)
        runs = np.array([signal(trace, name)[:n] for trace in self.device])
        others = [np.delete(runs, i, axis=0).mean(axis=0) for i in range(len(runs))]
        return float(np.mean([rmse(run, other) for run, other in zip(runs, others, strict=True)]))

    def gap(self, model: str, name: str) -> float:
        """RMSE of a model's signal against the device mean."""
        return rmse(signal(self.models[model], name), self.device_mean(name))

    def fit(self, model: str, name: str) -> float:
        """NRMSE fit (%) of a model's signal to the device mean."""
        return fit_percent(signal(self.models[model], name), self.device_mean(name))


def build_controller(env: Any, controller: str, gains: PIDGains) -> Controller:
    """Build the paper's PID, or PID + the friction compensator with the env's model."""
    pid = PID.for_env(env, gains)
    return pid if controller == "pid" else FrictionCompensator(pid)


def check_reference(env_id: str, reference: float) -> float:
    """Return the env's safety limit; refuse a ``reference`` that lies beyond it.

    A step to such a target would end every run at the limit (the servo's ``|angle| >
    4π``, the Altino's wall), with nothing to compare.
    """
    device = devices.get(env_id)
    limit, unit, wall = device.limit, device.position_unit, device.sensor == SENSOR_IR
    real_number("the reference", reference)
    if not wall and abs(reference) >= limit:
        raise ValueError(
            f"reference {reference:g} {unit} lies beyond the safety limit of {limit:.4g} {unit} "
            f"of {device.title}, which ends a run when |{device.output}| passes it: give a "
            f"reference within ±{limit:.4g} {unit}"
        )
    if wall and reference <= limit:
        raise ValueError(
            f"reference {reference:g} {unit} is at or behind the safety limit of {limit:g} {unit} "
            f"from the wall, which ends a run: give a distance above {limit:g} {unit}"
        )
    farthest = float(ir_estimate(1))  # readout 0 means "out of range", not a distance
    if wall and reference > farthest:
        raise ValueError(
            f"reference {reference:g} cm is beyond the IR sensor's range (its farthest reading "
            f"is {farthest:.3g} cm): the car would not see when it got there and would keep "
            f"backing away; give a distance above {limit:g} and at most {farthest:.3g} cm"
        )
    return limit


def _ended_early(
    session: Any, trace: Rollout, limit: float, device: devices.Device
) -> tuple[str, str]:
    """How a terminated run ended: by the device's distance guard or the env's safety limit."""
    steps = trace.t.size - 1
    sample = session.last_sample
    if sample is not None and sample.status & Status.LIMIT:
        return DEVICE_LIMIT, f"the device's distance guard stopped it after {steps} steps"
    output, wall = device.output, device.sensor == SENSOR_IR
    where = f"its {output} fell to {limit:g}" if wall else f"|{output}| passed {limit:.4g}"
    detail = f"the safety limit ended it after {steps} steps ({where} {device.position_unit})"
    return SAFETY_LIMIT, detail


def run_sim2real(
    env_id: str,
    backend: object,
    *,
    controller: str = "pid",
    gains: PIDGains | None = None,
    params: str | None = None,
    repeats: int = 5,
    steps: int | None = None,
    reference: float | None = None,
    log: object = True,
    progress: Callable[[str], None] | None = None,
) -> Sim2RealResult:
    """Run ``controller`` on the device ``repeats`` times and once on each simulated model.

    A run that the safety limit ends, or that the device's watchdog stops, is recorded as such
    (:attr:`Sim2RealResult.runs`) and left out of the comparison; the other runs go on. The
    device runs hold the host loop at real-time priority where the system permits it
    (:func:`frictiongym.hardware.realtime.realtime_priority`).

    Parameters
    ----------
    env_id : str
        ``frictiongym/RotaryServo-v1`` or ``frictiongym/AltinoDistance-v1``.
    backend : str or Backend
        The device (``emulator://`` in tests).
    controller : {"pid", "compensated"}
        The paper's PID, or PID + friction compensator (its model: ``params`` if given, else
        the paper's friction).
    gains : PIDGains, optional
        Default: the paper's for this device and controller.
    params : str, optional
        An identified ``friction.json``: a third simulated model, "identified", and the
        compensator's model.
    repeats : int, default 5
        Device runs (their spread is the noise floor).
    steps : int, optional
        Steps per run (default: the env's episode length).
    reference : float, optional
        Step target (default: the env's step); refused beyond the env's safety limit.
    log : bool or path
        The device run log (see :class:`~frictiongym.envs.device.DeviceSession`).
    progress : callable, optional
        Called with a short text before each run, and when a run ends early.
    """
    if env_id not in ENV_IDS:
        envs.device_of_id(env_id, sorted(ENV_IDS))  # a description file, or the error
    if controller not in CONTROLLERS:
        raise ValueError(f"controller must be one of {CONTROLLERS}, got {controller!r}")
    if not (isinstance(repeats, int) and repeats >= 1):
        raise ValueError(f"repeats must be a positive integer, got {repeats!r}")
    if gains is None:  # the paper's (§3.1, §3.2, §5)
        gains = PIDGains(**devices.get(env_id).paper_gains[controller])
    task: dict[str, Any] = {} if reference is None else {"reference": float(reference)}
    if reference is not None:
        check_reference(env_id, float(reference))
    if params is not None:
        task["params"] = params
    models: dict[str, tuple[dict[str, Any], str]] = {
        "nominal": ({"friction": "none"}, "nominal plant, no friction"),
        "friction": ({"friction": "paper"}, "nominal plant + the paper's friction"),
    }
    if params:
        models["identified"] = ({"params": params}, f"the identified model ({params})")
    say = progress or (lambda _: None)
    metadata = {"controller": controller, "gains": gains, "tool": "sim2real"}
    device_env = envs.make(env_id, backend=backend, log=log, run_metadata=metadata, **task)
    try:
        ctrl = build_controller(device_env, controller, gains)
        n = int(steps or devices.get(env_id).episode_steps)  # the registered episode length
        session: Any = device_env.unwrapped.sim
        limit = float(session.limit)
        runs: list[DeviceRun] = []
        with realtime_priority() as priority:
            for r in range(1, repeats + 1):
                say(f"device run {r}/{repeats}")
                faults_before = len(session.faults)
                try:
                    trace = rollout(device_env, ctrl, n)
                except (WatchdogTripError, DeviceTimeoutError, DeviceDisconnectedError) as exc:
                    # A host stall or a link fault ends this run only; a device gone, the rest.
                    ended = _fault_kind(exc)
                    done = _steps_before_fault(session, faults_before)
                    runs.append(DeviceRun(r, done, ended, str(exc), None))
                    say(f"device run {r} ended by {FAULT_TEXT[ended]} after {done} steps: {exc}")
                    if ended == DISCONNECTED:
                        break
                    continue
                if trace.terminated[0]:
                    ended, detail = _ended_early(session, trace, limit, devices.get(env_id))
                    say(f"device run {r}: {detail}")
                else:
                    ended, detail = COMPLETE, f"{trace.t.size - 1} steps"
                runs.append(DeviceRun(r, trace.t.size - 1, ended, detail, trace))
        if session.log is not None:
            session.log.update(priority=priority)
        timing, periods = session.timing(), np.asarray(session.periods)
        log_dir = None if session.log is None else str(session.log.directory)
    finally:
        device_env.close()
    traces = {}
    for name, (kwargs, _) in models.items():
        say(f"simulated model: {name}")
        sim_env = envs.make(env_id, **{k: v for k, v in task.items() if k != "params"}, **kwargs)
        try:
            traces[name] = rollout(sim_env, ctrl, n)
        finally:
            sim_env.close()
    return Sim2RealResult(
        env_id=env_id,
        backend=str(backend),
        controller=controller,
        gains={"kp": float(gains.kp), "ki": float(gains.ki), "kd": float(gains.kd)},
        device=[run.trace for run in runs if run.complete and run.trace is not None],
        models=traces,
        model_descriptions={name: text for name, (_, text) in models.items()},
        timing=timing,
        periods=periods,
        log_dir=log_dir,
        runs=runs,
        priority=priority,
    )
