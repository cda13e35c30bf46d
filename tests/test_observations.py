"""Observations are clean floats: no float32 subnormals and no -0.0, in every env and backend.

After the disk stops, the filtered velocity estimate used to decay geometrically through the
float32 subnormals to -0.0 (166 subnormal and 776 signed-zero velocities in 2 500 steps of
N(0, 0.15 V) commands). Estimates below 2**-24 of their resolution are now exactly 0.0.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from frictiongym.plants.sensors import (
    QUBE_ENCODER_STEP,
    FilteredDerivative,
    ir_quantum,
    velocity_floor,
)
from tests._envs import ALTINO, IDS, SERVO

TINY = np.finfo(np.float32).tiny
#: Commands of N(0, std): around the break-away band, so the body sticks and slips.
STD = {SERVO: 0.15, ALTINO: 150.0}


def unclean(obs: np.ndarray) -> tuple[int, int]:
    """Count of float32 subnormals and of -0.0 in ``obs``."""
    obs = np.asarray(obs, dtype=np.float32)
    subnormal = (obs != 0.0) & (np.abs(obs) < TINY)
    negative_zero = (obs == 0.0) & np.signbit(obs)
    return int(subnormal.sum()), int(negative_zero.sum())


def noisy_commands(env_id: str, steps: int, num: int = 1, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(0.0, STD[env_id], (steps, num, 1)).astype(np.float32)


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("kwargs", [{}, {"quantize": False}, {"friction": "lugre"}])
def test_single_env_observations_are_clean(env_id: str, kwargs: dict) -> None:
    env = gym.make(env_id, **kwargs)
    obs, _ = env.reset(seed=0)
    seen = [obs]
    for u in noisy_commands(env_id, 2500)[:, 0]:
        obs, _, terminated, truncated, _ = env.step(u)
        seen.append(obs)
        if terminated or truncated:
            obs, _ = env.reset()
            seen.append(obs)
    assert unclean(np.array(seen)) == (0, 0)


@pytest.mark.parametrize(
    "options",
    [{"velocity": -1e-30}, {"position": -1e-40}, {"position": -1e-300}, {"reference": -1e-40}],
)
def test_an_ideal_sensor_near_zero_gives_clean_observations(options: dict) -> None:
    """With ``quantize=False`` the angle is the true one, as near 0 as a start makes it."""
    env = gym.make(SERVO, quantize=False)
    seen = [env.reset(seed=0, options=options)[0]]
    seen += [env.step(np.zeros(1, np.float32))[0] for _ in range(3)]
    assert unclean(np.array(seen)) == (0, 0)


def test_a_stuck_servo_reports_exactly_zero_velocity() -> None:
    # One push, then nothing: the disk stops, and its estimate must reach +0.0, not decay on.
    env = gym.make(SERVO)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.array([1.0], np.float32))
    velocities = [env.step(np.array([0.0], np.float32))[0][1] for _ in range(2000)]
    assert unclean(np.array(velocities)) == (0, 0)
    assert velocities[-1] == 0.0
    assert not np.signbit(velocities[-1])
    # ... through the filter's real decay, down to the floor (far below one count's worth).
    floor = velocity_floor(QUBE_ENCODER_STEP, np.exp(-50.0 * 0.002), 0.002)
    nonzero = np.abs(np.array(velocities, dtype=np.float64))[np.array(velocities) != 0.0]
    assert nonzero.min() >= np.float32(floor)
    assert nonzero.min() < 2.0 * floor


@pytest.mark.parametrize("env_id", IDS)
def test_vector_env_observations_are_clean_and_match_the_single_env(env_id: str) -> None:
    vec = gym.make_vec(env_id, num_envs=4, vectorization_mode="vector_entry_point")
    actions = noisy_commands(env_id, 1500, num=4)
    obs, _ = vec.reset(seed=3)
    seen = [obs]
    for a in actions:
        obs, *_ = vec.step(a)
        seen.append(obs)
    seen_array = np.array(seen)
    assert unclean(seen_array) == (0, 0)
    single = gym.make(env_id, max_episode_steps=None).unwrapped
    obs, _ = single.reset(seed=4)
    assert np.array_equal(obs, seen_array[0, 1])
    for t, a in enumerate(actions):
        obs, _, terminated, _, _ = single.step(a[1])
        assert np.array_equal(obs, seen_array[t + 1, 1])
        if terminated:
            break


def test_device_backend_observations_are_clean() -> None:
    env = gym.make(SERVO, backend="emulator://rotary?lockstep=1", log=False)
    try:
        obs, _ = env.reset(seed=0)
        seen = [obs]
        for _ in range(5):
            seen.append(env.step(np.array([1.0], np.float32))[0])
        for _ in range(1500):
            seen.append(env.step(np.array([0.0], np.float32))[0])
    finally:
        env.close()
    assert unclean(np.array(seen)) == (0, 0)
    assert seen[-1][1] == 0.0


def test_the_floor_sits_far_below_one_count() -> None:
    pole = np.exp(-50.0 * 0.002)
    floor = velocity_floor(QUBE_ENCODER_STEP, pole, 0.002)
    one_count = (1.0 - pole) * QUBE_ENCODER_STEP / 0.002
    assert floor == one_count * 2.0**-24
    assert TINY < floor < 1e-7 * one_count
    assert velocity_floor(ir_quantum(), 0.0, 0.05) > TINY


def test_filtered_derivative_applies_the_same_floor() -> None:
    tach = FilteredDerivative(50.0, 0.002, resolution=QUBE_ENCODER_STEP)
    tach.update(0.0)
    tach.update(QUBE_ENCODER_STEP)
    values = [float(tach.update(QUBE_ENCODER_STEP)) for _ in range(1000)]
    assert values[-1] == 0.0
    assert all(v == 0.0 or v >= tach.floor for v in values)
    plain = FilteredDerivative(50.0, 0.002)  # no resolution: no floor
    plain.update(0.0)
    plain.update(QUBE_ENCODER_STEP)
    assert float(plain.update(QUBE_ENCODER_STEP)) > 0.0
