"""Shared helpers of the env tests."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

import frictiongym  # noqa: F401  (registers the ids)

SERVO = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"
IDS = (SERVO, ALTINO)
#: Command scale around each device's break-away band (0.2 V; 200 units).
SCALE = {SERVO: 0.25, ALTINO: 250.0}
#: Every source of randomness at once: noise, a random reference, randomised parameters.
RANDOM_KWARGS: dict[str, Any] = {
    "sensor_noise": True,
    "reference": "random_steps",
    "randomize": {"friction": (0.5, 1.5), "inertia": (0.8, 1.2), "sensor_gain": (0.9, 1.1)},
}


def commands(env_id: str, steps: int, shape: tuple[int, ...] = (), seed: int = 0) -> np.ndarray:
    """AR(1) commands around the break-away band, float32, shape (steps, *shape, 1)."""
    rng = np.random.default_rng(seed)
    u = np.zeros((steps, *shape, 1))
    for t in range(1, steps):
        u[t] = 0.9 * u[t - 1] + 0.45 * SCALE[env_id] * rng.normal(size=(*shape, 1))
    return u.astype(np.float32)


def rollout(env: gym.Env, actions: np.ndarray) -> tuple[list, list, list]:
    """Observations, rewards and infos of a run that resets (unseeded) when an episode ends."""
    observations, rewards, infos = [], [], []
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        observations.append(obs)
        rewards.append(reward)
        infos.append(info)
        if terminated or truncated:
            obs, info = env.reset()
            observations.append(obs)
            rewards.append(None)
            infos.append(info)
    return observations, rewards, infos
