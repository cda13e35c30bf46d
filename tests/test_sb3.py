"""frictiongym.sb3: SB3's VecEnv over the native vector env, against DummyVecEnv."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor, VecNormalize

from frictiongym.residual import ResidualEnv
from frictiongym.residual.vector_env import make_residual_vec
from frictiongym.sb3 import FrictionVecEnv, make_sb3_vec
from tests._envs import ALTINO, IDS, RANDOM_KWARGS, SERVO, commands

N, MAX_STEPS = 3, 40


def dummy(env_id: str, residual: bool = False, **kwargs: Any) -> DummyVecEnv:
    def make() -> gym.Env:
        env = gym.make(env_id, max_episode_steps=MAX_STEPS, horizon=MAX_STEPS, **kwargs)
        return ResidualEnv(env) if residual else env

    return DummyVecEnv([make] * N)


def native(env_id: str, residual: bool = False, **kwargs: Any) -> FrictionVecEnv:
    if residual:
        return FrictionVecEnv(make_residual_vec(env_id, N, max_episode_steps=MAX_STEPS, **kwargs))
    return make_sb3_vec(env_id, N, max_episode_steps=MAX_STEPS, **kwargs)


def same(a: Any, b: Any, where: str) -> None:
    """Equal, with equal types: lists and dicts entry by entry, arrays with their dtypes."""
    assert type(a) is type(b), f"{where}: {type(a)} != {type(b)}"
    if isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            same(x, y, f"{where}[{k}]")
    elif isinstance(a, dict):
        assert sorted(a) == sorted(b), f"{where}: {sorted(a)} != {sorted(b)}"
        for key in a:
            same(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def run(vec: Any, actions: np.ndarray) -> list[Any]:
    vec.seed(7)
    trace: list[Any] = [vec.reset(), list(vec.reset_infos)]
    for a in actions:
        trace.append(vec.step(a))
        trace.append(list(vec.reset_infos))
    return trace


def actions_for(env_id: str, residual: bool) -> np.ndarray:
    if residual:
        return np.random.default_rng(3).uniform(-1.2, 1.2, (100, N, 1)).astype(np.float32)
    actions = commands(env_id, 100, shape=(N,), seed=4)
    if env_id == ALTINO:
        actions[15:, 1] = 1000.0  # into the wall: terminations as well as truncations
    return actions


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("residual", [False, True], ids=["env", "residual"])
@pytest.mark.parametrize("kwargs", [{}, RANDOM_KWARGS], ids=["default", "random"])
def test_same_seeds_give_what_dummy_vec_env_gives(env_id, residual, kwargs):
    actions = actions_for(env_id, residual)
    ours = run(native(env_id, residual, **kwargs), actions)
    theirs = run(dummy(env_id, residual, **kwargs), actions)
    same(ours, theirs, "run")
    infos = [info for out in ours[2::2] for info in out[3]]
    assert sum("terminal_observation" in info for info in infos) >= 2 * N
    if env_id == ALTINO and not residual:  # an ended episode that the time limit did not cut
        assert any("terminal_observation" in i and not i["TimeLimit.truncated"] for i in infos)


@pytest.mark.parametrize("env_id", IDS)
def test_vec_monitor_and_vec_normalize_on_top_agree(env_id):
    actions = actions_for(env_id, residual=False)
    runs = []
    for vec in (native(env_id), dummy(env_id)):
        wrapped = VecNormalize(VecMonitor(vec), gamma=0.9)
        trace = run(wrapped, actions)
        for out in trace[2::2]:
            for info in out[3]:
                info.get("episode", {}).pop("t", None)  # wall time
        runs.append(trace)
    same(runs[0], runs[1], "run")
    episodes = [i["episode"] for out in runs[0][2::2] for i in out[3] if "episode" in i]
    assert len(episodes) >= 2 * N


def test_ppo_learns_the_same_policy_on_both():
    """PPO with one seed gives the same weights on the native VecEnv and on DummyVecEnv."""
    weights = []
    for vec in (native(SERVO, residual=True), dummy(SERVO, residual=True)):
        model = PPO("MlpPolicy", vec, n_steps=32, batch_size=32, n_epochs=2, seed=5, device="cpu")
        model.learn(96)
        weights.append([p.detach().numpy().copy() for p in model.policy.parameters()])
    for a, b in zip(*weights, strict=True):
        np.testing.assert_array_equal(a, b)


def test_attributes_and_methods_as_dummy_vec_env_has_them():
    ours, theirs = native(SERVO, render_mode="rgb_array"), dummy(SERVO, render_mode="rgb_array")
    for vec in (ours, theirs):
        vec.seed(1)
        vec.reset()
    assert ours.get_attr("dt") == theirs.get_attr("dt")
    assert ours.get_attr("np_random_seed", [0, 2]) == theirs.get_attr("np_random_seed", [0, 2])
    assert ours.env_is_wrapped(gym.Wrapper) == [False] * N
    for a, b in zip(ours.env_method("render"), theirs.env_method("render"), strict=True):
        np.testing.assert_array_equal(a, b)
    assert len(ours.get_images()) == N
    ours.set_attr("level", 2)
    assert ours.get_attr("level") == [2] * N
    with pytest.raises(ValueError, match="set it for all"):
        ours.set_attr("level", 3, indices=[0])


def test_a_vector_env_that_autoresets_on_the_next_step_is_refused():
    vec = gym.make_vec(SERVO, num_envs=2, vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError, match="SAME_STEP"):
        FrictionVecEnv(vec)


def test_reset_options_reach_every_env():
    vec = native(SERVO)
    vec.set_options({"position": 0.3})
    obs = vec.reset()
    np.testing.assert_allclose(obs[:, 0], 0.3, atol=2e-3)
    vec.set_options([{"position": 0.1}, {}, {}])
    with pytest.raises(ValueError, match="one set of reset options"):
        vec.reset()


def test_an_episode_ended_by_contact_on_its_last_step_is_not_called_truncated():
    """terminated and truncated at once: SB3 must not bootstrap from the terminal state."""
    env = gym.make(ALTINO)
    env.reset(seed=0)
    steps = 1
    while not env.step(np.array([1000.0], np.float32))[2]:
        steps += 1
    push = np.full((steps, 2, 1), 1000.0, np.float32)
    ours = make_sb3_vec(ALTINO, 2, max_episode_steps=steps)
    theirs = DummyVecEnv([lambda: gym.make(ALTINO, max_episode_steps=steps, horizon=steps)] * 2)
    for vec in (ours, theirs):
        vec.seed(0)
        vec.reset()
        for a in push:
            *_, dones, infos = vec.step(a)
        assert dones.all()
        assert [i["TimeLimit.truncated"] for i in infos] == [False, False]


def test_get_attr_gives_the_spaces_the_policy_sees_through_wrappers():
    from gymnasium.vector import AutoresetMode
    from gymnasium.wrappers.vector import RescaleAction

    vec = gym.make_vec(
        SERVO,
        num_envs=2,
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    env = FrictionVecEnv(RescaleAction(vec, -1.0, 1.0))
    assert env.get_attr("action_space") == [env.action_space] * 2
    assert env.action_space.high[0] == 1.0
    assert env.get_attr("dt") == [0.002, 0.002]
