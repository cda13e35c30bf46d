"""The single envs: registration, checkers, contract, sensors, reward, episode end, options."""

from __future__ import annotations

import math
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from frictiongym import devices
from frictiongym.envs import ENV_IDS
from frictiongym.envs.references import Sine, StepSequence
from frictiongym.friction import ROTARY_PAPER, NoFriction
from frictiongym.plants import Plant
from frictiongym.plants.presets import ALTINO_PLANT, ROTARY_DT, ROTARY_PLANT
from frictiongym.plants.sensors import (
    QUBE_ENCODER_STEP,
    FilteredDerivative,
    ir_distance,
    ir_readout,
    quantize_angle,
)
from tests._envs import ALTINO, IDS, RANDOM_KWARGS, SERVO, commands

# Gymnasium's checker flags physical-unit actions and unbounded observations; both are by
# design (docs/envs.md: actions in volts / motor units, like Pendulum).
# The third kind is numba compiling a serial kernel with parallel=True on purpose
# (frictiongym.plants._kernel.serial_njit); the package filters it, catch_warnings here does not.
EXPECTED_WARNINGS = (
    "symmetric and normalized",
    "is probably too low",
    "is probably too high",
    "no transformation for parallel execution",
)


def _unexpected(caught: list[warnings.WarningMessage]) -> list[str]:
    messages = [str(w.message) for w in caught]
    return [m for m in messages if not any(e in m for e in EXPECTED_WARNINGS)]


def test_registration_uses_string_entry_points_and_time_limits():
    for env_id in IDS:
        spec = gym.spec(env_id)
        assert isinstance(spec.entry_point, str)
        assert isinstance(spec.vector_entry_point, str)
        assert spec.max_episode_steps == devices.get(env_id).episode_steps == ENV_IDS[env_id][3]


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("kwargs", [{}, RANDOM_KWARGS], ids=["default", "random"])
def test_gymnasium_and_sb3_checkers_pass(env_id, kwargs):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(gym.make(env_id, **kwargs).unwrapped)
        sb3_check_env(gym.make(env_id, **kwargs))
    assert _unexpected(caught) == []


@pytest.mark.parametrize("env_id", IDS)
def test_reset_and_step_return_the_contract(env_id):
    env = gym.make(env_id)
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    assert set(info) == {"position", "velocity", "command", "reference", "time", "stuck"}
    assert info["time"] == 0.0
    assert info["stuck"]
    assert info["command"] == 0.0
    obs, reward, terminated, truncated, info = env.step(np.array([0.0], dtype=np.float32))
    assert isinstance(reward, float)
    assert terminated is False
    assert truncated is False
    assert info["time"] == pytest.approx(env.unwrapped.dt)


@pytest.mark.parametrize(("env_id", "limit"), [(SERVO, 10.0), (ALTINO, 1000.0)])
def test_out_of_range_actions_are_saturated_and_reported(env_id, limit):
    env = gym.make(env_id)
    env.reset(seed=0)
    assert env.action_space.high[0] == limit
    assert env.step([5 * limit])[4]["command"] == limit
    assert env.step(np.array([-5 * limit]))[4]["command"] == -limit


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_actions_raise_and_change_nothing(bad):
    env, twin = gym.make(SERVO), gym.make(SERVO)
    env.reset(seed=0)
    twin.reset(seed=0)
    env.step([0.5])
    twin.step([0.5])
    with pytest.raises(ValueError, match="not a finite number"):
        env.step([bad])
    assert env.step([0.5])[4] == twin.step([0.5])[4]


def test_actions_of_the_wrong_shape_raise():
    env = gym.make(SERVO)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="one number"):
        env.step([1.0, 2.0])


def test_servo_follows_the_plant_and_its_sensors_exactly():
    """The env runs the plant kernel, the encoder and the filtered derivative, nothing else."""
    env = gym.make(SERVO).unwrapped
    obs, info = env.reset(seed=0)
    plant = Plant(ROTARY_PLANT, ROTARY_PAPER, ROTARY_DT)
    tach = FilteredDerivative(50.0, ROTARY_DT, resolution=QUBE_ENCODER_STEP)
    tach.update(quantize_angle(0.0))
    for u in commands(SERVO, 400, seed=3)[:, 0] * 4:
        obs, reward, _, _, info = env.step([u])
        plant.step(float(u))
        angle = float(quantize_angle(plant.position[0]))
        assert info["position"] == plant.position[0]
        assert info["velocity"] == plant.velocity[0]
        assert info["stuck"] == plant.stuck[0]
        assert obs[0] == np.float32(angle)
        assert obs[1] == np.float32(tach.update(angle))
        expected = -(abs(info["reference"] - info["position"]) + 0.01 * (info["command"] / 10) ** 2)
        assert reward == pytest.approx(expected, rel=1e-12)


def test_altino_measures_through_the_ir_equation_with_one_period_of_dead_time():
    env = gym.make(ALTINO).unwrapped
    obs, info = env.reset(seed=0)
    assert info["position"] == 30.0
    assert obs[0] == 0.0
    assert obs[1] == pytest.approx(966 / 45)
    obs, _, _, _, info = env.step([600.0])
    assert info["position"] == 30.0
    assert info["command"] == 600.0
    previous = obs[1]
    for _ in range(20):
        obs, reward, _, _, info = env.step([400.0])
        assert obs[0] == ir_readout(info["position"])
        assert obs[1] == np.float32(ir_distance(obs[0]))
        assert obs[2] == pytest.approx((obs[1] - previous) / 0.05, rel=1e-6, abs=1e-3)
        assert reward == pytest.approx(
            -(abs(5.0 - info["position"]) / 5.0 + 0.01 * 0.4**2), rel=1e-12
        )
        previous = obs[1]
    assert info["velocity"] < 0.0  # approaching: the distance falls


def test_delay_zero_moves_the_car_at_once():
    env = gym.make(ALTINO, delay=0.0)
    env.reset(seed=0)
    assert env.step([600.0])[4]["position"] < 30.0


def test_altino_touching_the_wall_terminates_with_the_penalty():
    env = gym.make(ALTINO)
    env.reset(seed=0, options={"position": 3.0})
    for _ in range(50):
        obs, reward, terminated, _, info = env.step([1000.0])
        if terminated:
            break
    assert terminated
    assert info["position"] <= 0.0
    assert reward < -100.0
    assert obs[0] == 800.0


def test_servo_running_away_terminates():
    env = gym.make(SERVO)
    env.reset(seed=0)
    for _ in range(500):
        *_, terminated, _, info = env.step([10.0])
        if terminated:
            break
    assert terminated
    assert abs(info["position"]) > 4 * math.pi


@pytest.mark.parametrize("env_id", IDS)
def test_episodes_are_truncated_by_the_registered_time_limit(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    steps = gym.spec(env_id).max_episode_steps
    for _ in range(steps - 1):
        assert not env.step([0.0])[3]
    assert env.step([0.0])[3]


def test_the_paper_friction_holds_the_servo_inside_the_band():
    for friction, moves in [("paper", False), ("none", True), (NoFriction(), True)]:
        env = gym.make(SERVO, friction=friction)
        env.reset(seed=0)
        info = env.step([0.2])[4]  # u_s+ = 0.21 V
        assert (info["position"] != 0.0) is moves
        assert info["stuck"] is not moves


@pytest.mark.parametrize("friction", ["paper", "none", "coulomb", "stribeck", "lugre"])
@pytest.mark.parametrize("env_id", IDS)
def test_every_named_law_runs(env_id, friction):
    env = gym.make(env_id, friction=friction)
    env.reset(seed=0)
    for u in commands(env_id, 50):
        obs = env.step(u)[0]
    assert np.all(np.isfinite(obs))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"friction": "sticky"}, "unknown friction law"),
        ({"friction": 3}, "FrictionModel"),
        ({"reference": "square"}, "unknown reference"),
        ({"randomize": {"mass": (0.9, 1.1)}}, "unknown randomisation keys"),
        ({"randomize": {"friction": (1.2, 0.8)}}, "0 < low <= high"),
        ({"sensor_noise": -1.0}, "sensor_noise must be >= 0"),
        ({"dt": 0.0}, "dt must be > 0"),
        ({"delay": 0.003}, "whole number of control"),
        ({"backend": "ftp://device"}, "unknown backend"),
        ({"backend": "serial:///dev/ttyACM0", "randomize": {"friction": (0.9, 1.1)}}, "not with"),
        ({"log": False}, "settings of device runs"),
        ({"render_mode": "ascii"}, "render_mode must be one of"),
    ],
)
def test_bad_arguments_say_what_is_wrong(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        gym.make(SERVO, **kwargs)


def test_a_missing_port_says_what_to_check():
    with pytest.raises(
        FileNotFoundError, match=r"could not open '/dev/frictiongym-none'.*plugged in"
    ):
        gym.make(SERVO, backend="/dev/frictiongym-none")


def test_reset_options_set_the_start_and_one_episodes_reference():
    env = gym.make(SERVO)
    obs, info = env.reset(seed=0, options={"position": 0.5, "velocity": 2.0, "reference": -1})
    assert info["position"] == 0.5
    assert info["velocity"] == 2.0
    assert not info["stuck"]
    assert obs[0] == np.float32(quantize_angle(0.5))
    assert obs[2] == -1.0
    obs, info = env.reset()
    assert info["position"] == 0.0
    assert obs[2] == 1.0


@pytest.mark.parametrize(
    ("env_id", "options", "match"),
    [
        (SERVO, {"angle": 1.0}, "unknown reset options"),
        (SERVO, {"position": math.nan}, "must be finite"),
        (SERVO, {"position": 20.0}, "within the safety limit"),
        (ALTINO, {"position": 0.0}, "distance to the wall"),
        (ALTINO, {"reference": "nowhere"}, "unknown reference"),
    ],
)
def test_bad_reset_options_say_what_is_wrong(env_id, options, match):
    with pytest.raises(ValueError, match=match):
        gym.make(env_id).reset(seed=0, options=options)


def test_reference_generators_drive_the_observed_reference():
    sine = Sine(amplitude=0.5, period=0.1)
    env = gym.make(SERVO, reference=sine)
    obs, _ = env.reset(seed=0)
    observed = [obs[2]] + [env.step([0.0])[0][2] for _ in range(60)]
    t = np.arange(61) * ROTARY_DT
    np.testing.assert_array_equal(observed, sine(t).astype(np.float32))
    env.reset(options={"reference": StepSequence((1.0, 2.0), period=0.01)})
    assert [env.step([0.0])[4]["reference"] for _ in range(6)] == [1, 1, 1, 1, 2, 2]


@pytest.mark.parametrize("env_id", IDS)
def test_seeded_runs_repeat_and_seeds_differ(env_id):
    def run(seed: int) -> list:
        env = gym.make(env_id, **RANDOM_KWARGS)
        obs, _ = env.reset(seed=seed)
        return [obs.tolist()] + [env.step(u)[0].tolist() for u in commands(env_id, 200)]

    assert run(7) == run(7)
    assert run(7) != run(8)


def test_sensor_noise_has_the_requested_spread():
    env = gym.make(SERVO, sensor_noise=0.01, quantize=False)
    env.reset(seed=1)
    angles = np.array([env.step([0.0])[0][0] for _ in range(4000)])
    assert abs(angles.mean()) < 4 * 0.01 / math.sqrt(4000)
    assert angles.std() == pytest.approx(0.01, rel=0.05)


def test_randomisation_scales_the_plant_and_the_sensor():
    env = gym.make(SERVO, randomize={"friction": (2.0, 2.0), "sensor_gain": (2.0, 2.0)})
    obs, _info = env.reset(seed=0, options={"position": 0.5})
    assert obs[0] == np.float32(quantize_angle(1.0))  # the encoder reads twice the angle
    assert env.step([0.4])[4]["stuck"]  # the band is 2 x 0.21 V
    heavy = gym.make(SERVO, friction="none", randomize={"inertia": (4.0, 4.0)})
    light = gym.make(SERVO, friction="none")
    heavy.reset(seed=0)
    light.reset(seed=0)
    assert heavy.step([1.0])[4]["velocity"] == pytest.approx(
        light.step([1.0])[4]["velocity"] / 4, rel=0.01
    )


def test_pickled_envs_continue_identically():
    env = gym.make(ALTINO, **RANDOM_KWARGS)
    env.reset(seed=3)
    actions = commands(ALTINO, 60)
    for u in actions[:30]:
        env.step(u)
    clone = pickle.loads(pickle.dumps(env))
    for u in actions[30:]:
        a, b = env.step(u), clone.step(u)
        np.testing.assert_array_equal(a[0], b[0])
        assert a[1:] == b[1:]


@pytest.mark.parametrize(("env_id", "shape"), [(SERVO, (400, 400, 3)), (ALTINO, (200, 600, 3))])
def test_rgb_array_frames_follow_the_state(env_id, shape):
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    assert first.shape == shape
    assert first.dtype == np.uint8
    for _ in range(30):
        env.step([env.action_space.high[0]])
    assert not np.array_equal(first, env.render())


def test_human_mode_opens_a_window_and_closes():
    pytest.importorskip("pygame")
    env = gym.make(SERVO, render_mode="human")
    env.reset(seed=0)
    assert env.render() is None
    env.step([1.0])
    clone = pickle.loads(pickle.dumps(env))  # the window is not pickled
    clone.close()
    env.close()


def test_render_without_a_mode_warns():
    env = gym.make(SERVO)
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.unwrapped.render() is None


@pytest.mark.parametrize("env_id", IDS)
def test_dt_and_plant_arguments(env_id):
    env = gym.make(env_id, dt=0.01, plant=ALTINO_PLANT if env_id == ALTINO else ROTARY_PLANT)
    env.reset(seed=0)
    assert env.step([0.0])[4]["time"] == 0.01


@pytest.mark.parametrize("env_id", IDS)
def test_sb3_trains_on_gym_make_without_glue(env_id):
    """A user's training script: gym.make, SB3, learn, predict; nothing in between."""
    from stable_baselines3 import SAC

    env = gym.make(env_id, reference="random_steps")
    model = SAC("MlpPolicy", env, learning_starts=32, batch_size=32, seed=0, device="cpu")
    model.learn(total_timesteps=96)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action)
    assert np.isfinite(env.step(action)[1])
