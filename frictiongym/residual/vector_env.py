"""The residual env over a native vector env: N residual envs in one compiled call.

:class:`ResidualVectorEnv` is :class:`~frictiongym.residual.ResidualEnv` for a batch: one
batched base controller, one call of the env kernel per step. It runs the vector env in
Gymnasium's ``SAME_STEP`` autoreset mode (Stable-Baselines3's and CleanRL's): env ``i`` of
``reset(seed=s)`` gives exactly what a ``ResidualEnv`` over the single env reset with seed
``s + i`` gives, step for step and across episodes.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv, VectorWrapper
from gymnasium.vector.utils import batch_space

from frictiongym import envs
from frictiongym.controllers.base import FloatArray
from frictiongym.controllers.residual_core import (
    OBSERVATION_BOUND,
    OBSERVATION_SIZE,
    ResidualConfig,
    bounded_residual,
    residual_observation,
)
from frictiongym.residual.env import BaseSpec, residual_setup

ObsArray = npt.NDArray[np.float32]
#: The keys the residual env adds to the env's info.
ADDED_INFO = ("base_action", "residual")


class ResidualVectorEnv(VectorWrapper):
    """A native frictiongym vector env whose actions are bounded corrections to a base controller.

    Everything is as :class:`~frictiongym.residual.ResidualEnv` says, per env: the applied
    action, the observation, the reward, and ``info``'s ``base_action`` and ``residual``
    (with ``_base_action`` and ``_residual`` masks; an env reset within the step reports them
    in ``info["final_info"]``, as ``SyncVectorEnv`` over ``ResidualEnv`` does).

    Parameters
    ----------
    env : gymnasium.vector.VectorEnv
        A frictiongym native vector env made with ``autoreset_mode=AutoresetMode.SAME_STEP``
        (``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP, ...)``).
    base, config, scale, residual_cost, precision
        As for :class:`~frictiongym.residual.ResidualEnv`; the base controller is batched
        (one history per env).
    """

    def __init__(
        self,
        env: VectorEnv[Any, Any, Any],
        base: BaseSpec = None,
        *,
        config: ResidualConfig | None = None,
        scale: float | None = None,
        residual_cost: float = 0.0,
        precision: float | None = None,
    ) -> None:
        mode = env.metadata.get("autoreset_mode")
        if mode is not AutoresetMode.SAME_STEP:
            raise ValueError(
                f"ResidualVectorEnv needs a vector env in autoreset mode SAME_STEP, got {mode}: "
                "make it with gym.make_vec(..., autoreset_mode=AutoresetMode.SAME_STEP)"
            )
        super().__init__(env)
        self.base, self.config, self.objective = residual_setup(
            env, base, config, scale, residual_cost, precision
        )
        bound = OBSERVATION_BOUND
        self.single_action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.single_observation_space = spaces.Box(-bound, bound, (OBSERVATION_SIZE,), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._base_action: FloatArray = np.zeros(self.num_envs)

    def _observe(self, obs: Any, base_action: FloatArray) -> ObsArray:
        return residual_observation(obs, self.base.spec, base_action, self.config)

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[ObsArray, dict[str, Any]]:
        """Reset the envs (all, or ``options["reset_mask"]``'s) and their base controllers."""
        inner: Any = self.env  # a frictiongym vector env, which takes a list of seeds too
        obs, info = inner.reset(seed=seed, options=options)
        mask = (options or {}).get("reset_mask")
        self.base.reset(mask)
        if mask is None:
            self._base_action = self.base(obs)[:, 0]
        else:
            fresh = np.asarray(mask, dtype=bool)
            self._base_action[fresh] = self.base.advance(obs, fresh)[fresh, 0]
        return self._observe(obs, self._base_action), info

    def step(
        self, actions: Any
    ) -> tuple[ObsArray, FloatArray, npt.NDArray[np.bool_], npt.NDArray[np.bool_], dict[str, Any]]:
        """Apply each env's base action plus its bounded residual; see the class docstring."""
        n = self.num_envs
        residual = bounded_residual(np.asarray(actions).reshape(n, -1)[:, 0], self.config.scale)
        base = self._base_action
        total = np.clip(base + residual, -self.config.limit, self.config.limit)
        obs, reward, terminated, truncated, info = self.env.step(
            total.astype(np.float32).reshape(n, 1)
        )
        ended = np.asarray(info.get("_final_obs", np.zeros(n, dtype=bool)))
        last_obs, last_info = obs, info  # each env's observation and info of this step
        if ended.any():
            last_obs = obs.copy()
            last_obs[ended] = np.stack(list(info["final_obs"][ended]))
            last_info = {
                key: np.where(ended, info["final_info"][key], info[key])
                for key in ("reference", "position")
            }
        reward = self.objective.reward(
            reward, last_info["reference"], last_info["position"], residual, terminated
        )
        following = self.base(last_obs)[:, 0]  # every env's base sees its step's observation
        residual_obs = self._observe(last_obs, following)
        added = {"base_action": base.copy(), "residual": residual}
        if ended.any():
            info = self._ended(info, ended, residual_obs, added)
            self.base.reset(ended)
            following[ended] = self.base.advance(obs, ended)[ended, 0]
            residual_obs[ended] = self._observe(obs, following)[ended]
        if not ended.all():  # the envs reset within the step report them in final_info only
            for key, value in added.items():
                info[key] = np.where(ended, 0.0, value)
                info["_" + key] = ~ended
        self._base_action = following
        return residual_obs, np.asarray(reward, np.float64), terminated, truncated, info

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        """One result per env, as ``SyncVectorEnv`` over ``ResidualEnv`` answers.

        The residual env's own spaces, ``base``, ``config`` and ``objective``; the rest as the
        wrapped vector env answers (:meth:`frictiongym.envs.vector.FrictionVectorEnv.call`).
        """
        own = {
            "action_space": self.single_action_space,
            "observation_space": self.single_observation_space,
            "base": self.base,
            "config": self.config,
            "objective": self.objective,
        }
        if name in own:
            return (own[name],) * self.num_envs
        inner: Any = self.env
        return tuple(inner.call(name, *args, **kwargs))

    def get_attr(self, name: str) -> tuple[Any, ...]:
        """One value per env, as :meth:`call` reads it."""
        return self.call(name)

    def set_attr(self, name: str, values: Any) -> None:
        """Set an attribute of the wrapped vector env's envs (its rules)."""
        inner: Any = self.env
        inner.set_attr(name, values)

    @staticmethod
    def _ended(
        info: dict[str, Any],
        ended: npt.NDArray[np.bool_],
        residual_obs: ObsArray,
        added: dict[str, FloatArray],
    ) -> dict[str, Any]:
        """Return ``info`` with the ended envs' last residual observation and added keys."""
        final_obs = np.full(len(ended), None, dtype=object)
        for i in np.flatnonzero(ended):
            final_obs[i] = residual_obs[i].copy()
        final_info = dict(info["final_info"])
        for key, value in added.items():
            final_info[key] = np.where(ended, value, 0.0)
            final_info["_" + key] = ended.copy()
        return {**info, "final_obs": final_obs, "final_info": final_info}


def make_residual_vec(
    env_id: str,
    num_envs: int,
    *,
    base: BaseSpec = None,
    config: ResidualConfig | None = None,
    scale: float | None = None,
    residual_cost: float = 0.0,
    precision: float | None = None,
    **env_kwargs: Any,
) -> ResidualVectorEnv:
    """Make ``num_envs`` residual envs of ``env_id`` on its native vector env (SAME_STEP)."""
    vec = envs.make_vec(
        env_id, num_envs=num_envs, autoreset_mode=AutoresetMode.SAME_STEP, **env_kwargs
    )
    return ResidualVectorEnv(
        vec,
        base,
        config=config,
        scale=scale,
        residual_cost=residual_cost,
        precision=precision,
    )
