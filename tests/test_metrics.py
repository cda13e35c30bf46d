import math

import control
import numpy as np
import pytest

from frictiongym.metrics import step_metrics


def _second_order(zeta: float, wn: float = 10.0, dt: float = 1e-3, t_end: float = 3.0):
    sys = control.tf([wn**2], [1.0, 2 * zeta * wn, wn**2])
    t = np.arange(0.0, t_end + dt / 2, dt)
    response = control.step_response(sys, t)
    return t, np.asarray(response.outputs).ravel()


@pytest.mark.parametrize("zeta", [0.2, 0.5, 0.7, 1.0, 1.5])
def test_matches_python_control_step_info(zeta):
    t, y = _second_order(zeta)
    ours = step_metrics(t, y, reference=1.0, y0=0.0, final_value=1.0)
    ref = control.step_info(y, t, final_output=1.0)
    dt = t[1] - t[0]
    assert ours.rise_time == pytest.approx(ref["RiseTime"], abs=dt)
    assert ours.settling_time == pytest.approx(ref["SettlingTime"], abs=dt)
    assert ours.peak_time == pytest.approx(ref["PeakTime"], abs=dt)
    assert ours.overshoot_pct == pytest.approx(ref["Overshoot"], abs=1e-9)


def test_second_order_analytic_overshoot_and_peak_time():
    zeta, wn = 0.3, 10.0
    t, y = _second_order(zeta, wn)
    m = step_metrics(t, y, reference=1.0)
    wd = wn * math.sqrt(1 - zeta**2)
    assert m.peak_time == pytest.approx(math.pi / wd, abs=1e-3)
    expected = 100 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))
    assert m.overshoot_pct == pytest.approx(expected, rel=1e-3)


def test_offset_response_measured_against_reference():
    t = np.linspace(0.0, 2.0, 2001)
    y = 0.97 * (1 - np.exp(-t / 0.1))  # ends 3 % short: a friction-like offset
    m = step_metrics(t, y, reference=1.0)
    assert m.steady_state_error_pct == pytest.approx(3.0, abs=0.01)
    assert math.isinf(m.settling_time)  # never inside the 2 % band of the reference
    assert m.overshoot_pct == 0.0
    assert m.rise_time == pytest.approx(0.1 * math.log(0.97 / 0.07) - 0.1 * math.log(0.97 / 0.87),
                                        abs=2e-3)  # fmt: skip


def test_downward_step_and_nonzero_start():
    t = np.linspace(0.0, 1.0, 1001)
    y = 20.0 - 15.0 * (1 - np.exp(-t / 0.05))  # from 20 down to 5
    m = step_metrics(t, y, reference=5.0)
    assert m.rise_time == pytest.approx(0.05 * math.log(9.0), abs=2e-3)
    assert m.steady_state_error < 1e-6
    assert m.overshoot_pct == 0.0


def test_bad_input_raises():
    with pytest.raises(ValueError, match="same length"):
        step_metrics([0, 1, 2], [0, 1], 1.0)
    with pytest.raises(ValueError, match="finite"):
        step_metrics([0, 1], [0, float("nan")], 1.0)
    with pytest.raises(ValueError, match="zero"):
        step_metrics([0, 1], [1.0, 1.0], 1.0)
