import math

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.controllers import PID, LoopSpec, PIDGains


def spec(dt=0.1, limit=math.inf, direction=1.0, velocity=1):
    return LoopSpec(dt=dt, limit=limit, velocity=velocity, direction=direction)


def test_proportional_integral_by_hand():
    pid = PID(spec(0.1), PIDGains(kp=2.0, ki=10.0), derivative="difference")
    errors = [1.0, 0.5, -0.25]
    integral = 0.0
    for e in errors:
        integral += e * 0.1
        u = pid.update(e, 0.0)
        assert float(u) == pytest.approx(2.0 * e + 10.0 * integral, abs=1e-15)


def test_hand_computed_sequence_through_the_observation():
    # kp=1, ki=2, kd=0.5 at dt=0.5 on observations [y, v, r]; by hand:
    # k=0: e=1,   I=0.5,  u = 1 + 1 - 0.5*0   = 2.0
    # k=1: e=0.5, I=0.75, u = 0.5 + 1.5 - 0.5*2 = 1.0
    # k=2: e=-0.5, I=0.5, u = -0.5 + 1 - 0.5*(-1) = 1.0
    pid = PID(spec(0.5), PIDGains(kp=1.0, ki=2.0, kd=0.5))
    obs = [[0.0, 0.0, 1.0], [0.5, 2.0, 1.0], [1.5, -1.0, 1.0]]
    actions = [pid(o) for o in obs]
    assert all(a.shape == (1,) for a in actions)
    np.testing.assert_allclose(np.concatenate(actions), [2.0, 1.0, 1.0], atol=1e-15)


def test_derivative_on_measurement_has_no_kick_and_filters():
    dt, tau = 0.01, 0.05
    pid = PID(spec(dt), PIDGains(kp=0.0, kd=3.0), derivative="difference", derivative_tau=tau)
    assert float(pid.update(1.0, 0.0)) == 0.0  # first sample: no history, no kick
    assert float(pid.update(5.0, 0.0)) == 0.0  # reference steps do not kick either
    a = math.exp(-dt / tau)
    u = float(pid.update(5.0, 0.01))  # measurement moves by 0.01 in one period
    assert u == pytest.approx(-3.0 * (1 - a) * 0.01 / dt)
    u2 = float(pid.update(5.0, 0.01))
    assert u2 == pytest.approx(a * u)


def test_velocity_measurement_replaces_the_difference():
    pid = PID(spec(0.01), PIDGains(kp=1.0, kd=0.5))
    assert float(pid.update(1.0, 0.2, velocity=4.0)) == pytest.approx(0.8 - 2.0)


def test_clamping_anti_windup():
    pid = PID(spec(0.01, limit=2.0), PIDGains(kp=1.0, ki=100.0))
    for _ in range(100):
        u = pid.update(10.0, 0.0)  # saturated the whole time
    assert float(u) == 2.0
    assert float(pid.integral) == pytest.approx(0.0)  # the integrator never wound up
    # error reverses: integral action starts at once, nothing to unwind
    u = pid.update(-0.5, 0.0)
    assert float(u) == pytest.approx(-0.5 + 100.0 * (-0.005))


def test_back_calculation_bleeds_the_excess_into_the_integral():
    dt, tt = 0.01, 0.1
    pid = PID(
        spec(dt, limit=2.0),
        PIDGains(kp=1.0, ki=10.0),
        anti_windup="back-calculation",
        tracking_time=tt,
    )
    integral = 0.0
    for _ in range(50):
        u = float(pid.update(10.0, 0.0))
        raw = 10.0 + 10.0 * (integral + 10.0 * dt)
        integral += 10.0 * dt + (min(raw, 2.0) - raw) * dt / (10.0 * tt)
        assert float(pid.integral) == pytest.approx(integral, rel=1e-12)
    assert u == 2.0
    # The integral settles where the tracking term balances the error: (u_sat - raw)/(ki Tt)
    # = -e, i.e. raw = 2 + 10 * 10 * 0.1 = 12 = kp e + ki (I + e dt) = 11 + 10 I: I = 0.1.
    for _ in range(2000):
        pid.update(10.0, 0.0)
    assert float(pid.integral) == pytest.approx(0.1, rel=1e-6)
    none = PID(spec(dt, limit=2.0), PIDGains(kp=1.0, ki=10.0), anti_windup="none")
    for _ in range(100):
        none.update(10.0, 0.0)
    assert float(none.integral) == pytest.approx(10.0)  # winds up without anti-windup


def test_default_tracking_time_is_astrom_hagglunds_rule():
    g = PIDGains(kp=7.8, ki=1.5, kd=0.275)
    pid = PID(spec(), g, anti_windup="back-calculation")
    assert pid.tracking_time == pytest.approx(math.sqrt((7.8 / 1.5) * (0.275 / 7.8)))
    assert PID(spec(), PIDGains(kp=2.0, ki=1.0)).tracking_time == pytest.approx(2.0)


def test_batched_direction_and_masked_reset():
    pid = PID(spec(0.1, direction=-1.0), PIDGains(kp=2.0, ki=1.0), derivative="difference")
    u = pid.update(5.0, np.array([4.0, 5.0, 7.0]))
    np.testing.assert_allclose(u, [-2.0 - 0.1, 0.0, 4.0 + 0.2])
    pid.reset([True, False, False])
    np.testing.assert_allclose(pid.integral, [0.0, 0.0, -0.2])
    with pytest.raises(ValueError, match="reset mask has 2 entries"):
        pid.reset([True, False])
    with pytest.raises(ValueError, match="call reset"):
        pid.update(5.0, np.zeros(4))
    actions = pid(np.array([[4.0, 0.0, 5.0], [5.0, 0.0, 5.0], [7.0, 0.0, 5.0]]))
    assert actions.shape == (3, 1)


@pytest.mark.parametrize("env_id", ["frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1"])
def test_for_env_reads_the_loop(env_id):
    env = gym.make(env_id)
    pid = PID.for_env(env, PIDGains(kp=1.0))
    s = pid.spec
    assert s.dt == env.unwrapped.dt
    assert s.limit == env.action_space.high[0]
    names = env.unwrapped.sim.device.observation_names
    assert names[s.position] in ("angle", "distance")
    assert names[s.velocity] == "velocity"
    assert names[s.reference] == "reference"
    obs, _ = env.reset(seed=0)
    action = pid(obs)
    assert env.action_space.contains(action.astype(np.float32))
    # Far from the reference the command pushes toward it: the servo forward, the Altino
    # (30 cm from the wall, target 5 cm) forward too, i.e. toward the wall.
    assert action[0] > 0.0


def test_for_env_rejects_foreign_envs():
    with pytest.raises(TypeError, match="not a frictiongym env"):
        PID.for_env(gym.make("CartPole-v1"), PIDGains(kp=1.0))


def test_bad_settings_raise():
    with pytest.raises(ValueError, match="kp"):
        PIDGains(kp=float("nan"))
    with pytest.raises(ValueError, match="ki"):
        PIDGains(kp=1.0, ki=-1.0)
    with pytest.raises(ValueError, match="dt"):
        LoopSpec(dt=0.0, limit=1.0)
    with pytest.raises(ValueError, match="direction"):
        LoopSpec(dt=0.1, limit=1.0, direction=2.0)
    with pytest.raises(ValueError, match="anti_windup"):
        PID(spec(), PIDGains(1.0), anti_windup="conditional")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="velocity entry"):
        PID(spec(velocity=None), PIDGains(1.0))
    with pytest.raises(ValueError, match="observation has 2 entries"):
        PID(spec(), PIDGains(1.0))([0.0, 1.0])
