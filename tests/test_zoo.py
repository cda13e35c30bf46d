"""The shipped RL Zoo hyperparameters and frictiongym.zoo, which trains them natively."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from frictiongym import zoo
from frictiongym.controllers.residual_core import make_base

V1 = ("frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1")


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_every_v1_env_has_settings_in_the_zoos_format(algo):
    entries = yaml.safe_load(zoo.conf_file(algo).read_text())
    assert sorted(entries) == sorted(V1)
    for env_id in V1:
        entry = entries[env_id]
        assert entry["env_wrapper"] == [
            {"gymnasium.wrappers.RescaleAction": {"min_action": -1.0, "max_action": 1.0}}
        ]
        assert entry["policy"] == "MlpPolicy"
        settings = zoo.load(algo, env_id)
        assert settings.rescale == (-1.0, 1.0)
        assert settings.n_timesteps > 0
        # Every other key is a constructor argument of the algorithm.
        algorithm = getattr(__import__("stable_baselines3"), algo.upper())
        import inspect

        accepted = inspect.signature(algorithm.__init__).parameters
        assert set(settings.hyperparameters) <= set(accepted)


def test_policy_kwargs_are_read_as_plain_values_never_run():
    assert zoo._plain_dict("dict(log_std_init=-1.0, net_arch=[64, 64])", "x") == {
        "log_std_init": -1.0,
        "net_arch": [64, 64],
    }
    for text in ("dict(activation_fn=nn.ReLU)", "__import__('os')", "dict(a=open('f'))"):
        with pytest.raises(ValueError, match="policy_kwargs"):
            zoo._plain_dict(text, "x")


def test_unknown_algorithms_and_envs_are_named():
    with pytest.raises(ValueError, match="no shipped hyperparameters for 'a2c'"):
        zoo.conf_file("a2c")
    with pytest.raises(ValueError, match="no entry for CartPole-v1"):
        zoo.load("ppo", "CartPole-v1")


def test_native_training_equals_the_zoos_dummy_vec_env_construction():
    """The Zoo builds DummyVecEnv over RescaleAction(gym.make(id)), then VecNormalize: PPO
    with one seed learns the same weights there as on zoo.make_env's native env."""
    settings = dataclasses.replace(
        zoo.load("ppo", V1[1]),
        n_envs=2,
        hyperparameters={**zoo.load("ppo", V1[1]).hyperparameters, "n_steps": 32, "batch_size": 32},
    )
    ours, _ = zoo.train(settings, seed=3, steps=128)

    def make() -> gym.Env:
        return gym.wrappers.RescaleAction(gym.make(V1[1]), -1.0, 1.0)

    env = VecNormalize(DummyVecEnv([make] * 2), gamma=settings.hyperparameters["gamma"])
    env.seed(3)
    theirs = PPO(
        "MlpPolicy",
        env,
        seed=3,
        device="cpu",
        policy_kwargs=settings.policy_kwargs,
        **settings.hyperparameters,
    )
    theirs.learn(128)
    for a, b in zip(ours.policy.parameters(), theirs.policy.parameters(), strict=True):
        np.testing.assert_array_equal(a.detach().numpy(), b.detach().numpy())


def test_episode_return_scores_a_controller_on_the_env():
    env = gym.make(V1[1])
    controller = make_base(env)
    controller.reset()
    score = zoo.episode_return(V1[1], controller)
    assert -2000.0 < score < 0.0  # better than standing still at the start
    assert zoo.episode_return(V1[1], lambda obs: np.zeros(1)) == pytest.approx(-2000.0)


def test_the_zoos_linear_schedules_and_normalize_settings_are_read():
    schedule = zoo._schedule("lin_1e-3")
    assert schedule(1.0) == pytest.approx(1e-3)
    assert schedule(0.25) == pytest.approx(2.5e-4)
    assert zoo._schedule(0.5) == 0.5
    assert zoo._normalize(True, "x") == {}
    assert zoo._normalize(False, "x") is None
    assert zoo._normalize("{'norm_obs': True, 'norm_reward': False}", "x") == {
        "norm_obs": True,
        "norm_reward": False,
    }
    with pytest.raises(ValueError, match="normalize"):
        zoo._normalize("dict(norm_obs=__import__('os'))", "x")
