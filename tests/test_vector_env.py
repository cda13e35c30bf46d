"""The native vector envs: make_vec, autoreset, and agreement with the single env."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from tests._envs import ALTINO, IDS, RANDOM_KWARGS, SERVO, commands


def make_vec(env_id: str, num_envs: int, **kwargs):
    return gym.make_vec(
        env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs
    )


@pytest.mark.parametrize("env_id", IDS)
def test_make_vec_builds_batched_spaces_and_declares_autoreset(env_id):
    env = make_vec(env_id, 3)
    assert env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert env.unwrapped.max_episode_steps == gym.spec(env_id).max_episode_steps
    obs, info = env.reset(seed=0)
    assert obs.shape == (3, *env.single_observation_space.shape)
    assert obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample() * 0)
    assert reward.shape == terminated.shape == truncated.shape == (3,)
    for key in ("position", "velocity", "command", "reference", "time", "stuck"):
        assert info[key].shape == (3,)
        assert info["_" + key].all()


def single_run(env_id: str, seed: int, actions: np.ndarray, max_steps: int, kwargs: dict):
    """The single env driven as the vector env drives env i under NEXT_STEP autoreset."""
    env = gym.make(env_id, max_episode_steps=max_steps, horizon=max_steps, **kwargs)
    obs, _ = env.reset(seed=seed)
    observations, rewards, dones = [obs], [], []
    done = False
    for a in actions:
        if done:  # the vector env spends this action on the reset
            obs, _ = env.reset()
            reward, done = 0.0, False
        else:
            obs, reward, terminated, truncated, _ = env.step(a)
            done = terminated or truncated
        observations.append(obs)
        rewards.append(reward)
        dones.append(done)
    return np.array(observations), np.array(rewards), np.array(dones)


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("kwargs", [{}, RANDOM_KWARGS], ids=["default", "random"])
def test_vector_env_matches_the_single_env_across_autoresets(env_id, kwargs):
    num_envs, steps, max_steps = 4, 130, 50
    actions = commands(env_id, steps, shape=(num_envs,), seed=5)
    if env_id == ALTINO:
        actions[20:, 1] = 1000.0  # env 1 drives into the wall: termination, then autoreset
    env = make_vec(env_id, num_envs, max_episode_steps=max_steps, **kwargs)
    obs, _ = env.reset(seed=11)
    observations, rewards, dones = [obs], [], []
    for a in actions:
        obs, reward, terminated, truncated, _ = env.step(a)
        observations.append(obs)
        rewards.append(reward)
        dones.append(terminated | truncated)
    observations, rewards, dones = np.array(observations), np.array(rewards), np.array(dones)
    assert dones.sum() >= num_envs * 2  # every env went through at least two resets
    for i in range(num_envs):
        single = single_run(env_id, 11 + i, actions[:, i], max_steps, kwargs)
        np.testing.assert_array_equal(single[0], observations[:, i])
        np.testing.assert_array_equal(single[1], rewards[:, i])
        np.testing.assert_array_equal(single[2], dones[:, i])


@pytest.mark.parametrize("env_id", IDS)
def test_parallel_and_serial_kernels_agree_bit_for_bit(env_id):
    runs = []
    for parallel in (False, True):
        env = make_vec(env_id, 16, parallel=parallel, max_episode_steps=40, **RANDOM_KWARGS)
        obs, _ = env.reset(seed=2)
        trace = [obs]
        for a in commands(env_id, 100, shape=(16,)):
            trace.append(env.step(a)[0])
        runs.append(np.array(trace))
    np.testing.assert_array_equal(*runs)


def test_seed_lists_and_their_length():
    env = make_vec(SERVO, 2, **RANDOM_KWARGS)
    a = env.reset(seed=[5, 9])[0]
    b = env.reset(seed=5)[0]
    single = gym.make(SERVO, **RANDOM_KWARGS)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], single.reset(seed=9)[0])
    with pytest.raises(ValueError, match="2 entries"):
        env.reset(seed=[1, 2, 3])


def test_reset_options_apply_to_every_env_and_take_arrays():
    env = make_vec(ALTINO, 3)
    _, info = env.reset(seed=0, options={"position": [10.0, 12.0, 14.0], "reference": 7.0})
    np.testing.assert_array_equal(info["position"], [10.0, 12.0, 14.0])
    np.testing.assert_array_equal(info["reference"], [7.0, 7.0, 7.0])


@pytest.mark.parametrize(
    "bad",
    [[[0.0], [math.nan]], [[0.0]], [[1.0], [2.0], [3.0]], [[[0.0]], [[1.0]]], [[0.0, 1.0]]],
)
def test_bad_actions_raise(bad):
    env = make_vec(SERVO, 2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"finite|one command per env"):
        env.step(np.array(bad))


def test_one_command_per_env_in_either_shape():
    """(N, 1), the batched action space's shape, and (N,) give the same step."""
    stepped = []
    for actions in (np.array([[0.5], [-0.5]]), np.array([0.5, -0.5])):
        env = make_vec(SERVO, 2)
        env.reset(seed=0)
        stepped.append(env.step(actions)[0])
    np.testing.assert_array_equal(stepped[0], stepped[1])


def test_vector_render_gives_one_frame_per_env():
    env = make_vec(SERVO, 2, render_mode="rgb_array")
    env.reset(seed=0)
    frames = env.render()
    assert len(frames) == 2
    assert frames[0].shape == (400, 400, 3)


def test_pickled_vector_envs_continue_identically():
    env = make_vec(SERVO, 3, max_episode_steps=20, **RANDOM_KWARGS)
    env.reset(seed=4)
    actions = commands(SERVO, 60, shape=(3,))
    for a in actions[:25]:
        env.step(a)
    clone = pickle.loads(pickle.dumps(env))
    for a in actions[25:]:
        np.testing.assert_array_equal(env.step(a)[0], clone.step(a)[0])
