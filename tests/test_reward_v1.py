"""The v1 reward: bounded steps, and an episode ended by the limit never pays off."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from frictiongym import devices
from tests._envs import commands

V0 = ("frictiongym/RotaryServo-v0", "frictiongym/AltinoDistance-v0")
V1 = ("frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1")
#: A command that runs each device into its limit: the servo past two turns, the car into the wall.
RUNAWAY = {V1[0]: 10.0, V1[1]: 1000.0}


def worst_step(env_id: str) -> float:
    device = devices.get(env_id)
    return device.error_cap / device.error_scale + device.effort_weight


def rewards(env: gym.Env, seed: int, actions: np.ndarray) -> tuple[list[float], bool]:
    env.reset(seed=seed)
    out, ended = [], False
    for a in actions:
        _, reward, terminated, truncated, _ = env.step(a)
        out.append(reward)
        if terminated or truncated:
            ended = terminated
            break
    return out, ended


@pytest.mark.parametrize("env_id", V1)
@pytest.mark.parametrize("prefix", [0, 7, 60])
def test_running_into_the_limit_is_never_better_than_finishing_the_episode(env_id, prefix):
    """From the state after ``prefix`` steps, running away to the limit scores less than
    holding still for the rest of the episode (whatever that costs)."""
    steps = gym.spec(env_id).max_episode_steps
    start = commands(env_id, prefix + 1, seed=3)[:prefix]
    runaway = np.full((steps, 1), RUNAWAY[env_id], np.float32)
    still = np.zeros((steps, 1), np.float32)
    crash, crashed = rewards(gym.make(env_id), 0, np.concatenate([start, runaway]))
    held, held_crashed = rewards(gym.make(env_id), 0, np.concatenate([start, still]))
    assert crashed
    assert not held_crashed
    assert sum(crash[prefix:]) < sum(held[prefix:])
    assert sum(crash) < -worst_step(env_id) * steps  # below the worst whole episode


#: A start far from the reference, within the safety limit: (position, reference).
FAR = {V1[0]: (3.5 * np.pi, -3.0), V1[1]: (60.0, 5.0)}


@pytest.mark.parametrize("env_id", V1)
def test_a_step_costs_at_most_the_cap_however_far_from_the_reference(env_id):
    position, reference = FAR[env_id]
    env = gym.make(env_id)
    env.reset(seed=1, options={"position": position, "reference": reference})
    device = devices.get(env_id)
    assert abs(position - reference) > device.error_cap  # beyond the cap: it applies
    for _ in range(20):
        _, reward, terminated, _, _ = env.step(np.zeros(1, np.float32))
        assert not terminated
        assert reward == -device.error_cap / device.error_scale  # held at rest: no effort
    v0 = gym.make(env_id.replace("-v1", "-v0"))
    v0.reset(seed=1, options={"position": position, "reference": reference})
    assert v0.step(np.zeros(1, np.float32))[1] < -worst_step(env_id)  # v0 has no cap


@pytest.mark.parametrize(("old", "new"), list(zip(V0, V1, strict=True)))
def test_v1_differs_from_v0_only_where_the_cap_applies(old, new):
    actions = commands(new, 300, seed=8)
    cap = devices.get(new).error_cap
    runs = []
    for env_id in (old, new):
        env = gym.make(env_id, sensor_noise=True)
        env.reset(seed=4)
        runs.append([env.step(a)[1::3] for a in actions])  # (reward, info)
    within = 0
    for (r0, info), (r1, _) in zip(*runs, strict=True):
        if abs(info["reference"] - info["position"]) <= cap:
            assert r0 == r1  # the same float
            within += 1
        else:
            assert r1 > r0
    assert within > 30


@pytest.mark.parametrize("env_id", V1)
@pytest.mark.parametrize("steps", [100, 1200])
def test_the_vector_env_charges_a_worst_episode_of_its_own_length(env_id, steps):
    """Its horizon is its max_episode_steps; a single env given that horizon pays the same."""
    vec = gym.make_vec(
        env_id, num_envs=2, vectorization_mode="vector_entry_point", max_episode_steps=steps
    )
    assert vec.unwrapped.horizon == steps
    single = gym.make(env_id, max_episode_steps=steps, horizon=steps)
    push = np.full((steps, 2, 1), RUNAWAY[env_id], np.float32)
    vec.reset(seed=5)
    total = np.zeros(2)
    for a in push:
        _, reward, terminated, _, _ = vec.step(a)
        total += reward
        if terminated.all():
            break
    crash, crashed = rewards(single, 5, push[:, 0])
    assert crashed
    assert total[0] == pytest.approx(sum(crash), rel=1e-12)
    assert sum(crash) < -worst_step(env_id) * steps


def test_terminal_cost_and_horizon_are_checked():
    with pytest.raises(TypeError, match="terminal_cost"):
        gym.make(V1[0], terminal_cost="yes")
    with pytest.raises(ValueError, match="horizon"):
        gym.make(V1[0], horizon=0)
