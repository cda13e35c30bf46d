"""What Gymnasium's own checks expect of our envs, and clear errors for what users get wrong.

Gymnasium 1.4's test suite, run against both ids, found three defects (each fixed here and
kept fixed by a test): unseeded resets of the native vector env started fresh generators,
its ``info`` masks were one shared read-only array, and the single env accepted strings,
booleans and wrong shapes as actions.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import SyncVectorEnv

from tests._envs import ALTINO, IDS, RANDOM_KWARGS, SERVO, commands


def make_vec(env_id: str, num_envs: int, **kwargs):
    return gym.make_vec(
        env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs
    )


def make_sync(env_id: str, num_envs: int, **kwargs) -> SyncVectorEnv:
    return SyncVectorEnv([lambda: gym.make(env_id, **kwargs) for _ in range(num_envs)])


@pytest.mark.parametrize("env_id", IDS)
def test_unseeded_reset_continues_each_envs_seeded_stream(env_id: str) -> None:
    """A run seeded once is reproducible through later unseeded resets, as with Sync."""
    runs = []
    for make in (make_vec, make_sync):
        env = make(env_id, 3, **RANDOM_KWARGS)
        trace = [env.reset(seed=0)[0]]
        for a in commands(env_id, 5, shape=(3,)):
            trace.append(env.step(a)[0])
        trace.append(env.reset()[0])
        trace.append(env.reset(seed=[None, 7, None])[0])
        runs.append(np.array(trace))
    np.testing.assert_array_equal(runs[0], runs[1])
    # ... and the unseeded reset did draw new values: the streams moved on.
    assert not np.array_equal(runs[0][0], runs[0][-2])


@pytest.mark.parametrize("env_id", IDS)
def test_info_masks_are_new_writable_arrays_each_call(env_id: str) -> None:
    env = make_vec(env_id, 2)
    _, first = env.reset(seed=0)
    info = env.step(np.zeros((2, 1), np.float32))[4]
    info["_position"][0] = False  # must not raise (gymnasium: each call returns new objects)
    assert info["_time"][0]  # the masks are not one shared array
    assert first["_position"] is not info["_position"]
    assert first["_position"].all()


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
@pytest.mark.parametrize("parallel", [False, True])
def test_info_masks_are_set_for_every_env_of_a_large_batch(mode: str, parallel: bool) -> None:
    """Every env of a batch the threads step reports every key, through autoresets too."""
    env = make_vec(ALTINO, 600, parallel=parallel, autoreset_mode=mode, max_episode_steps=25)
    keys = ("position", "velocity", "command", "reference", "time", "stuck")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    ended = 0
    for step in range(60):
        if step == 10:  # half the envs restart: their episodes end 10 steps after the others'
            env.reset(options={"reset_mask": np.arange(600) < 300})
        _, _, terminated, truncated, info = env.step(rng.uniform(-800, 800, (600, 1)))
        ended += int(np.count_nonzero(terminated | truncated))
        for key in keys:
            assert info["_" + key].shape == (600,)
            assert info["_" + key].all()
        if "final_info" in info:  # same-step: the ended envs' last info, only theirs
            for key in keys:
                np.testing.assert_array_equal(info["final_info"]["_" + key], info["_final_obs"])
    assert ended > 0  # autoresets happened on the way


@pytest.mark.parametrize(
    "action",
    ["1.5", True, [True], 0.5, np.float64(0.5), np.zeros((1, 1)), [1.0, 2.0], None, ["a"]],
    ids=repr,
)
def test_single_env_refuses_what_is_not_one_number(action: object) -> None:
    env = gym.make(SERVO).unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match="one number"):
        env.step(action)


@pytest.mark.parametrize("action", [[0.5], (0.5,), np.array([0.5]), np.array([1], np.int64)])
def test_single_env_takes_one_number_in_any_array_form(action: object) -> None:
    env = gym.make(SERVO).unwrapped
    env.reset(seed=0)
    assert env.step(action)[4]["command"] == float(np.asarray(action)[0])


def test_vector_env_refuses_non_numbers() -> None:
    env = make_vec(SERVO, 2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="numbers in command units"):
        env.step(np.array([[True], [False]]))


@pytest.mark.parametrize("env_id", IDS)
def test_unwrapped_env_refuses_a_step_or_a_frame_before_reset(env_id: str) -> None:
    with pytest.raises(gym.error.ResetNeeded):
        gym.make(env_id).unwrapped.step(np.array([0.0], np.float32))
    with pytest.raises(gym.error.ResetNeeded):
        make_vec(env_id, 2).step(np.zeros((2, 1), np.float32))
    with pytest.raises(gym.error.ResetNeeded):  # it drew a made-up state
        gym.make(env_id, render_mode="rgb_array").unwrapped.render()
    with pytest.raises(gym.error.ResetNeeded):
        make_vec(env_id, 2, render_mode="rgb_array").render()


@pytest.mark.parametrize("make", [gym.make, lambda i, **kw: make_vec(i, 2, **kw)])
def test_unknown_arguments_name_the_env_and_the_valid_ones(make) -> None:
    with pytest.raises(TypeError) as excinfo:
        make(ALTINO, noise=1)
    message = str(excinfo.value)
    assert "AltinoDistance" in message
    assert "'noise' (did you mean 'sensor_noise'?)" in message
    assert "reference" in message


def test_device_settings_with_the_simulator_say_so() -> None:
    with pytest.raises(ValueError, match="settings of device runs"):
        gym.make(SERVO, log=False)


@pytest.mark.parametrize("env_id", IDS)
def test_a_diverged_plant_terminates_instead_of_running_on(env_id: str) -> None:
    from frictiongym.plants import _kernel as plant_kernel

    env = gym.make(env_id).unwrapped
    env.reset(seed=0)
    env.sim.state[plant_kernel.S_X, 0] = np.nan  # what a diverging integration would leave
    assert env.step(np.array([0.0], np.float32))[2]


def test_masked_arrays_are_refused_not_read_through_the_mask() -> None:
    """``np.ma.masked_array([1.0], mask=[True])`` sent its hidden 1 V."""
    env = gym.make(SERVO)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="masked array"):
        env.step(np.ma.masked_array([1.0], mask=[True]))
    vec = make_vec(SERVO, 2)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match="masked array"):
        vec.step(np.ma.masked_array([[1.0], [1.0]], mask=[[True], [False]]))
