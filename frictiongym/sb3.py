"""Stable-Baselines3 on the native vector env: N envs in one compiled call.

:class:`FrictionVecEnv` is a Stable-Baselines3 ``VecEnv`` over a frictiongym native vector env
(or a :class:`~frictiongym.residual.vector_env.ResidualVectorEnv` over one), so SB3's
algorithms and its ``VecNormalize`` and ``VecMonitor`` run on it as on a ``DummyVecEnv``
over the single envs, and get the same trajectories for the same seeds::

    from stable_baselines3 import PPO
    from frictiongym.residual.vector_env import make_residual_vec
    from frictiongym.sb3 import FrictionVecEnv, make_sb3_vec

    env = make_sb3_vec("frictiongym/RotaryServo-v1", n_envs=32)
    PPO("MlpPolicy", env, seed=0).learn(100_000)
    # residual policies on the compensated PID:
    residual = FrictionVecEnv(make_residual_vec("frictiongym/RotaryServo-v1", 32))

It follows SB3's conventions: ``reset()`` returns the observations only (seeds go through
``seed()`` and options through ``set_options()`` first, each used by one reset); an env whose
episode ends is reset within the step, its last observation in ``infos[i]
["terminal_observation"]`` and ``infos[i]["TimeLimit.truncated"]`` set as SB3 reads it; the
reset's info goes to ``reset_infos``; rewards are float32. Needs the ``rl`` extra
(``pip install "frictiongym[rl]"``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium.vector import AutoresetMode, VectorEnv

from frictiongym import envs

try:
    from stable_baselines3.common.vec_env import VecEnv
    from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvStepReturn
except ImportError as exc:  # pragma: no cover - the rl extra is part of the test extra
    raise ImportError(
        f'frictiongym.sb3 needs Stable-Baselines3: pip install "frictiongym[rl]" ({exc})'
    ) from None


class FrictionVecEnv(VecEnv):
    """A Stable-Baselines3 ``VecEnv`` over a Gymnasium vector env in ``SAME_STEP`` autoreset.

    Parameters
    ----------
    env : gymnasium.vector.VectorEnv
        A frictiongym native vector env made with ``autoreset_mode=AutoresetMode.SAME_STEP``
        (:func:`make_sb3_vec`), or a ``ResidualVectorEnv``, either possibly under Gymnasium's
        vector wrappers (``gymnasium.wrappers.vector.RescaleAction``...).

    Notes
    -----
    ``get_attr``, ``set_attr`` and ``env_method`` go through the vector env's ``get_attr``,
    ``set_attr`` and ``call`` (the native env answers what a batch sharing one simulation
    can: :meth:`frictiongym.envs.vector.FrictionVectorEnv.call`). ``env_is_wrapped`` is
    False for every env: there are no per-env Gymnasium wrappers.
    """

    def __init__(self, env: VectorEnv[Any, Any, Any]) -> None:
        mode = env.metadata.get("autoreset_mode")
        if mode is not AutoresetMode.SAME_STEP:
            raise ValueError(
                f"FrictionVecEnv needs a vector env in autoreset mode SAME_STEP (SB3's), got "
                f"{mode}: make it with gym.make_vec(..., autoreset_mode=AutoresetMode.SAME_STEP) "
                "or use make_sb3_vec"
            )
        self.env: Any = env
        #: What answers call, get_attr and set_attr: the outermost env that has them (the
        #: native env or the residual env, under Gymnasium's vector wrappers, which do not).
        self._calls: Any = env
        while not hasattr(self._calls, "call") and hasattr(self._calls, "env"):
            self._calls = self._calls.env
        self._actions: npt.NDArray[Any] | None = None
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)

    def reset(self) -> npt.NDArray[np.float32]:
        """Reset every env with the seeds of :meth:`seed` and options of ``set_options``."""
        options = self._options[0]
        if any(o != options for o in self._options[1:]):
            raise ValueError(
                "the native vector env takes one set of reset options for all its envs; "
                "give set_options one dict"
            )
        inner: Any = self.env  # a frictiongym vector env, which takes a list of seeds
        obs, info = inner.reset(seed=list(self._seeds), options=dict(options) or None)
        self.reset_infos = _split(info, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: npt.NDArray[Any]) -> None:
        """Store the actions of the next :meth:`step_wait`."""
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        """Step every env; the ended ones are reset within the step (SB3's convention)."""
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async(actions) first")
        actions, self._actions = self._actions, None
        obs, reward, terminated, truncated, info = self.env.step(actions)
        dones = terminated | truncated
        infos = _split(info, self.num_envs)
        if dones.any():
            last = _split(info["final_info"], self.num_envs)
            final_obs = info["final_obs"]
            for k in np.flatnonzero(dones).tolist():
                self.reset_infos[k] = infos[k]
                infos[k] = last[k]
                infos[k]["terminal_observation"] = final_obs[k]
        for i, (ended, cut) in enumerate(zip(terminated.tolist(), truncated.tolist(), strict=True)):
            infos[i]["TimeLimit.truncated"] = cut and not ended
        return obs, reward.astype(np.float32), dones, infos

    def close(self) -> None:
        """Close the vector env."""
        self.env.close()

    def get_images(self) -> Sequence[npt.NDArray[np.uint8] | None]:
        """One RGB frame per env (``render_mode="rgb_array"``)."""
        frames = self.env.render() if self.render_mode == "rgb_array" else None
        return list(frames) if frames is not None else [None] * self.num_envs

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Return an attribute of the envs ``indices`` (all by default)."""
        own = {"action_space": self.action_space, "observation_space": self.observation_space}
        if attr_name in own:  # what the policy sees, through any wrapper (RescaleAction)
            return [own[attr_name] for _ in self._get_indices(indices)]
        values = self._calls.get_attr(attr_name)
        return [values[i] for i in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute of every env (the native envs share one value of each)."""
        if sorted(self._get_indices(indices)) != list(range(self.num_envs)):
            raise ValueError(
                f"set_attr({attr_name!r}): the native vector env's envs share one value of each "
                "attribute; set it for all of them (indices=None)"
            )
        self._calls.set_attr(attr_name, value)

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        """Return ``env_i.method_name(*args, **kwargs)`` of the envs ``indices``."""
        results = self._calls.call(method_name, *method_args, **method_kwargs)
        return [results[i] for i in self._get_indices(indices)]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper[Any, Any, Any, Any]], indices: VecEnvIndices = None
    ) -> list[bool]:
        """Return False for each env: the native envs have no per-env Gymnasium wrappers."""
        return [False for _ in self._get_indices(indices)]


def _split(info: dict[str, Any], n: int) -> list[dict[str, Any]]:
    """Turn a Gymnasium vector info (arrays and ``_key`` masks) into one dict per env."""
    infos: list[dict[str, Any]] = [{} for _ in range(n)]
    for key, value in info.items():
        if key.startswith("_") or key in ("final_obs", "final_info"):
            continue
        present = info.get("_" + key)
        entries: Iterable[Any] = value.tolist() if isinstance(value, np.ndarray) else value
        for i, (entry, has) in enumerate(
            zip(entries, [True] * n if present is None else present.tolist(), strict=True)
        ):
            if has:
                infos[i][key] = entry
    return infos


def make_sb3_vec(
    env_id: str, n_envs: int, *, seed: int | None = None, **env_kwargs: Any
) -> FrictionVecEnv:
    """Make a :class:`FrictionVecEnv` of ``n_envs`` envs of ``env_id`` on its native vector env.

    Parameters
    ----------
    env_id : str
        A frictiongym id.
    n_envs : int
        Number of envs, stepped in one compiled call.
    seed : int, optional
        Seeds the first reset (env ``i``: ``seed + i``), as ``make_vec_env(seed=...)`` does.
    **env_kwargs
        Arguments of the env (``randomize``, ``reference``, ``max_episode_steps``...).

    See Also
    --------
    frictiongym.residual.vector_env.make_residual_vec : residual envs on the native vector
        env, for ``FrictionVecEnv(make_residual_vec(env_id, n_envs))``.
    """
    env = envs.make_vec(
        env_id, num_envs=n_envs, autoreset_mode=AutoresetMode.SAME_STEP, **env_kwargs
    )
    vec = FrictionVecEnv(env)
    if seed is not None:
        vec.seed(seed)
    return vec
