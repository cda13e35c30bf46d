"""rollout on single and vector envs, Rollout.metrics, and ControllerPolicy (SB3's predict)."""

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.controllers import (
    PID,
    Controller,
    ControllerPolicy,
    LoopSpec,
    PIDGains,
    Rollout,
    rollout,
)
from frictiongym.envs import RotaryServoEnv, RotaryServoVectorEnv
from frictiongym.metrics import response_metrics
from frictiongym.plants.presets import ALTINO_PAPER_GAINS_KI10, ROTARY_PAPER_GAINS

SERVO = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"
SERVO_GAINS = PIDGains(**ROTARY_PAPER_GAINS)
#: The per-sample signals and per-env flags (``direction`` and ``settings`` describe the run).
FIELDS = [f.name for f in dataclasses.fields(Rollout) if f.name not in ("direction", "settings")]


class Constant(Controller):
    """A controller returning a fixed command (one per env if ``value`` is an array)."""

    def __init__(self, spec, value):
        self.spec = spec
        self.value = np.asarray(value, dtype=np.float64)

    def reset(self, mask=None):
        pass

    def command(self, observation):
        _, y, _ = self.spec.split(observation)
        return np.broadcast_to(self.value, y.shape).astype(np.float64)


# --------------------------------------------------------------------------------------------
# Single env
# --------------------------------------------------------------------------------------------


def test_single_env_rollout_records_the_episode():
    env = gym.make(SERVO)
    run = rollout(env, PID.for_env(env, SERVO_GAINS), seed=0)
    n = 2501
    assert run.num_envs == 1
    np.testing.assert_array_equal(run.length, [n])
    assert not run.terminated[0]
    assert run.t.shape == (n,)
    for name in FIELDS:
        if name not in ("t", "length", "terminated"):
            assert getattr(run, name).shape == (n, 1), name
    assert run.t[0] == 0.0
    np.testing.assert_allclose(np.diff(run.t), env.unwrapped.dt, rtol=1e-9)
    assert run.position[0, 0] == 0.0  # the servo starts at rest at 0 rad
    assert run.velocity[0, 0] == 0.0
    assert run.reward[0, 0] == 0.0
    assert np.all(run.reward[1:] < 0.0)
    np.testing.assert_array_equal(run.reference, 1.0)  # the default 1 rad step
    for name in ("position", "velocity", "measured", "command", "reference", "reward"):
        assert np.all(np.isfinite(getattr(run, name))), name
    assert run.stuck[0, 0]  # it starts stuck
    assert np.array_equal(run.signal("position"), run.position[:, 0])
    assert run.valid.all()  # the encoder's angle is never saturated
    assert run.direction == 1.0


def test_single_env_command_is_the_applied_action():
    env = gym.make(SERVO)
    run = rollout(env, PID.for_env(env, SERVO_GAINS), seed=3)
    # The same loop by hand.
    pid = PID.for_env(env, SERVO_GAINS)
    obs, info = env.reset(seed=3)
    pid.reset()
    positions, measured, rewards, applied = [info["position"]], [obs[0]], [0.0], []
    for _ in range(2500):
        action = pid(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        assert info["command"] == float(np.clip(action[0], -10.0, 10.0))
        applied.append(info["command"])
        positions.append(info["position"])
        measured.append(obs[0])
        rewards.append(reward)
    assert truncated
    assert not terminated
    np.testing.assert_array_equal(run.command[:-1, 0], applied)  # held from t[k] to t[k+1]
    assert run.command[-1, 0] == run.command[-2, 0]  # the last sample repeats it
    np.testing.assert_array_equal(run.position[:, 0], positions)
    np.testing.assert_array_equal(run.measured[:, 0], np.asarray(measured, dtype=np.float64))
    np.testing.assert_array_equal(run.reward[:, 0], rewards)


def test_command_is_saturated_by_the_env():
    env = gym.make(SERVO)
    # A controller that thinks the limit is 100 V asks for 50 V; the amplifier gives 10 V.
    wide = Constant(LoopSpec(dt=0.002, limit=100.0), 50.0)
    run = rollout(env, wide, steps=20)
    np.testing.assert_array_equal(run.command, 10.0)
    negative = rollout(env, Constant(LoopSpec(dt=0.002, limit=100.0), -50.0), steps=20)
    np.testing.assert_array_equal(negative.command, -10.0)


def test_steps_argument():
    env = gym.make(SERVO)
    run = rollout(env, PID.for_env(env, SERVO_GAINS), steps=30)
    assert run.t.shape == (31,)
    np.testing.assert_array_equal(run.length, [31])
    assert run.t[-1] == pytest.approx(30 * 0.002)
    full = rollout(env, PID.for_env(env, SERVO_GAINS))
    np.testing.assert_array_equal(full.position[:31], run.position)


def test_steps_errors():
    env = gym.make(SERVO)
    pid = PID.for_env(env, SERVO_GAINS)
    for steps in (0, -1):
        with pytest.raises(ValueError, match="positive number of steps"):
            rollout(env, pid, steps=steps)
    bare = RotaryServoEnv()  # no TimeLimit, no registered episode length
    with pytest.raises(ValueError, match="positive number of steps"):
        rollout(bare, pid)
    assert rollout(bare, pid, steps=5).length[0] == 6
    bare_vec = RotaryServoVectorEnv(num_envs=2)  # max_episode_steps None
    with pytest.raises(ValueError, match="positive number of steps"):
        rollout(bare_vec, PID.for_env(bare_vec, SERVO_GAINS))


# --------------------------------------------------------------------------------------------
# Vector env
# --------------------------------------------------------------------------------------------


def test_vector_env_rollout_equals_single_env_rollouts():
    vec = gym.make_vec(
        SERVO, num_envs=3, vectorization_mode="vector_entry_point", sensor_noise=True
    )
    run = rollout(vec, PID.for_env(vec, SERVO_GAINS), seed=[5, 6, 7])
    assert run.num_envs == 3
    np.testing.assert_array_equal(run.length, [2501] * 3)
    env = gym.make(SERVO, sensor_noise=True)
    singles = [rollout(env, PID.for_env(env, SERVO_GAINS), seed=s) for s in (5, 6, 7)]
    for i, single in enumerate(singles):
        np.testing.assert_array_equal(run.t, single.t)
        for name in FIELDS:
            if name == "t":
                continue
            np.testing.assert_array_equal(
                getattr(run, name)[..., i], getattr(single, name)[..., 0], err_msg=name
            )
    # The noise differs between seeds, so the columns are not copies of each other.
    assert not np.array_equal(run.measured[:, 0], run.measured[:, 1])


# --------------------------------------------------------------------------------------------
# Termination
# --------------------------------------------------------------------------------------------


def test_altino_driven_into_the_wall_terminates():
    env = gym.make(ALTINO)
    full_forward = Constant(LoopSpec.from_env(env), 1000.0)
    run = rollout(env, full_forward)
    n = int(run.length[0])
    assert run.terminated[0]
    assert n < 401
    assert run.t.shape == (n,)
    assert run.position[-1, 0] <= 0.0  # touched the wall
    assert np.all(run.position[:-1, 0] > 0.0)
    assert run.reward[-1, 0] < -100.0  # the limit penalty
    m = run.metrics()
    assert np.isfinite(m.iae)
    assert m.iae > 0.0
    assert m.control_effort == pytest.approx(1000.0)


def test_vector_env_keeps_recording_the_envs_that_did_not_crash():
    vec = gym.make_vec(ALTINO, num_envs=2, vectorization_mode="vector_entry_point")
    spec = LoopSpec.from_env(vec)
    run = rollout(vec, Constant(spec, [1000.0, 0.0]))  # env 0 full forward, env 1 idle
    crashed = int(run.length[0])
    assert run.terminated.tolist() == [True, False]
    assert crashed < 401
    assert run.length[1] == 401
    assert run.t.shape == (401,)
    np.testing.assert_allclose(np.diff(run.t), 0.05, rtol=1e-9)
    for name in ("position", "velocity", "measured", "command", "reference", "reward"):
        values = getattr(run, name)
        assert np.all(np.isfinite(values[:crashed, 0])), name
        assert np.all(np.isnan(values[crashed:, 0])), name
        assert np.all(np.isfinite(values[:, 1])), name
    assert not run.stuck[crashed:, 0].any()
    np.testing.assert_array_equal(run.position[:, 1], 30.0)  # never moved
    assert run.signal("position", 0).shape == (crashed,)
    # The crashed env's samples equal those of a single env driven the same way.
    single = rollout(gym.make(ALTINO), Constant(spec, 1000.0))
    np.testing.assert_array_equal(run.signal("position", 0), single.signal("position"))
    assert run.metrics(0) == single.metrics(0)
    assert run.metrics(1).iae == pytest.approx(25.0 * 20.0)  # 25 cm short for 20 s


# --------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------


def test_metrics_agree_with_response_metrics_by_hand():
    vec = gym.make_vec(ALTINO, num_envs=2, vectorization_mode="vector_entry_point")
    run = rollout(vec, PID.for_env(vec, PIDGains(**ALTINO_PAPER_GAINS_KI10)), seed=[1, 2])
    for i in range(2):
        n = int(run.length[i])
        for kwargs in ({}, {"settling_band": 0.05, "end_fraction": 0.2}):
            by_hand = response_metrics(
                run.t[:n],
                run.position[:n, i],
                run.reference[n - 1, i],
                command=run.command[:n, i],
                stuck=run.stuck[:n, i],
                y0=run.position[0, i],
                **kwargs,
            )
            assert run.metrics(i, **kwargs) == by_hand


def test_metrics_need_two_samples():
    env = gym.make(SERVO)
    run = rollout(env, PID.for_env(env, SERVO_GAINS), steps=1)
    assert run.t.shape == (2,)
    short = dataclasses.replace(run, length=np.array([1]))
    with pytest.raises(ValueError, match="too short for metrics"):
        short.metrics()


# --------------------------------------------------------------------------------------------
# ControllerPolicy
# --------------------------------------------------------------------------------------------


def test_evaluate_policy_scores_a_pid_like_rollout():
    from stable_baselines3.common.evaluation import evaluate_policy

    env = gym.make(SERVO, max_episode_steps=200)
    expected = rollout(env, PID.for_env(env, SERVO_GAINS)).reward.sum()
    policy = ControllerPolicy(PID.for_env(env, SERVO_GAINS))
    with pytest.warns(UserWarning, match="Monitor"):
        returns, lengths = evaluate_policy(
            policy, env, n_eval_episodes=2, return_episode_rewards=True
        )
    assert lengths == [200, 200]
    # DummyVecEnv keeps float32 rewards and the policy float32 actions: not bit-identical.
    assert returns == pytest.approx([expected, expected], rel=1e-5)
    mean, std = evaluate_policy(policy, env, n_eval_episodes=2, warn=False)
    assert mean == pytest.approx(expected, rel=1e-5)
    assert std == pytest.approx(0.0, abs=1e-4)


def test_predict_returns_float32_actions_per_env():
    env = gym.make(SERVO)
    policy = ControllerPolicy(PID.for_env(env, SERVO_GAINS))
    obs = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 1.0]], dtype=np.float32)
    action, state = policy.predict(obs, state=None, episode_start=np.ones(2, dtype=bool))
    assert action.dtype == np.float32
    assert action.shape == (2, 1)
    assert state is None
    g = SERVO_GAINS
    expected = [g.kp * e + g.ki * e * 0.002 for e in (1.0, 0.5)]
    np.testing.assert_allclose(action[:, 0], expected, rtol=1e-6)
    single = ControllerPolicy(PID.for_env(env, SERVO_GAINS))(np.array([0.0, 0.0, 1.0]))
    assert single.dtype == np.float32
    assert single.shape == (1,)


def test_episode_start_resets_only_the_starting_envs():
    dt = 0.1
    pid = PID(LoopSpec(dt=dt, limit=100.0), PIDGains(kp=1.0, ki=1.0))
    policy = ControllerPolicy(pid)
    obs = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.0, 0.0, 3.0]])
    errors = np.array([1.0, 2.0, 3.0])
    policy.predict(obs, episode_start=np.ones(3, dtype=bool))
    for _ in range(3):
        policy.predict(obs, episode_start=np.zeros(3, dtype=bool))
    np.testing.assert_allclose(pid.integral, 4 * dt * errors)
    # A new episode in env 1 only: its integral restarts, the others carry on.
    action, _ = policy.predict(obs, episode_start=np.array([False, True, False]))
    np.testing.assert_allclose(pid.integral, [5 * dt * 1.0, 1 * dt * 2.0, 5 * dt * 3.0])
    np.testing.assert_allclose(action[:, 0], errors + pid.integral, rtol=1e-6)
    # Resetting before the call: with a zero error, the masked env's integral stays 0.
    at_reference = np.array([[0.0, 0.0, 1.0], [2.0, 0.0, 2.0], [0.0, 0.0, 3.0]])
    policy.predict(at_reference, episode_start=[False, True, False])
    np.testing.assert_allclose(pid.integral, [6 * dt * 1.0, 0.0, 6 * dt * 3.0])
    # Every env starting: a full reset.
    policy.predict(obs, episode_start=np.ones(3, dtype=bool))
    np.testing.assert_allclose(pid.integral, dt * errors)


# --------------------------------------------------------------------------------------------
# The one run record: sensor range, the plant's direction, runs recorded by hand
# --------------------------------------------------------------------------------------------


def test_altino_rollout_marks_the_ir_sensors_saturated_samples_invalid():
    env = gym.make(ALTINO)
    run = rollout(env, PID.for_env(env, PIDGains(**ALTINO_PAPER_GAINS_KI10)))
    far = run.signal("measured") >= env.observation_space.high[1]  # 30 cm: beyond 21.47 cm
    assert far[0]
    assert not far[-1]
    np.testing.assert_array_equal(run.signal("valid"), ~far)
    assert run.direction == -1.0  # a positive command shortens the distance
    np.testing.assert_array_equal(run.plant_output(), -run.signal("measured"))


def test_a_run_recorded_by_hand_fills_what_it_did_not_record():
    run = Rollout.of_one_run(
        np.arange(3) * 0.1, settings={"kind": "ramp"}, command=[1.0, 2.0, 3.0], measured=[0, 1, 2]
    )
    assert run.num_envs == 1
    assert run.length.tolist() == [3]
    assert not run.terminated[0]
    assert run.signal("command").tolist() == [1.0, 2.0, 3.0]
    assert np.isnan(run.position).all()
    assert run.valid.all()
    assert not run.stuck.any()
    assert run.settings == {"kind": "ramp"}
    with pytest.raises(TypeError, match="no signal"):
        Rollout.of_one_run(np.arange(3) * 0.1, output=[0.0, 1.0, 2.0])


def test_metrics_of_the_measured_output_use_what_the_controller_saw():
    env = gym.make(SERVO, sensor_noise=True)
    run = rollout(env, PID.for_env(env, SERVO_GAINS), seed=2)
    n = int(run.length[0])
    expected = response_metrics(
        run.t[:n], run.measured[:n, 0], 1.0, command=run.command[:n, 0], y0=run.measured[0, 0]
    )
    np.testing.assert_equal(run.metrics(output="measured").as_dict(), expected.as_dict())
    assert run.metrics().iae != expected.iae  # the true angle differs from the noisy one
    with pytest.raises(ValueError, match="'position' or 'measured'"):
        run.metrics(output="velocity")
