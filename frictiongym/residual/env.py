"""Residual-learning env: the applied action is a base controller's plus a bounded residual."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from frictiongym._validation import real_number
from frictiongym.controllers.base import Controller, FloatArray
from frictiongym.controllers.residual_core import (
    OBSERVATION_BOUND,
    OBSERVATION_SIZE,
    ResidualConfig,
    bounded_residual,
    make_base,
    residual_observation,
)
from frictiongym.devices import device_of

ObsArray = npt.NDArray[np.float32]
#: A base controller, or a factory building one for the wrapped env.
BaseSpec = Controller | Callable[[Any], Controller] | None


class ResidualEnv(gym.Wrapper[ObsArray, ObsArray, Any, Any]):
    """A frictiongym env whose action is a bounded correction to a base controller's action.

    At every step the base controller computes its action ``u_b`` from the env's observation,
    and the applied action is ``clip(u_b + scale * clip(a, -1, 1), -limit, limit)`` for the
    policy's action ``a``: the residual never exceeds ``scale`` in magnitude, whatever the
    policy outputs (NaN counts as 0), and the total never exceeds the env's limit. A policy
    that outputs 0 reproduces the base controller exactly.

    ## Action Space

    ``Box(-1, 1, (1,), float32)``: the residual as a fraction of ``scale``.

    ## Observation Space

    ``Box(-10, 10, (6,), float32)``: :func:`~frictiongym.residual.residual_observation` of the
    env's observation and of ``u_b`` (the error on a coarse and a fine scale, the rate,
    the reference, ``u_b / limit``, and whether the output is at rest), in the sign convention
    of the command.

    ## Rewards

    The env's reward by default. With ``precision`` set, its tracking term ``-|e| / e0`` is
    replaced by ``-log(1 + |e| / precision)`` (``e`` the true tracking error of the step,
    ``info``'s ``reference - position``): the few encoder counts or IR steps friction leaves
    then weigh about as much per step as a large transient error, where the env's linear
    term makes them a thousandth of it. The env's effort term and safety penalty are kept.
    ``residual_cost * (residual / scale)**2`` is subtracted from either (0 by default).

    ## Info

    The env's ``info`` plus ``base_action`` (``u_b``) and ``residual`` (the bounded residual
    before the saturation of the total; ``info["command"]`` is the applied action).

    Parameters
    ----------
    env : gymnasium.Env
        A frictiongym env made with ``gym.make`` (any arguments: ``randomize``, ``reference``,
        ``max_episode_steps``, a device ``backend``...).
    base : Controller or callable, optional
        The base controller, built for ``env``, or a factory ``env -> Controller``. By default
        the paper's friction-compensated PID of the device
        (:func:`~frictiongym.controllers.residual_core.make_base`). It is reset with the env.
    config : ResidualConfig, optional
        Observation scales and the residual bound; the device's defaults by default.
    scale : float, optional
        The residual bound in action units (V, motor units), overriding ``config``'s; by
        default 10 % of the limit for the servo (1 V) and 20 % for the Altino (200).
    residual_cost : float, default 0.0
        Weight of the optional penalty on the residual's size.
    precision : float, optional
        Error scale of the logarithmic tracking reward (rad, cm); the env's linear reward if
        None.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        base: BaseSpec = None,
        *,
        config: ResidualConfig | None = None,
        scale: float | None = None,
        residual_cost: float = 0.0,
        precision: float | None = None,
    ) -> None:
        super().__init__(env)
        self.base, self.config, self.objective = residual_setup(
            env, base, config, scale, residual_cost, precision
        )
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        bound = OBSERVATION_BOUND
        self.observation_space = spaces.Box(-bound, bound, (OBSERVATION_SIZE,), np.float32)
        self._base_action: FloatArray = np.zeros(1)

    @property
    def scale(self) -> float:
        """The residual bound, in action units."""
        return self.config.scale

    def _observe(self, obs: Any) -> ObsArray:
        self._base_action = self.base(obs)
        return residual_observation(obs, self.base.spec, self._base_action, self.config)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsArray, dict[str, Any]]:
        """Reset the env and the base controller; return the residual observation."""
        obs, info = self.env.reset(seed=seed, options=options)
        self.base.reset()
        return self._observe(obs), info

    def step(self, action: Any) -> tuple[ObsArray, SupportsFloat, bool, bool, dict[str, Any]]:
        """Apply the base action plus the bounded residual ``action``; see the class docstring."""
        residual = bounded_residual(np.asarray(action).reshape(-1)[:1], self.config.scale)
        base = self._base_action.reshape(1)
        total = np.clip(base + residual, -self.config.limit, self.config.limit)
        obs, reward, terminated, truncated, info = self.env.step(total.astype(np.float32))
        info = {**info, "base_action": float(base[0]), "residual": float(residual[0])}
        shaped = self.objective.reward(
            float(reward), info["reference"], info["position"], residual[0], terminated
        )
        return self._observe(obs), float(shaped), terminated, truncated, info


@dataclass(frozen=True)
class Objective:
    """What the residual env's reward adds to the env's (the class docstring's "Rewards").

    On a v1 env (``tracking_cap`` and ``horizon`` set), the terms it adds are capped and a
    terminated episode pays them for a whole worst episode too, as the env does its own: an
    episode ended at a limit still scores less than any episode that avoids it.
    """

    error_scale: float  #: the env's e0
    scale: float  #: the residual bound
    residual_cost: float = 0.0
    precision: float | None = None
    tracking_cap: float = math.inf  #: the env's cap of its tracking term (its v1 reward)
    horizon: int = 0  #: the episode length the env's terminal cost covers (0: v0's reward)

    def reward(
        self,
        reward: npt.ArrayLike,
        reference: npt.ArrayLike,
        position: npt.ArrayLike,
        residual: npt.ArrayLike,
        terminated: npt.ArrayLike = False,
    ) -> Any:
        """Return the training reward of one env (numbers) or of a batch (arrays)."""
        shaped: Any = np.asarray(reward, dtype=np.float64)
        worst = 0.0  # the most a step's added terms can cost beyond the env's own
        if self.precision is not None:
            error = np.abs(np.asarray(reference, np.float64) - np.asarray(position, np.float64))
            cap = self.tracking_cap
            tracking = np.minimum(error / self.error_scale, cap)  # the env's term
            charged = np.minimum(error, cap * self.error_scale)  # the error it charges
            shaped = shaped + tracking - np.log1p(charged / self.precision)
            if math.isfinite(cap):
                worst = max(math.log1p(cap * self.error_scale / self.precision) - cap, 0.0)
        if self.residual_cost:
            shaped = shaped - self.residual_cost * (np.asarray(residual) / self.scale) ** 2
            worst += self.residual_cost
        if self.horizon and worst:
            shaped = shaped - np.where(terminated, worst * self.horizon, 0.0)
        return shaped


def residual_setup(
    env: Any,
    base: BaseSpec,
    config: ResidualConfig | None,
    scale: float | None,
    residual_cost: float,
    precision: float | None,
) -> tuple[Controller, ResidualConfig, Objective]:
    """Check and resolve a residual env's arguments (single or vector; the class docstring)."""
    if config is None:
        config = ResidualConfig.for_env(env, scale)
    elif scale is not None:
        config = ResidualConfig.from_dict({**config.to_dict(), "scale": float(scale)})
    if base is None:
        controller = make_base(env)
    elif isinstance(base, Controller):
        controller = base
    elif callable(base):
        controller = base(env)
    else:
        raise TypeError(f"base must be a Controller or a factory env -> Controller, got {base!r}")
    if not isinstance(controller, Controller):
        raise TypeError(f"the base factory returned {controller!r}, not a Controller")
    if controller.spec.limit != config.limit:
        raise ValueError(
            f"the base controller's limit {controller.spec.limit} differs from the "
            f"config's {config.limit}: build both for this env"
        )
    if precision is not None:
        precision = real_number("precision", precision, "> 0", hint=" (an error scale)")
    objective = Objective(
        error_scale=float(device_of(env).error_scale),
        scale=config.scale,
        residual_cost=real_number("residual_cost", residual_cost, ">= 0"),
        precision=precision,
        tracking_cap=env.unwrapped.tracking_cap,
        horizon=env.unwrapped.horizon,
    )
    return controller, config, objective
