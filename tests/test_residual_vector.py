"""The batched residual env against SyncVectorEnv over ResidualEnv, in SAME_STEP autoreset."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from frictiongym.controllers import PID, PIDGains
from frictiongym.residual import ResidualEnv
from frictiongym.residual.vector_env import ResidualVectorEnv, make_residual_vec
from tests._envs import ALTINO, IDS, RANDOM_KWARGS, SERVO
from tests.test_vector_modes import assert_same

NUM_ENVS, MAX_STEPS = 3, 40
OBJECTIVES = [{}, {"precision": 0.01, "residual_cost": 0.5}]


def policy_actions(steps: int, seed: int = 2) -> np.ndarray:
    """Residual actions in [-1.2, 1.2] (beyond the bound too), one per env."""
    return np.random.default_rng(seed).uniform(-1.2, 1.2, (steps, NUM_ENVS, 1)).astype(np.float32)


def run(env: gym.vector.VectorEnv, steps: int = 130) -> list[Any]:
    """A run whose envs end their episodes on different steps (env 1 restarts at step 7)."""
    trace: list[Any] = [env.reset(seed=21)]
    for k, a in enumerate(policy_actions(steps)):
        trace.append(env.step(a))
        if k == 7:
            trace.append(env.reset(options={"reset_mask": np.array([False, True, False])}))
    return trace


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("kwargs", [{}, RANDOM_KWARGS], ids=["default", "random"])
@pytest.mark.parametrize("objective", OBJECTIVES, ids=["env-reward", "precision-cost"])
def test_batched_residual_env_equals_sync_over_the_single_residual_env(env_id, kwargs, objective):
    env_kwargs = {"max_episode_steps": MAX_STEPS, **kwargs}
    ours = run(make_residual_vec(env_id, NUM_ENVS, **objective, **env_kwargs))
    theirs = run(
        SyncVectorEnv(
            [lambda: ResidualEnv(gym.make(env_id, horizon=MAX_STEPS, **env_kwargs), **objective)]
            * NUM_ENVS,
            autoreset_mode=AutoresetMode.SAME_STEP,
        )
    )
    for k, (a, b) in enumerate(zip(ours, theirs, strict=True)):
        assert_same(a, b, f"call {k}")
    assert sum(int(out[3].sum()) for out in ours if len(out) == 5) >= 2 * NUM_ENVS


def test_a_masked_reset_resets_only_those_base_controllers():
    env = make_residual_vec(SERVO, NUM_ENVS)
    single = [ResidualEnv(gym.make(SERVO)) for _ in range(NUM_ENVS)]
    obs, _ = env.reset(seed=5)
    ref = [e.reset(seed=5 + i)[0] for i, e in enumerate(single)]
    actions = policy_actions(20)
    for a in actions[:10]:
        obs = env.step(a)[0]
        ref = [e.step(a[i])[0] for i, e in enumerate(single)]
    mask = np.array([False, True, False])
    obs, _ = env.reset(options={"reset_mask": mask})
    ref[1] = single[1].reset()[0]
    for a in actions[10:]:
        obs = env.step(a)[0]
        ref = [e.step(a[i])[0] for i, e in enumerate(single)]
    np.testing.assert_array_equal(obs, np.array(ref))


def test_the_vector_env_must_autoreset_on_the_same_step():
    vec = gym.make_vec(ALTINO, num_envs=2, vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError, match="SAME_STEP"):
        ResidualVectorEnv(vec)


def test_a_given_batched_base_controller_is_used():
    vec = gym.make_vec(
        SERVO,
        num_envs=2,
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    pid = PID.for_env(vec, PIDGains(2.0, 0.0, 0.0))
    env = ResidualVectorEnv(vec, pid, scale=0.5)
    env.reset(seed=0)
    info = env.step(np.zeros((2, 1), np.float32))[4]
    assert env.base is pid
    np.testing.assert_array_equal(info["base_action"], info["command"])  # residual 0


def test_a_base_whose_history_puts_the_batch_first_is_refused_not_run_wrong():
    """advance() restores the others' history along the last axis; (N, 1) would be mixed up."""
    from frictiongym.controllers.base import Controller

    class BatchFirst(Controller):
        def __init__(self, spec):
            self.spec = spec
            self.integral = np.zeros((NUM_ENVS, 1))

        def reset(self, mask=None):
            self.integral[np.asarray(mask if mask is not None else True, bool)] = 0.0

        def command(self, observation):
            self.integral += observation[:, :1]
            return self.integral[:, 0]

    vec = gym.make_vec(
        SERVO,
        num_envs=NUM_ENVS,
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    env = ResidualVectorEnv(vec, BatchFirst.for_env)
    env.reset(seed=0)
    with pytest.raises(TypeError, match="batch on the last axis"):
        env.reset(options={"reset_mask": np.array([True, False, False])})
