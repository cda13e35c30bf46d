"""The native vector env in each autoreset mode against SyncVectorEnv over the single env."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from frictiongym.envs import _kernel as env_kernel
from tests._envs import ALTINO, IDS, RANDOM_KWARGS, SERVO, commands

MODES = list(AutoresetMode)
NUM_ENVS, MAX_STEPS = 3, 30


def native(env_id: str, mode: AutoresetMode, **kwargs: Any) -> gym.vector.VectorEnv:
    return gym.make_vec(
        env_id,
        num_envs=NUM_ENVS,
        vectorization_mode="vector_entry_point",
        max_episode_steps=MAX_STEPS,
        autoreset_mode=mode,
        **kwargs,
    )


def sync(env_id: str, mode: AutoresetMode, **kwargs: Any) -> SyncVectorEnv:
    return SyncVectorEnv(
        # The single env cannot see its TimeLimit: it gets the vector env's horizon by hand.
        [lambda: gym.make(env_id, max_episode_steps=MAX_STEPS, horizon=MAX_STEPS, **kwargs)]
        * NUM_ENVS,
        autoreset_mode=mode,
    )


def assert_same(a: Any, b: Any, where: str = "") -> None:
    """Equal values, dict keys, array shapes and dtypes; object arrays entry by entry."""
    if isinstance(a, tuple):
        assert isinstance(b, tuple), where
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{where}.{k}")
    elif isinstance(a, dict):
        assert isinstance(b, dict), where
        assert sorted(a) == sorted(b), f"{where}: keys {sorted(a)} != {sorted(b)}"
        for key in a:
            assert_same(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert b.dtype == object, where
        assert a.shape == b.shape, where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert (x is None) == (y is None), f"{where}[{i}]"
            if x is not None:
                assert_same(x, y, f"{where}[{i}]")
    else:
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype, f"{where}: dtype {a.dtype} != {b.dtype}"
        np.testing.assert_array_equal(a, b, err_msg=where)


def run(env: gym.vector.VectorEnv, env_id: str, mode: AutoresetMode) -> list[Any]:
    """Everything the env returns over a run with several episode ends in each env."""
    actions = commands(env_id, 100, shape=(NUM_ENVS,), seed=5)
    if env_id == ALTINO:
        actions[10:, 1] = 1000.0  # env 1 drives into the wall again and again: terminations
    trace: list[Any] = [env.reset(seed=11)]
    for a in actions:
        out = env.step(a)
        trace.append(out)
        done = out[2] | out[3]
        if mode is AutoresetMode.DISABLED and done.any():
            trace.append(env.reset(options={"reset_mask": done}))
    return trace


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("mode", MODES, ids=[m.name for m in MODES])
@pytest.mark.parametrize("kwargs", [{}, RANDOM_KWARGS], ids=["default", "random"])
def test_each_mode_returns_what_sync_vector_env_returns(env_id, mode, kwargs):
    ours, theirs = (
        run(native(env_id, mode, **kwargs), env_id, mode),
        run(sync(env_id, mode, **kwargs), env_id, mode),
    )
    assert len(ours) == len(theirs)
    for k, (a, b) in enumerate(zip(ours, theirs, strict=True)):
        assert_same(a, b, f"call {k}")
    ends = sum(int((out[2] | out[3]).sum()) for out in ours if len(out) == 5)
    assert ends >= 2 * NUM_ENVS  # each env ended at least twice


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("mode", MODES, ids=[m.name for m in MODES])
def test_episodes_after_a_reset_with_another_reference_go_back_to_the_default_one(env_id, mode):
    # an autoreset leaves the task rows alone while every env holds the default ones: after a
    # reset of all, or of some, with another reference it must write them again
    custom = 0.3 if env_id == SERVO else 25.0
    envs = native(env_id, mode), sync(env_id, mode)
    traces = []
    for env in envs:
        actions = commands(env_id, 90, shape=(NUM_ENVS,), seed=2)
        if env_id == ALTINO:
            actions[10:, 1] = 1000.0  # terminations as well as truncations
        trace: list[Any] = [env.reset(seed=3, options={"reference": custom})]
        for t, a in enumerate(actions):
            if t == 45:
                options = {"reset_mask": np.array([False, True, False]), "reference": custom}
                trace.append(env.reset(options=options))
            out = env.step(a)
            trace.append(out)
            done = out[2] | out[3]
            if mode is AutoresetMode.DISABLED and done.any():
                trace.append(env.reset(options={"reset_mask": done}))
        traces.append(trace)
    for k, (a, b) in enumerate(zip(*traces, strict=True)):
        assert_same(a, b, f"call {k}")
    # every env has been reset without options since; the single env runs the same reset
    # code, so the rows are checked against the default row itself
    sim = envs[0].unwrapped.sim
    default = np.repeat(sim.reference.sample()[:, None], NUM_ENVS, axis=1)
    np.testing.assert_array_equal(sim.rows[env_kernel.T_REF :], default)


@pytest.mark.parametrize("env_id", IDS)
def test_a_single_env_reset_without_options_after_one_with_them_is_a_default_reset(env_id):
    env = gym.make(env_id)
    default = env.reset(seed=1)[1]
    custom = {"reference": 0.3 if env_id == SERVO else 25.0, "position": default["position"] / 2}
    changed = env.reset(options=custom)[1]
    assert changed["reference"] == custom["reference"] != default["reference"]
    again = env.reset(seed=1)[1]
    assert again == default


@pytest.mark.parametrize("mode", MODES, ids=[m.name for m in MODES])
def test_the_mode_is_declared_in_metadata(mode):
    env = native(SERVO, mode)
    assert env.metadata["autoreset_mode"] is mode
    assert native(SERVO, mode.value).autoreset_mode is mode  # its string value works too
    assert type(env.unwrapped).metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP


def test_an_unknown_mode_is_refused_with_the_choices():
    with pytest.raises(ValueError, match="SAME_STEP"):
        native(SERVO, "sometimes")


def test_disabled_mode_refuses_to_step_an_ended_env():
    env = native(ALTINO, AutoresetMode.DISABLED)
    env.reset(seed=0)
    push = np.array([[0.0], [1000.0], [0.0]], np.float32)
    for _ in range(200):
        *_, terminated, truncated, _ = env.step(push)
        if (terminated | truncated).any():
            break
    with pytest.raises(gym.error.ResetNeeded, match="reset_mask"):
        env.step(push)
    env.reset(options={"reset_mask": terminated | truncated})
    env.step(push)  # the ended env was reset: stepping goes on


@pytest.mark.parametrize(
    ("mask", "error"),
    [
        ([True, False, True], TypeError),
        (np.array([1, 0, 1]), TypeError),
        (np.array([True, False]), ValueError),
        (np.zeros(3, bool), ValueError),
    ],
    ids=["list", "ints", "shape", "none"],
)
def test_bad_reset_masks_are_refused_as_sync_vector_env_refuses_them(mask, error):
    for env in (native(SERVO, AutoresetMode.NEXT_STEP), sync(SERVO, AutoresetMode.NEXT_STEP)):
        env.reset(seed=0)
        with pytest.raises(error):
            env.reset(options={"reset_mask": mask})


def test_a_masked_reset_keeps_the_other_envs_and_the_callers_options():
    env = native(SERVO, AutoresetMode.NEXT_STEP)
    obs, _ = env.reset(seed=0)
    for _ in range(5):
        obs = env.step(np.full((NUM_ENVS, 1), 0.5, np.float32))[0]
    options = {"reset_mask": np.array([False, True, False]), "position": 0.1}
    again, info = env.reset(options=options)
    np.testing.assert_array_equal(again[[0, 2]], obs[[0, 2]])
    assert again[1, 0] == pytest.approx(0.1, abs=2e-3)
    assert list(info["_position"]) == [False, True, False]
    assert "reset_mask" in options  # the caller's dict is left whole


@pytest.mark.parametrize("env_id", IDS)
def test_a_masked_reset_returns_the_last_observation_of_the_others_even_if_the_caller_changed_it(
    env_id,
):
    # the others' observations are rebuilt from their state (noise included), not kept aside
    env = native(env_id, AutoresetMode.NEXT_STEP, sensor_noise=True)
    env.reset(seed=1)
    for action in commands(env_id, 7, (NUM_ENVS,)):
        obs = env.step(action)[0]
    last = obs.copy()
    obs[:] = 99.0  # a caller that normalises in place
    again, _ = env.reset(options={"reset_mask": np.array([True, False, False])})
    np.testing.assert_array_equal(again[1:], last[1:])


def test_a_masked_reset_before_any_reset_is_refused():
    env = native(SERVO, AutoresetMode.NEXT_STEP)
    with pytest.raises(gym.error.ResetNeeded, match="reset every env once"):
        env.reset(options={"reset_mask": np.ones(NUM_ENVS, bool)})


def test_get_attr_call_and_set_attr_answer_as_sync_vector_env_does():
    ours = native(SERVO, AutoresetMode.NEXT_STEP, render_mode="rgb_array")
    theirs = sync(SERVO, AutoresetMode.NEXT_STEP, render_mode="rgb_array")
    for env in (ours, theirs):
        env.reset(seed=3)
        env.step(np.full((NUM_ENVS, 1), 0.4, np.float32))
    for name in ("dt", "np_random_seed", "render_mode", "action_space", "observation_space"):
        assert ours.get_attr(name) == theirs.get_attr(name), name
    for a, b in zip(ours.call("render"), theirs.call("render"), strict=True):
        np.testing.assert_array_equal(a, b)
    draws = [tuple(g.random() for g in env.get_attr("np_random")) for env in (ours, theirs)]
    assert draws[0] == draws[1]
    for env in (ours, theirs):
        env.set_attr("curriculum_level", 2)
        assert env.get_attr("curriculum_level") == (2,) * NUM_ENVS
        env.set_attr("curriculum_level", [3] * NUM_ENVS)
        assert env.get_attr("curriculum_level") == (3,) * NUM_ENVS


def test_what_the_shared_simulation_cannot_do_per_env_is_refused_clearly():
    env = native(SERVO, AutoresetMode.NEXT_STEP)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="one value for all"):
        env.set_attr("curriculum_level", [1, 2, 3])
    with pytest.raises(AttributeError, match="fixed when it is made"):
        env.set_attr("dt", 0.01)
    with pytest.raises(AttributeError, match="no method 'step'"):
        env.call("step", np.zeros((NUM_ENVS, 1)))


def test_what_a_review_found_odd_now_answers_as_sync_does():
    ours, theirs = native(ALTINO, AutoresetMode.NEXT_STEP), sync(ALTINO, AutoresetMode.NEXT_STEP)
    for env in (ours, theirs):
        env.reset(seed=0)
        env.step(np.zeros((NUM_ENVS, 1), np.float16))  # any float dtype is a command
        env.set_attr("offsets", [np.zeros(2)] * NUM_ENVS)  # array values compared by content
    assert ours.get_attr("spec")[0].kwargs == {}  # the single env's spec: gym.make can use it
    assert gym.make(ours.get_attr("spec")[0]).unwrapped.device.name == "AltinoDistance"
    # A masked reset takes N-long positions: the masked envs' entries.
    obs, _ = ours.reset(
        options={
            "reset_mask": np.array([False, True, False]),
            "position": np.array([9.0, 12.0, 9.0]),
        }
    )
    assert obs[1, 1] == pytest.approx(12.0, abs=0.1)


@pytest.mark.parametrize(
    "kwargs", [{"reference": "random_steps"}, RANDOM_KWARGS], ids=["reference", "randomize"]
)
def test_a_refused_action_after_an_episode_end_spends_none_of_the_resets_draws(kwargs):
    envs = [native(SERVO, AutoresetMode.NEXT_STEP, **kwargs) for _ in range(2)]
    action = np.full((NUM_ENVS, 1), 0.3, np.float32)
    for env in envs:
        env.reset(seed=1)
        for _ in range(MAX_STEPS):  # every env is truncated: the next step resets them
            env.step(action)
    bad = action.copy()
    bad[2] = np.nan
    with pytest.raises(ValueError, match="not a finite number"):
        envs[0].step(bad)
    assert_same(envs[0].step(action), envs[1].step(action))


@pytest.mark.parametrize("kwargs", [{}, RANDOM_KWARGS], ids=["default", "randomize"])
def test_a_refused_action_after_an_episode_end_changes_nothing(kwargs):
    env = native(SERVO, AutoresetMode.NEXT_STEP, **kwargs)
    action = np.full((NUM_ENVS, 1), 0.3, np.float32)
    env.reset(seed=1)
    for _ in range(MAX_STEPS):  # every env is truncated: the next step resets them
        env.step(action)
    plants = env.unwrapped.sim.plants
    before = plants.state.copy(), plants.delay_buffer.copy(), plants.rows.copy()
    bad = action.copy()
    bad[2] = np.nan
    with pytest.raises(ValueError, match="not a finite number"):
        env.step(bad)
    for kept, now in zip(before, (plants.state, plants.delay_buffer, plants.rows), strict=True):
        np.testing.assert_array_equal(now, kept)  # the ended envs were not reset either


def test_a_single_env_resets_after_a_refused_action():
    env = gym.make(SERVO)
    first = env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan], np.float32))
    assert_same(env.reset(seed=0), first)
