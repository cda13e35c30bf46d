"""Run one controller on a device and on simulated models of it, and measure the gap.

:func:`run_sim2real` runs the controller ``repeats`` times on the device (its own spread is the
noise floor), once on each simulated model (the nominal plant without friction, and the
friction-augmented or identified one), and compares what the controller saw: the measured
output, the estimated velocity and the applied command.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from frictiongym.controllers import PID, Controller, FrictionCompensator, PIDGains, rollout
from frictiongym.envs import ENV_IDS
from frictiongym.hardware.runlog import Timing
from frictiongym.metrics import ResponseMetrics, response_metrics
from frictiongym.plants.presets import (
    ALTINO_PAPER_GAINS_COMPENSATED,
    ALTINO_PAPER_GAINS_KI10,
    ROTARY_PAPER_GAINS,
)

FloatArray = npt.NDArray[np.float64]

#: The paper's gains per env id and controller (§3.1, §3.2, §5).
PAPER_GAINS = {
    ("frictiongym/RotaryServo-v0", "pid"): ROTARY_PAPER_GAINS,
    ("frictiongym/RotaryServo-v0", "compensated"): ROTARY_PAPER_GAINS,
    ("frictiongym/AltinoDistance-v0", "pid"): ALTINO_PAPER_GAINS_KI10,
    ("frictiongym/AltinoDistance-v0", "compensated"): ALTINO_PAPER_GAINS_COMPENSATED,
}
CONTROLLERS = ("pid", "compensated")
#: Signals compared, as (name, unit key): the controller's view of the loop.
SIGNALS = ("output", "velocity", "command")


@dataclass(frozen=True)
class Trace:
    """One closed-loop episode as the controller saw it (``n`` samples)."""

    t: FloatArray
    output: FloatArray  #: the measured output (angle, or distance estimate)
    velocity: FloatArray  #: the estimated velocity in the observation
    command: FloatArray  #: applied command held from ``t[k]`` (the last repeats)
    reference: FloatArray
    terminated: bool

    def signal(self, name: str) -> FloatArray:
        """Return the signal ``name`` (one of :data:`SIGNALS`)."""
        values: FloatArray = getattr(self, name)
        return values

    def metrics(self) -> ResponseMetrics:
        """Step metrics of the measured output against the final reference."""
        return response_metrics(
            self.t, self.output, float(self.reference[-1]), command=self.command,
            y0=float(self.output[0]),
        )  # fmt: skip


def record(env: Any, controller: Controller, steps: int) -> Trace:
    """Run one episode of ``controller`` on ``env`` for ``steps`` steps (or until it ends)."""
    run = rollout(env, controller, steps)
    return Trace(
        t=run.t,
        output=run.signal("measured"),
        velocity=run.signal("rate"),
        command=run.signal("command"),
        reference=run.signal("reference"),
        terminated=bool(run.terminated[0]),
    )


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
    device: list[Trace]
    models: dict[str, Trace]
    model_descriptions: dict[str, str]
    timing: Timing | None
    periods: FloatArray = field(default_factory=lambda: np.zeros(0))
    log_dir: str | None = None

    def device_mean(self, name: str) -> FloatArray:
        """Mean over the device runs of a signal (over their common length)."""
        n = min(trace.t.size for trace in self.device)
        return np.mean([trace.signal(name)[:n] for trace in self.device], axis=0)

    def spread(self, name: str) -> float:
        """Return the device's spread: mean RMSE of each run against the mean of the others."""
        if len(self.device) < 2:
            return math.nan
        n = min(trace.t.size for trace in self.device)
        runs = np.array([trace.signal(name)[:n] for trace in self.device])
        errors = []
        for i in range(len(runs)):
            others = np.delete(runs, i, axis=0).mean(axis=0)
            errors.append(rmse(runs[i], others))
        return float(np.mean(errors))

    def gap(self, model: str, name: str) -> float:
        """RMSE of a model's signal against the device mean."""
        return rmse(self.models[model].signal(name), self.device_mean(name))

    def fit(self, model: str, name: str) -> float:
        """NRMSE fit (%) of a model's signal to the device mean."""
        return fit_percent(self.models[model].signal(name), self.device_mean(name))

    def device_metrics(self) -> list[ResponseMetrics]:
        """Step metrics of each device run."""
        return [trace.metrics() for trace in self.device]


def build_controller(env: Any, controller: str, gains: PIDGains) -> Controller:
    """Build the paper's PID, or PID + the friction compensator with the env's model."""
    pid = PID.for_env(env, gains)
    return pid if controller == "pid" else FrictionCompensator(pid)


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

    Parameters
    ----------
    env_id : str
        ``frictiongym/RotaryServo-v0`` or ``frictiongym/AltinoDistance-v0``.
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
        Step target (default: the env's step).
    log : bool or path
        The device run log (see :class:`~frictiongym.envs.device.DeviceSession`).
    progress : callable, optional
        Called with a short text before each run.
    """
    if env_id not in ENV_IDS:
        raise ValueError(f"unknown env id {env_id!r}; use one of {sorted(ENV_IDS)}")
    if controller not in CONTROLLERS:
        raise ValueError(f"controller must be one of {CONTROLLERS}, got {controller!r}")
    if not (isinstance(repeats, int) and repeats >= 1):
        raise ValueError(f"repeats must be a positive integer, got {repeats!r}")
    if gains is None:
        if (env_id, controller) not in PAPER_GAINS:
            raise ValueError(f"no paper gains for {env_id!r}; pass gains")
        gains = PIDGains(**PAPER_GAINS[env_id, controller])
    task: dict[str, Any] = {} if reference is None else {"reference": float(reference)}
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
    device_env = gym.make(env_id, backend=backend, log=log, run_metadata=metadata, **task)
    try:
        ctrl = build_controller(device_env, controller, gains)
        n = int(steps or getattr(device_env.spec, "max_episode_steps", 0) or 0)
        if n < 1:
            raise ValueError("give steps: the env has no registered episode length")
        runs = []
        for r in range(repeats):
            say(f"device run {r + 1}/{repeats}")
            runs.append(record(device_env, ctrl, n))
        session: Any = device_env.unwrapped.sim  # type: ignore[attr-defined]
        timing, periods = session.timing(), np.asarray(session.periods)
        log_dir = None if session.log is None else str(session.log.directory)
    finally:
        device_env.close()
    traces = {}
    for name, (kwargs, _) in models.items():
        say(f"simulated model: {name}")
        sim_kwargs = {**{k: v for k, v in task.items() if k != "params"}, **kwargs}
        sim_env = gym.make(env_id, **{k: v for k, v in sim_kwargs.items() if v is not None})
        try:
            traces[name] = record(sim_env, ctrl, n)
        finally:
            sim_env.close()
    return Sim2RealResult(
        env_id=env_id, backend=str(backend), controller=controller,
        gains={"kp": float(gains.kp), "ki": float(gains.ki), "kd": float(gains.kd)},
        device=runs, models=traces,
        model_descriptions={name: text for name, (_, text) in models.items()},
        timing=timing, periods=periods, log_dir=log_dir,
    )  # fmt: skip


def differences(result: Sim2RealResult, keys: Sequence[str]) -> dict[str, dict[str, float]]:
    """Model minus device-mean of each step metric in ``keys``, per model."""
    device = [m.as_dict() for m in result.device_metrics()]
    out = {}
    for name, trace in result.models.items():
        model = trace.metrics().as_dict()
        out[name] = {k: model[k] - float(np.mean([d[k] for d in device])) for k in keys}
    return out
