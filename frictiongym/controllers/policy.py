"""Evaluate any controller like a Stable-Baselines3 policy."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym.controllers.base import Controller


class ControllerPolicy:
    """A :class:`Controller` with SB3's ``predict`` signature.

    ``stable_baselines3.common.evaluation.evaluate_policy(ControllerPolicy(pid), env)`` then
    scores a PID exactly as it scores a trained model; ``episode_start`` resets the
    controller of the envs that start a new episode.
    """

    def __init__(self, controller: Controller) -> None:
        self.controller = controller

    def predict(
        self,
        observation: npt.ArrayLike,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: npt.ArrayLike | None = None,
        deterministic: bool = True,
    ) -> tuple[npt.NDArray[np.float32], tuple[np.ndarray, ...] | None]:
        """Return the action for ``observation`` (deterministic) and ``state`` unchanged."""
        obs = np.asarray(observation, dtype=np.float64)
        if episode_start is not None:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            if starts.all():
                self.controller.reset()
            elif starts.any():
                self.controller.reset(starts)
        return self.controller(obs).astype(np.float32), state

    def __call__(self, observation: npt.ArrayLike) -> Any:
        """Return the controller's action as a float32 array."""
        return self.predict(observation)[0]
