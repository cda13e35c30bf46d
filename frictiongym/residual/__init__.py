"""Residual control: a base controller's action plus a bounded, learned correction.

* :class:`ResidualEnv`: wraps a frictiongym env and a base controller into an env whose
  action is the residual (for Stable-Baselines3, under its own VecEnvs).
* :class:`ResidualConfig`, :func:`residual_observation`, :func:`bounded_residual`: the
  observation and the bound, shared with
  :class:`frictiongym.controllers.residual.ResidualController`, which runs a trained policy.
* ``frictiongym train`` (:mod:`frictiongym.residual.train`): SAC, TD3 or PPO with domain
  randomisation.

Nothing here imports torch or Stable-Baselines3 until a model is trained or loaded
(docs/residual.md).
"""

from frictiongym.controllers.residual_core import (
    OBSERVATION_NAMES,
    ResidualConfig,
    bounded_residual,
    make_base,
    residual_observation,
)
from frictiongym.residual.env import ResidualEnv

__all__ = [
    "OBSERVATION_NAMES",
    "ResidualConfig",
    "ResidualEnv",
    "bounded_residual",
    "make_base",
    "residual_observation",
]
