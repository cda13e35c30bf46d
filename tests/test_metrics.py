import dataclasses
import math

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from frictiongym.metrics import (
    ResponseMetrics,
    control_effort,
    iae,
    itae,
    limit_cycle,
    response_metrics,
    step_metrics,
    time_stuck,
)


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
    assert m.rise_time == pytest.approx(
        0.1 * math.log(0.97 / 0.07) - 0.1 * math.log(0.97 / 0.87), abs=2e-3
    )


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


# --------------------------------------------------------------------------------------------
# Cross-check against python-control's step_info
# --------------------------------------------------------------------------------------------

DT = 1e-3


def _response(sys, t_end: float, dt: float = DT):
    t = np.arange(0.0, t_end + dt / 2, dt)
    return t, np.asarray(control.step_response(sys, t).outputs).ravel()


def _second_order_tf(zeta: float, wn: float = 10.0):
    return control.tf([wn**2], [1.0, 2 * zeta * wn, wn**2])


LINEAR_SYSTEMS = {
    "zeta=0.2": _second_order_tf(0.2),
    "zeta=0.5": _second_order_tf(0.5),
    "zeta=0.7": _second_order_tf(0.7),
    "zeta=1.0": _second_order_tf(1.0),
    # 3rd order: an underdamped pair and a real pole of comparable speed, DC gain 1.
    "3rd-order": _second_order_tf(0.3) * control.tf([8.0], [1.0, 8.0]),
}


@pytest.mark.parametrize("name", list(LINEAR_SYSTEMS))
def test_step_and_response_metrics_match_step_info(name):
    sys = LINEAR_SYSTEMS[name]
    t, y = _response(sys, t_end=6.0)
    final = float(control.dcgain(sys))
    assert final == pytest.approx(1.0)
    ref = control.step_info(y, t, final_output=final)
    ours = step_metrics(t, y, reference=1.0, y0=0.0, final_value=final)
    # Long enough a run (> 10 time constants) that the reference and the final value agree.
    full = response_metrics(t, y, reference=1.0, y0=0.0)
    for m in (ours, full):
        # Rise time, peak and overshoot have the same definition here as in step_info (first
        # sample at or past each limit, largest sample): they agree to rounding.
        assert m.rise_time == pytest.approx(ref["RiseTime"], abs=1e-9)
        assert m.peak_time == pytest.approx(ref["PeakTime"], abs=1e-9)
        assert m.overshoot_pct == pytest.approx(ref["Overshoot"], abs=1e-6)
        # step_info counts a sample exactly on the band edge as outside: one sample at most.
        assert m.settling_time == pytest.approx(ref["SettlingTime"], abs=DT + 1e-12)
    # The same data given as an LTI system (python-control then uses the DC gain).
    from_sys = control.step_info(sys, T=t)
    assert ours.settling_time == pytest.approx(from_sys["SettlingTime"], abs=DT + 1e-12)
    assert ours.rise_time == pytest.approx(from_sys["RiseTime"], abs=1e-9)


def test_final_value_default_of_step_info_is_last_sample():
    # A short run that has not settled: step_info (data, no final_output) uses y[-1].
    t, y = _response(_second_order_tf(0.5), t_end=0.5)
    ref = control.step_info(y, t)
    ours = step_metrics(t, y, reference=1.0, y0=0.0, final_value=float(y[-1]))
    assert ours.rise_time == pytest.approx(ref["RiseTime"], abs=1e-9)
    assert ours.peak_time == pytest.approx(ref["PeakTime"], abs=1e-9)
    assert ours.overshoot_pct == pytest.approx(ref["Overshoot"], abs=1e-6)
    assert ours.settling_time == pytest.approx(ref["SettlingTime"], abs=DT + 1e-12)


def test_offset_start_and_time_origin_differ_from_step_info_by_design():
    # step_info measures from y = 0 and reports absolute times; we measure from y0 and t[0].
    t, y = _response(_second_order_tf(0.4), t_end=3.0)
    ref = control.step_info(y, t, final_output=1.0)
    shifted = step_metrics(t + 2.0, y + 5.0, reference=6.0, y0=5.0)
    assert shifted.rise_time == pytest.approx(ref["RiseTime"], abs=1e-9)
    assert shifted.peak_time == pytest.approx(ref["PeakTime"], abs=1e-9)
    assert shifted.settling_time == pytest.approx(ref["SettlingTime"], abs=DT + 1e-12)
    assert shifted.overshoot_pct == pytest.approx(ref["Overshoot"], rel=1e-6)


def test_peak_of_non_minimum_phase_response_differs_from_step_info_by_design():
    # Undershoot (-1.25) larger than any overshoot: step_info's PeakTime is at the largest |y|
    # (the undershoot), ours at the largest excursion in the step's direction.
    sys = control.tf([-4.0, 1.0], [1.0, 2.0, 1.0])
    t, y = _response(sys, t_end=20.0)
    ref = control.step_info(y, t, final_output=1.0)
    ours = step_metrics(t, y, reference=1.0, y0=0.0, final_value=1.0)
    assert t[np.argmin(y)] == pytest.approx(ref["PeakTime"])
    assert ours.peak_time > 10.0  # monotone approach from below: the peak is at the end
    assert ours.rise_time == pytest.approx(ref["RiseTime"], abs=1e-9)
    assert ours.overshoot_pct == ref["Overshoot"] == 0.0


# --------------------------------------------------------------------------------------------
# IAE, ITAE, control effort
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("tau", [0.05, 0.3])
def test_iae_itae_of_first_order_error(tau):
    t_end = 20 * tau
    t = np.arange(0.0, t_end + DT / 2, DT)
    e = np.exp(-t / tau)
    decay = math.exp(-t_end / tau)
    # Trapezoid error is dt^2/12 * [f'(T) - f'(0)]: about dt^2 / (12 tau) and dt^2 / 12.
    assert iae(t, e) == pytest.approx(tau * (1 - decay), abs=DT**2 / tau)
    assert itae(t, e) == pytest.approx(tau**2 - tau * (t_end + tau) * decay, abs=DT**2)
    assert iae(t, -e) == iae(t, e)  # absolute error
    # -> tau and tau^2 for a long run (here e^-20 from the limit).
    assert iae(t, e) == pytest.approx(tau, abs=DT**2 / tau + tau * decay)
    assert itae(t, e) == pytest.approx(tau**2, abs=DT**2 + tau * (t_end + tau) * decay)


def test_iae_itae_of_constant_error_and_time_origin():
    t = np.linspace(3.0, 5.0, 11)  # starts at 3 s: times count from t[0]
    e = np.full_like(t, -0.5)
    assert iae(t, e) == pytest.approx(0.5 * 2.0)
    assert itae(t, e) == pytest.approx(0.5 * 2.0**2 / 2)


def test_control_effort_is_rms():
    t = np.linspace(0.0, 2.0, 201)
    assert control_effort(t, np.full_like(t, -3.0)) == pytest.approx(3.0)
    amplitude, period = 2.5, 0.25  # 8 whole periods
    u = amplitude * np.sin(2 * np.pi * t / period + 0.3)
    assert control_effort(t, u) == pytest.approx(amplitude / math.sqrt(2), rel=1e-9)
    # A time average: the same signal over twice the run has the same effort.
    t2 = np.linspace(0.0, 4.0, 401)
    u2 = amplitude * np.sin(2 * np.pi * t2 / period + 0.3)
    assert control_effort(t2, u2) == pytest.approx(control_effort(t, u), rel=1e-9)


# --------------------------------------------------------------------------------------------
# Limit cycle
# --------------------------------------------------------------------------------------------

T_RUN = np.arange(0.0, 10.0 + DT / 2, DT)


@settings(max_examples=40, deadline=None)
@given(
    amplitude=st.floats(0.01, 100.0),
    period=st.floats(0.02, 1.0),
    phase=st.floats(0.0, 2 * math.pi),
    offset=st.floats(-10.0, 10.0),
)
def test_limit_cycle_of_a_sine(amplitude, period, phase, offset):
    y = offset + amplitude * np.sin(2 * np.pi * T_RUN / period + phase)
    a, p = limit_cycle(T_RUN, y, hysteresis=0.2 * amplitude)
    # Within what one sample can change: the sine moves at most 2*pi*A*dt/P per sample.
    assert a == pytest.approx(amplitude, abs=2 * np.pi * amplitude * DT / period)
    assert p == pytest.approx(period, abs=DT)


def test_limit_cycle_of_a_stick_slip_square_wave():
    # Stick at 0.95, slip in 20 ms to 1.05, stick 300 ms, slip back...: period 0.64 s.
    knots_t, knots_y, now, level = [0.0], [0.95], 0.0, 0.95
    while now < T_RUN[-1]:
        now += 0.3
        knots_t.append(now)
        knots_y.append(level)
        now += 0.02
        level = 2.0 - level
        knots_t.append(now)
        knots_y.append(level)
    y = np.interp(T_RUN, knots_t, knots_y)
    a, p = limit_cycle(T_RUN, y, hysteresis=0.01)
    assert a == pytest.approx(0.05, abs=1e-9)
    assert p == pytest.approx(0.64, abs=DT)
    m = response_metrics(T_RUN, y, reference=1.0, y0=0.0)  # default band: 0.01
    assert m.limit_cycle_amplitude == pytest.approx(0.05, abs=1e-9)
    assert m.limit_cycle_period == pytest.approx(0.64, abs=DT)


@pytest.mark.parametrize("window", [0.5, 1.0])
def test_decaying_oscillation_is_not_a_limit_cycle(window):
    t, y = _response(_second_order_tf(0.2), t_end=3.0)
    # Even with no hysteresis at all, which counts every crossing of the mean.
    a, p = limit_cycle(t, y, hysteresis=0.0, window=window)
    assert a == 0.0
    assert math.isnan(p)
    m = response_metrics(t, y, reference=1.0)
    assert m.limit_cycle_amplitude == 0.0
    assert math.isnan(m.limit_cycle_period)


@pytest.mark.parametrize(
    "y",
    [
        np.full_like(T_RUN, 0.1),  # constant (its mean is not exactly 0.1)
        0.3 * T_RUN - 1.0,  # ramp
        0.97 * (1 - np.exp(-T_RUN / 0.2)),  # stuck at a fixed offset
    ],
    ids=["constant", "ramp", "stuck-offset"],
)
def test_no_limit_cycle_without_oscillation(y):
    a, p = limit_cycle(T_RUN, y)
    assert a == 0.0
    assert math.isnan(p)


def test_noise_below_hysteresis_is_not_a_limit_cycle():
    rng = np.random.default_rng(0)
    y = 1.0 + rng.uniform(-0.009, 0.009, T_RUN.size)
    assert limit_cycle(T_RUN, y, hysteresis=0.01)[0] == 0.0
    # Without hysteresis every crossing of the mean counts: noise looks like a fast cycle.
    a, p = limit_cycle(T_RUN, y, hysteresis=0.0)
    assert a > 0.0
    assert p < 10 * DT


def test_quantised_rest_is_not_a_limit_cycle_with_the_default_band():
    # A servo at rest dithering by one encoder count (2048 counts/rev) around 1 rad.
    count = 2 * np.pi / 2048
    y = np.where(np.arange(T_RUN.size) % 7 < 3, 1.0, 1.0 + count)
    y[: T_RUN.size // 4] = np.linspace(0.0, 1.0, T_RUN.size // 4)
    m = response_metrics(T_RUN, y, reference=1.0)
    assert m.limit_cycle_amplitude == 0.0


def test_oscillation_starting_late_is_detected():
    # Still for 8 s, then 4 periods of 0.5 s that last to the end.
    y = np.where(T_RUN > 8.0, 0.2 * np.sin(2 * np.pi * (T_RUN - 8.0) / 0.5), 0.0)
    a, p = limit_cycle(T_RUN, y, hysteresis=0.02)
    assert a == pytest.approx(0.2, abs=1e-3)
    assert p == pytest.approx(0.5, abs=DT)


def test_oscillation_that_dies_before_the_end_is_not_a_limit_cycle():
    # Sustained until 6 s, then stuck: plenty of cycles in the window, but none at its end.
    y = np.where(T_RUN < 6.0, 0.2 * np.sin(2 * np.pi * T_RUN / 0.25), 0.0)
    assert limit_cycle(T_RUN, y, hysteresis=0.02)[0] == 0.0


def test_min_cycles():
    # Two periods from rest at 9 s: the first exit from the band is not a crossing (the
    # trigger had no state yet), so 3 crossings (down, up, down): one complete cycle.
    y = np.where(T_RUN > 9.0, np.sin(2 * np.pi * (T_RUN - 9.0) / 0.5), 0.0)
    assert limit_cycle(T_RUN, y, hysteresis=0.1)[0] == 0.0
    a, p = limit_cycle(T_RUN, y, hysteresis=0.1, min_cycles=1)
    assert a == pytest.approx(1.0, abs=1e-3)
    assert p == pytest.approx(0.5, abs=DT)


def test_growing_oscillation_is_not_sustained():
    y = np.exp(T_RUN / 1.0) * np.sin(2 * np.pi * T_RUN / 0.5)
    assert limit_cycle(T_RUN, y, hysteresis=0.0)[0] == 0.0


# --------------------------------------------------------------------------------------------
# Time stuck
# --------------------------------------------------------------------------------------------


def test_time_stuck():
    t = np.arange(11) * 0.1  # 1 s run
    never_moves = np.ones(11, dtype=bool)
    assert time_stuck(t, never_moves) == pytest.approx(1.0)
    start_only = np.array([1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0], dtype=bool)
    assert time_stuck(t, start_only) == 0.0
    # Breaks away at 0.2 s, moves, sticks from 0.5 s to the end (0.5 s).
    moves_then_sticks = np.array([1, 1, 0, 0, 0, 1, 1, 1, 1, 1, 1], dtype=bool)
    assert time_stuck(t, moves_then_sticks) == pytest.approx(0.5)
    # Stick-slip: two stuck samples mid-run count their intervals; 0/1 ints are accepted.
    assert time_stuck(t, [0, 0, 1, 1, 0, 0, 0, 0, 0, 0, 1]) == pytest.approx(0.2)
    assert time_stuck(t, np.zeros(11)) == 0.0


def test_time_stuck_uses_sample_durations():
    t = np.array([0.0, 0.1, 0.5, 0.6, 2.0])  # non-uniform sampling
    assert time_stuck(t, [False, True, False, True, True]) == pytest.approx(0.4 + 1.4)


# --------------------------------------------------------------------------------------------
# response_metrics
# --------------------------------------------------------------------------------------------


def test_response_metrics_fields_and_combination():
    assert [f.name for f in dataclasses.fields(ResponseMetrics)] == [
        "rise_time",
        "peak_time",
        "settling_time",
        "overshoot_pct",
        "steady_state_error",
        "steady_state_error_pct",
        "iae",
        "itae",
        "control_effort",
        "limit_cycle_amplitude",
        "limit_cycle_period",
        "time_stuck",
    ]
    t = T_RUN
    y = 2.0 * (1 - np.exp(-t / 0.2)) + 0.1 * np.sin(2 * np.pi * t / 0.4) * (t > 1.0)
    command = np.full_like(t, 0.5)
    stuck = t < 0.1
    m = response_metrics(t, y, reference=2.0, command=command, stuck=stuck)
    step = step_metrics(t, y, reference=2.0)
    assert {k: v for k, v in m.as_dict().items() if k in step.as_dict()} == step.as_dict()
    assert m.iae == pytest.approx(iae(t, 2.0 - y))
    assert m.itae == pytest.approx(itae(t, 2.0 - y))
    assert m.control_effort == pytest.approx(0.5)
    assert m.time_stuck == 0.0
    assert m.limit_cycle_amplitude == pytest.approx(0.1, abs=1e-3)
    assert m.limit_cycle_period == pytest.approx(0.4, abs=DT)
    assert len(m.as_dict()) == 12

    bare = response_metrics(t, y, reference=2.0)
    assert math.isnan(bare.control_effort)
    assert math.isnan(bare.time_stuck)
    # Hunting inside half the settling band (0.02 of a step of 2: +-0.02) is not counted.
    small = 2.0 * (1 - np.exp(-t / 0.2)) + 0.015 * np.sin(2 * np.pi * t / 0.4)
    assert response_metrics(t, small, reference=2.0).limit_cycle_amplitude == 0.0
    assert response_metrics(t, small, 2.0, cycle_hysteresis=0.0).limit_cycle_amplitude > 0.0


def test_response_metrics_is_frozen():
    t = np.linspace(0.0, 1.0, 101)
    m = response_metrics(t, t, reference=1.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.iae = 0.0  # type: ignore[misc]


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: iae([0.0, 1.0, 2.0], [0.0, 1.0]), "same length"),
        (lambda: iae([[0.0, 1.0]], [0.0, 1.0]), "1-D"),
        (lambda: iae([0.0, 1.0], [[0.0, 1.0]]), "same length"),
        (lambda: iae([0.0], [1.0]), "at least 2 samples"),
        (lambda: itae([0.0, 1.0, 2.0], [0.0, np.nan, 1.0]), r"error\[1\] = nan"),
        (lambda: itae([0.0, np.inf], [0.0, 1.0]), "t must be finite"),
        (lambda: control_effort([0.0, 2.0, 1.0], [1.0, 1.0, 1.0]), "strictly increasing"),
        (lambda: control_effort([0.0, 1.0, 1.0], [1.0, 1.0, 1.0]), "duplicate"),
        (lambda: control_effort(["a", "b"], [1.0, 1.0]), "numbers"),
        (lambda: limit_cycle([0.0, 1.0], [0.0, 1.0]), "at least 3"),
        (lambda: limit_cycle(T_RUN, T_RUN, hysteresis=-1.0), "hysteresis"),
        (lambda: limit_cycle(T_RUN, T_RUN, window=0.0), "window"),
        (lambda: limit_cycle(T_RUN, T_RUN, min_cycles=0), "min_cycles"),
        (lambda: time_stuck([0.0, 1.0, 2.0], [True, False]), "same length"),
        (lambda: time_stuck([0.0, 1.0], [0.5, 1.0]), "booleans"),
        (lambda: step_metrics([0.0, 1.0], [0.0, 1.0], math.nan), "reference must be finite"),
        (lambda: step_metrics([0.0, 1.0], [0.0, 1.0], 1.0, rise_limits=(0.9, 0.1)), "rise"),
        (lambda: step_metrics([0.0, 1.0], [0.0, 1.0], 1.0, end_fraction=2.0), "end_fraction"),
        (lambda: step_metrics([0.0, 1.0], [0.0, 1.0], 1.0, settling_band=0.0), "settling"),
        (lambda: response_metrics(T_RUN, T_RUN, 1.0, command=[1.0, 2.0]), "command"),
        (lambda: response_metrics(T_RUN, T_RUN, 1.0, stuck=T_RUN), "booleans"),
    ],
)
def test_validation_errors(call, match):
    with pytest.raises(ValueError, match=match):
        call()
