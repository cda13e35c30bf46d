import math

import numpy as np
import pytest

from frictiongym.controllers.pid import PID, PIDGains


def test_proportional_integral_by_hand():
    pid = PID(PIDGains(kp=2.0, ki=10.0), dt=0.1)
    errors = [1.0, 0.5, -0.25]
    integral = 0.0
    for e in errors:
        integral += e * 0.1
        u = pid.update(e, 0.0)
        assert float(u) == pytest.approx(2.0 * e + 10.0 * integral, abs=1e-15)


def test_derivative_on_measurement_has_no_kick_and_filters():
    dt, tau = 0.01, 0.05
    pid = PID(PIDGains(kp=0.0, kd=3.0), dt=dt, derivative_tau=tau)
    assert float(pid.update(1.0, 0.0)) == 0.0  # first sample: no history, no kick
    assert float(pid.update(5.0, 0.0)) == 0.0  # reference steps do not kick either
    a = math.exp(-dt / tau)
    u = float(pid.update(5.0, 0.01))  # measurement moves by 0.01 in one period
    assert u == pytest.approx(-3.0 * (1 - a) * 0.01 / dt)
    u2 = float(pid.update(5.0, 0.01))
    assert u2 == pytest.approx(a * u)


def test_velocity_measurement_replaces_the_difference():
    pid = PID(PIDGains(kp=1.0, kd=0.5), dt=0.01)
    assert float(pid.update(1.0, 0.2, velocity=4.0)) == pytest.approx(0.8 - 2.0)


def test_clamping_anti_windup():
    pid = PID(PIDGains(kp=1.0, ki=100.0), dt=0.01, limit=2.0)
    for _ in range(100):
        u = pid.update(10.0, 0.0)  # saturated the whole time
    assert float(u) == 2.0
    assert pid.integral == pytest.approx(0.0)  # the integrator never wound up
    # error reverses: integral action starts at once, nothing to unwind
    u = pid.update(-0.5, 0.0)
    assert float(u) == pytest.approx(-0.5 + 100.0 * (-0.005))


def test_batched_and_direction():
    pid = PID(PIDGains(kp=2.0), dt=0.1, direction=-1.0)
    u = pid.update(5.0, np.array([4.0, 5.0, 7.0]))
    np.testing.assert_allclose(u, [-2.0, 0.0, 4.0])


def test_bad_settings_raise():
    with pytest.raises(ValueError, match="kp"):
        PIDGains(kp=float("nan"))
    with pytest.raises(ValueError, match="ki"):
        PIDGains(kp=1.0, ki=-1.0)
    with pytest.raises(ValueError, match="dt"):
        PID(PIDGains(1.0), dt=0.0)
    with pytest.raises(ValueError, match="direction"):
        PID(PIDGains(1.0), dt=0.1, direction=2.0)
