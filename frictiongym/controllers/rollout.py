"""Roll out any controller on any frictiongym env, single or vector, and keep the signals.

:class:`Rollout` is the package's one record of a run: the benchmark, sim2real, the paper's
step experiments (:mod:`frictiongym.loops`) and identification's command profiles all record
into it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym.controllers.base import Controller, FloatArray
from frictiongym.metrics import ResponseMetrics, response_metrics

BoolArray = npt.NDArray[np.bool_]
#: ``info`` keys recorded by :func:`rollout` (the env contract, docs/envs.md).
SIGNALS = ("position", "velocity", "command", "reference", "time")


@dataclass(frozen=True)
class Rollout:
    """Signals of a run, sample ``k`` at time ``t[k]``, one column per env.

    ``position``, ``velocity`` and ``reference`` are the true state from ``info``;
    ``measured`` and ``rate`` are the output and its rate as the controller saw them (its
    observation entries; ``rate`` is NaN when the observation has none); ``command[k]`` is
    the applied (saturated) command held from ``t[k]`` to ``t[k+1]`` (the last sample repeats
    it); ``reward[k]`` is the reward of the step that ended at ``t[k]`` (0 at ``k = 0``);
    ``stuck[k]`` tells whether friction held the body at ``t[k]``; ``valid[k]`` whether the
    measured output lay inside its observation bounds (the sensor not saturated). Env ``i``
    has ``length[i]`` recorded samples (fewer when it terminated, e.g. the Altino touching
    the wall); the rest are NaN. A signal that was not recorded is NaN throughout.

    ``direction`` is the loop's sign (:class:`~frictiongym.controllers.LoopSpec`): -1 when a
    positive command lowers the output (the Altino's distance). ``settings`` says what was
    run, e.g. an identification experiment's ``kind``, ``sign`` and levels.
    """

    t: FloatArray
    position: FloatArray
    velocity: FloatArray
    measured: FloatArray
    rate: FloatArray
    command: FloatArray
    reference: FloatArray
    reward: FloatArray
    stuck: BoolArray
    valid: BoolArray
    length: npt.NDArray[np.int64]
    terminated: BoolArray
    direction: float = 1.0
    settings: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def of_one_run(
        cls,
        t: FloatArray,
        terminated: bool = False,
        direction: float = 1.0,
        settings: dict[str, Any] | None = None,
        **signals: npt.ArrayLike,
    ) -> Rollout:
        """Record one run from its 1-D signals (keyword per field); missing ones are NaN.

        ``stuck`` and ``valid`` default to False and True.
        """
        n = int(np.shape(t)[0])
        columns: dict[str, Any] = {name: np.full((n, 1), np.nan) for name in _FLOAT_SIGNALS}
        columns["stuck"] = np.zeros((n, 1), dtype=bool)
        columns["valid"] = np.ones((n, 1), dtype=bool)
        unknown = sorted(set(signals) - set(columns))
        if unknown:
            raise TypeError(f"Rollout has no signal {unknown}; give some of {sorted(columns)}")
        for name, values in signals.items():
            columns[name] = np.asarray(values, dtype=columns[name].dtype).reshape(n, 1)
        return cls(
            t=np.asarray(t, dtype=np.float64),
            length=np.array([n], dtype=np.int64),
            terminated=np.array([terminated]),
            direction=float(direction),
            settings=dict(settings or {}),
            **columns,
        )

    @property
    def num_envs(self) -> int:
        """Number of envs (columns)."""
        return int(self.position.shape[1])

    def signal(self, name: str, env: int = 0) -> npt.NDArray[Any]:
        """Return the recorded samples of signal ``name`` for env ``env``."""
        values: npt.NDArray[Any] = getattr(self, name)
        return values[: self.length[env], env]

    def plant_output(self, env: int = 0) -> FloatArray:
        """Return the measured output signed so that a positive command drives it up."""
        return self.direction * self.signal("measured", env)

    def metrics(self, env: int = 0, output: str = "position", **kwargs: Any) -> ResponseMetrics:
        """Response metrics of env ``env``'s ``output`` against its final reference.

        ``output`` is ``"position"`` (the true output, with the stick flags) or
        ``"measured"`` (what the controller saw, which carries no stick flags). Keyword
        arguments go to :func:`frictiongym.metrics.response_metrics`.
        """
        if output not in ("position", "measured"):
            raise ValueError(f"output must be 'position' or 'measured', got {output!r}")
        n = int(self.length[env])
        if n < 2:
            raise ValueError(f"env {env} has {n} sample(s): too short for metrics")
        y = getattr(self, output)[:n, env]
        return response_metrics(
            self.t[:n],
            y,
            float(self.reference[n - 1, env]),
            command=self.command[:n, env],
            stuck=self.stuck[:n, env] if output == "position" else None,
            y0=float(y[0]),
            **kwargs,
        )


#: The per-sample float signals of :class:`Rollout`.
_FLOAT_SIGNALS = ("position", "velocity", "measured", "rate", "command", "reference", "reward")


def _episode_steps(env: Any) -> int | None:
    spec = getattr(env, "spec", None)
    steps = getattr(spec, "max_episode_steps", None)
    return steps if steps is not None else getattr(env.unwrapped, "max_episode_steps", None)


def rollout(
    env: Any,
    controller: Controller,
    steps: int | None = None,
    *,
    seed: int | list[int] | None = None,
    options: dict[str, Any] | None = None,
) -> Rollout:
    """Run one episode of ``controller`` on ``env`` and record every signal.

    Parameters
    ----------
    env : gymnasium.Env or gymnasium.vector.VectorEnv
        A frictiongym env (``gym.make`` or ``gym.make_vec``); a vector env runs its envs side
        by side, each recorded until its episode ends (it is not followed into autoreset).
    controller : Controller
        Built for this env (``PID.for_env(env, gains)``); it is reset with the env.
    steps : int, optional
        Steps to run; the env's episode length by default.
    seed, options
        Passed to ``env.reset``.

    Returns
    -------
    Rollout
        ``steps + 1`` samples (the reset state, then one per step), fewer if every env's
        episode ended earlier.
    """
    steps = steps if steps is not None else _episode_steps(env)
    if steps is None or int(steps) < 1:
        raise ValueError(f"steps must be a positive number of steps, got {steps!r}")
    n = int(getattr(env, "num_envs", 1))
    size = (int(steps) + 1, n)
    rec = {name: np.full(size, np.nan) for name in (*SIGNALS, "measured", "rate", "reward")}
    stuck = np.zeros(size, dtype=bool)
    active = np.ones(n, dtype=bool)
    length = np.full(n, size[0], dtype=np.int64)
    terminated = np.zeros(n, dtype=bool)

    def record(k: int, obs: Any, info: dict[str, Any], mask: BoolArray) -> None:
        for name in SIGNALS:
            if name in info:
                rec[name][k, mask] = np.asarray(info[name], dtype=np.float64).reshape(n)[mask]
        seen = np.asarray(obs, dtype=np.float64).reshape(n, -1)[mask]
        rec["measured"][k, mask] = seen[:, controller.spec.position]
        if controller.spec.velocity is not None:
            rec["rate"][k, mask] = seen[:, controller.spec.velocity]
        if "stuck" in info:
            stuck[k, mask] = np.asarray(info["stuck"], dtype=bool).reshape(n)[mask]

    obs, info = env.reset(seed=seed, options=options)
    controller.reset()
    record(0, obs, info, active)
    rec["reward"][0] = 0.0
    for k in range(1, size[0]):
        obs, reward, term, trunc, info = env.step(controller(obs))
        record(k, obs, info, active)
        rec["reward"][k, active] = np.asarray(reward, dtype=np.float64).reshape(n)[active]
        rec["command"][k - 1, active] = rec["command"][k, active]
        ended = active & (np.asarray(term).reshape(n) | np.asarray(trunc).reshape(n))
        terminated |= active & np.asarray(term).reshape(n)
        length[ended] = k + 1
        active &= ~ended
        if not active.any():
            break
    m = int(length.max())  # every env may have ended before ``steps``
    t = rec.pop("time")[:m, int(np.argmax(length))]
    trimmed: dict[str, Any] = {name: values[:m] for name, values in rec.items()}
    low, high = observation_bounds(env, controller.spec.position)
    valid = (low < trimmed["measured"]) & (trimmed["measured"] < high)
    return Rollout(
        t=t,
        stuck=stuck[:m],
        valid=valid,
        length=length,
        terminated=terminated,
        direction=controller.spec.direction,
        **trimmed,
    )


def observation_bounds(env: Any, index: int) -> tuple[float, float]:
    """Bounds of observation entry ``index`` (infinite when the space has none)."""
    space = getattr(env, "single_observation_space", env.observation_space)
    low, high = getattr(space, "low", None), getattr(space, "high", None)
    if low is None or high is None:
        return -np.inf, np.inf
    return float(low[index]), float(high[index])
