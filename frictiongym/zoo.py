r"""RL from scratch: the shipped hyperparameters, in the RL Zoo's format, on the native env.

``frictiongym/hyperparams/<algo>.yml`` holds PPO's and SAC's settings for the v1 envs in
the format of the SB3 RL Zoo, so a user of the Zoo runs them as they are::

    python -m rl_zoo3.train --algo ppo --env frictiongym/AltinoDistance-v1 \
        --gym-packages frictiongym --conf-file "$(python -m frictiongym.zoo ppo)"

:func:`train` trains the same settings with Stable-Baselines3 on the native vector env
(``frictiongym.sb3``: the same trajectories as the Zoo's ``DummyVecEnv`` over the single
envs, many times faster), and :func:`episode_return` scores a policy, or any controller, on
an episode of the env. Needs the ``rl`` extra.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
import yaml  # type: ignore[import-untyped]
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers.vector import RescaleAction

from frictiongym.sb3 import FrictionVecEnv

#: The folder of the YAML files, one per algorithm.
HYPERPARAMS = Path(__file__).parent / "hyperparams"
#: The Zoo's keys that are not constructor arguments of the algorithm.
_ZOO_KEYS = ("env_wrapper", "normalize", "n_envs", "n_timesteps", "policy", "policy_kwargs")


@dataclass(frozen=True)
class ZooSettings:
    """One env's entry of a Zoo YAML file, parsed."""

    algo: str
    env_id: str
    n_timesteps: int
    n_envs: int = 1
    #: ``VecNormalize``'s arguments (the Zoo's ``normalize: true`` is ``{}``); None: none
    normalize: dict[str, Any] | None = None
    rescale: tuple[float, float] | None = None  #: ``RescaleAction``'s bounds, if wrapped
    policy: str = "MlpPolicy"
    policy_kwargs: dict[str, Any] = field(default_factory=dict)
    hyperparameters: dict[str, Any] = field(default_factory=dict)  #: the algorithm's


def conf_file(algo: str) -> Path:
    """Return the YAML file of ``algo`` (``"ppo"``, ``"sac"``), for the Zoo's ``--conf-file``."""
    path = HYPERPARAMS / f"{algo}.yml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in HYPERPARAMS.glob("*.yml")))
        raise ValueError(f"no shipped hyperparameters for {algo!r}; there are: {known}")
    return path


def load(algo: str, env_id: str) -> ZooSettings:
    """Return the shipped settings of ``algo`` on ``env_id``.

    Raises
    ------
    ValueError
        If there are none, or an entry uses what this reader does not take (the message
        names it): wrappers other than ``RescaleAction``, or ``policy_kwargs`` that are not a
        ``dict(...)`` of plain values.
    """
    entries = yaml.safe_load(conf_file(algo).read_text())
    if env_id not in entries:
        raise ValueError(f"{conf_file(algo)} has no entry for {env_id}; it has {sorted(entries)}")
    entry = dict(entries[env_id])
    rescale = None
    for wrapper in entry.get("env_wrapper", []):
        (name, arguments), *more = wrapper.items()
        if more or name != "gymnasium.wrappers.RescaleAction":
            raise ValueError(f"{env_id}: wrapper {wrapper} is not gymnasium's RescaleAction")
        rescale = (float(arguments["min_action"]), float(arguments["max_action"]))
    return ZooSettings(
        algo=algo,
        env_id=env_id,
        n_timesteps=int(entry["n_timesteps"]),
        n_envs=int(entry.get("n_envs", 1)),
        normalize=_normalize(entry.get("normalize", False), env_id),
        rescale=rescale,
        policy=entry.get("policy", "MlpPolicy"),
        policy_kwargs=_plain_dict(entry.get("policy_kwargs", "dict()"), env_id),
        hyperparameters={k: _schedule(v) for k, v in entry.items() if k not in _ZOO_KEYS},
    )


@dataclass(frozen=True)
class LinearSchedule:
    """The Zoo's ``lin_<x>``: a value falling linearly from ``x`` to 0 over the training."""

    start: float

    def __call__(self, progress_remaining: float) -> float:
        """Return the value when ``progress_remaining`` (1 at the start, 0 at the end) is left."""
        return progress_remaining * self.start


def _schedule(value: Any) -> Any:
    """Read the Zoo's ``lin_<x>`` (a linear schedule); anything else as it is."""
    if isinstance(value, str) and value.startswith("lin_"):
        return LinearSchedule(float(value[4:]))
    return value


def _normalize(value: Any, env_id: str) -> dict[str, Any] | None:
    """Read the Zoo's ``normalize``: a bool, or a string of ``VecNormalize``'s arguments."""
    if isinstance(value, bool):
        return {} if value else None
    try:
        arguments = ast.literal_eval(value)
    except (ValueError, SyntaxError):
        arguments = None
    if not isinstance(arguments, dict):
        raise ValueError(f"{env_id}: normalize {value!r} is neither a bool nor a dict of values")
    return arguments


def _plain_dict(text: str, env_id: str) -> dict[str, Any]:
    """Read the Zoo's ``"dict(key=value, ...)"`` string of literal values (nothing evaluated)."""
    node = ast.parse(text, mode="eval").body
    if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)):
        raise ValueError(f"{env_id}: policy_kwargs {text!r} is not dict(...)")
    if node.func.id != "dict" or node.args:
        raise ValueError(f"{env_id}: policy_kwargs {text!r} is not dict(key=value, ...)")
    try:
        return {k.arg: ast.literal_eval(k.value) for k in node.keywords if k.arg}
    except ValueError:
        raise ValueError(f"{env_id}: policy_kwargs {text!r} holds more than plain values") from None


def make_env(settings: ZooSettings, seed: int, n_envs: int | None = None) -> Any:
    """Return the training VecEnv of ``settings``: native env, RescaleAction, VecNormalize.

    What the Zoo builds from the same entry (``DummyVecEnv`` over single envs under
    ``RescaleAction``, then ``VecNormalize`` with the algorithm's discount), on the native
    vector env.
    """
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    vec: Any = gym.make_vec(
        settings.env_id,
        num_envs=n_envs or settings.n_envs,
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    if settings.rescale is not None:
        vec = RescaleAction(vec, *settings.rescale)
    env: Any = VecMonitor(FrictionVecEnv(vec))
    if settings.normalize is not None:
        gamma = settings.hyperparameters.get("gamma", 0.99)
        env = VecNormalize(env, **{"gamma": gamma, **settings.normalize})
    env.seed(seed)
    return env


def train(
    settings: ZooSettings, seed: int, steps: int | None = None, callback: Any = None
) -> tuple[Any, Any]:
    """Train ``settings`` from scratch; return the model and its training env.

    The env is needed to run the policy: with ``normalize`` it holds the observation
    statistics the policy was trained on (:func:`policy_controller`).
    """
    import stable_baselines3

    env = make_env(settings, seed)
    algorithm = getattr(stable_baselines3, settings.algo.upper())
    model = algorithm(
        settings.policy,
        env,
        seed=seed,
        device="cpu",
        policy_kwargs=settings.policy_kwargs,
        **settings.hyperparameters,
    )
    model.learn(steps or settings.n_timesteps, callback=callback)
    return model, env


def policy_controller(
    model: Any, env: Any, settings: ZooSettings
) -> Callable[[npt.NDArray[np.float32]], npt.NDArray[np.float32]]:
    """Return ``obs -> action`` of a trained policy, deterministic, in the policy's units.

    Run it with :func:`episode_return` and ``rescale=settings.rescale``, as it was trained.
    """

    def act(obs: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        seen = env.normalize_obs(obs) if settings.normalize is not None else obs
        action, _ = model.predict(seen[None], deterministic=True)
        return np.asarray(action[0], np.float32)

    return act


def episode_return(
    env_id: str,
    act: Callable[[npt.NDArray[np.float32]], Any],
    seed: int = 0,
    rescale: tuple[float, float] | None = None,
    **env_kwargs: Any,
) -> float:
    """Return the reward summed over one episode of ``env_id`` under ``act``.

    ``act`` gives actions in the env's units, or in ``rescale``'s bounds for a policy trained
    under ``RescaleAction`` (the env is then wrapped as in training).
    """
    env: Any = gym.make(env_id, **env_kwargs)
    if rescale is not None:
        low, high = (np.float32(bound) for bound in rescale)
        env = gym.wrappers.RescaleAction(env, low, high)
    try:
        obs, _ = env.reset(seed=seed)
        total = 0.0
        while True:
            action = np.asarray(act(obs), np.float32).reshape(1)
            obs, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            if terminated or truncated:
                return total
    finally:
        env.close()


if __name__ == "__main__":  # python -m frictiongym.zoo ppo: the file for --conf-file
    try:
        print(conf_file(sys.argv[1] if len(sys.argv) > 1 else "ppo"))
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        sys.exit(2)
