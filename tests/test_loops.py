"""Closed-loop step experiments of the paper on the simulated plants (frictiongym.loops).

Thresholds come from the phenomena and the specs, not from our numbers. Where the Altino model
disagrees with the paper (docs/altino-model.md), the test says so and pins what the model does.
"""

import dataclasses
import importlib.util
import itertools
import math
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.controllers import PID, FrictionCompensator, Rollout, rollout
from frictiongym.controllers.pid import PIDGains
from frictiongym.friction import ALTINO_LUGRE, ALTINO_PAPER, ROTARY_PAPER, NoFriction
from frictiongym.loops import altino_step, rotary_step
from frictiongym.plants.presets import (
    ALTINO_DT,
    ALTINO_PAPER_GAINS_COMPENSATED,
    ALTINO_PAPER_GAINS_KI10,
    ALTINO_PAPER_GAINS_KI20,
    ALTINO_PLANT,
    ALTINO_START_CM,
    ALTINO_TARGET_CM,
    ROTARY_PAPER_GAINS,
)
from frictiongym.plants.sensors import QUBE_COUNTS_PER_REV, ir_readout

TARGET = ALTINO_TARGET_CM
STEP = ALTINO_START_CM - TARGET
US = 200.0  # the paper's break-away level, both directions (Fig. 10(b))
KI10 = PIDGains(**ALTINO_PAPER_GAINS_KI10)
KI20 = PIDGains(**ALTINO_PAPER_GAINS_KI20)
COMPENSATED = PIDGains(**ALTINO_PAPER_GAINS_COMPENSATED)


def stick_spans(run: Rollout) -> list[tuple[int, int]]:
    """Index ranges [i, j) where the car is stuck, the rest before the first motion excluded."""
    stuck = run.signal("stuck")
    first = int(np.argmin(stuck))  # first moving sample
    edges = np.flatnonzero(np.diff(stuck[first:].astype(np.int8))) + first + 1
    bounds = [first, *edges.tolist(), stuck.size]
    return [(i, j) for i, j in itertools.pairwise(bounds) if stuck[i]]


# --- QUBE-Servo 2 --------------------------------------------------------------------------


def test_rotary_nominal_plant_meets_the_papers_four_specs():
    m = rotary_step(NoFriction(), duration=2.0).metrics()
    assert m.rise_time < 0.05
    assert m.peak_time < 0.1
    assert m.settling_time < 1.5
    assert m.overshoot_pct < 20.0


def test_rotary_with_paper_friction_ends_stuck_off_target():
    run = rotary_step(ROTARY_PAPER, duration=2.0)
    error = abs(1.0 - run.signal("position")[-1])
    assert run.signal("stuck")[-round(0.5 / 0.002) :].all()  # held by stiction for the last 0.5 s
    # Larger than one encoder count, and inside the P band |e| <= u_s / Kp that stiction holds.
    assert 2.0 * math.pi / QUBE_COUNTS_PER_REV < error < 0.210 / ROTARY_PAPER_GAINS["kp"]


# --- Altino: presets -----------------------------------------------------------------------


def test_altino_start_is_in_the_papers_range_beyond_the_eq1_saturation():
    # The paper's stated IR range is "up to 30 cm"; Eq. (1) reads 0 beyond 21.47 cm.
    assert ir_readout(ALTINO_START_CM) == 0 < ir_readout(20.0)
    assert ALTINO_START_CM <= 30.0
    assert ALTINO_PLANT.delay_steps(ALTINO_DT) >= 0  # dead time is whole periods


def test_altino_lugre_preset_mirrors_the_paper_levels_and_the_plant_mass():
    lugre, paper = ALTINO_LUGRE, ALTINO_PAPER
    assert (lugre.us_pos, lugre.us_neg, lugre.uc_pos, lugre.uc_neg) == (
        paper.us_pos,
        paper.us_neg,
        paper.uc_pos,
        paper.uc_neg,
    )
    assert lugre.viscous == paper.viscous
    # The Gaussian Stribeck curve is within 1 % of u_s - u_c of u_c at the paper's v0.
    for vs, v0 in ((lugre.vs_pos, paper.v0_pos), (lugre.vs_neg, paper.v0_neg)):
        assert math.exp(-((v0 / vs) ** 2)) == pytest.approx(0.01)
    assert lugre.us_pos / lugre.sigma0 == pytest.approx(0.05)  # pre-sliding at break-away, cm
    zeta = lugre.sigma1 / (2.0 * math.sqrt(lugre.sigma0 * ALTINO_PLANT.inertia))
    assert zeta == pytest.approx(1.0)  # critically damped bristles with the preset mass


# --- Altino: the paper's experiments -------------------------------------------------------


def test_ki10_stops_short_of_the_papers_overshoot():
    """Known disagreement: the paper saw an overshoot to about 3 cm.

    From 30 cm the car passes the target by less than 1 cm (0.35 cm) and stays stuck there,
    inside the stiction band |e| < u_s / Kp (docs/altino-model.md).
    """
    run = altino_step(KI10, duration=20.0)
    assert not run.terminated[0]
    assert 0.0 < TARGET - run.signal("position").min() < 1.0
    assert run.signal("stuck")[-round(10.0 / ALTINO_DT) :].all()
    assert abs(TARGET - run.signal("position")[-1]) * KI10.kp < US


def test_ki10_overshoots_and_stays_from_40cm_where_ki20_hits_the_wall():
    """The paper's Ki = 10 phenomenon needs a start the paper's Ki = 20 run rules out."""
    ki10 = altino_step(KI10, start_cm=45.0, duration=20.0)
    i, j = next((i, j) for i, j in stick_spans(ki10) if j > int(np.argmin(ki10.signal("position"))))
    assert 1.0 < TARGET - ki10.signal("position")[i] < 3.0  # passes the target by 1-3 cm
    assert (j - i) * ALTINO_DT >= 10.0  # and stays there
    ki20 = altino_step(KI20, start_cm=45.0, duration=20.0)
    assert ki20.terminated[0]
    assert ki20.signal("position")[-1] == 0.0
    assert ki20.t[-1] < 5.0


def test_ki20_overshoots_sticks_and_does_not_hunt():
    """Known disagreement: the paper's Ki = 20 run oscillates around 5 cm.

    The model overshoots by more than 1 cm, sticks for seconds, returns once and then stays
    stuck near the target: no target crossing in 30-60 s.
    """
    run = altino_step(KI20, duration=60.0)
    assert not run.terminated[0]
    assert TARGET - run.signal("position").min() > 1.0
    i, j = stick_spans(run)[0]
    assert (j - i) * ALTINO_DT > 3.0
    tail = run.signal("position")[run.t >= 30.0]
    assert np.all(np.sign(tail - TARGET) == np.sign(tail[0] - TARGET))
    assert abs(tail[-1] - TARGET) < 0.5


def test_stuck_car_breaks_away_when_the_integral_reaches_the_breakaway_level():
    """Oracle O8: while stuck the PID command ramps at Ki*e and motion starts at u_s."""
    run = altino_step(KI20, duration=20.0)
    i, j = stick_spans(run)[0]
    assert j < run.t.size  # it does break away within the run
    error = TARGET - run.signal("measured")[i]
    ramp = np.diff(run.signal("command")[i + 1 : j - 1]) / ALTINO_DT
    np.testing.assert_allclose(ramp, -KI20.ki * error, rtol=1e-9)  # D term is 0 while stuck
    k = i + int(
        np.flatnonzero(run.signal("command")[i:] < -US)[0]
    )  # first command beyond break-away
    # It reaches the plant after the dead time and moves the car during the next period.
    assert j == k + 1 + ALTINO_PLANT.delay_steps(ALTINO_DT)


def test_velocity_weakening_friction_makes_ki20_hunt_around_the_target():
    """Hunting (oracle O9) needs a friction drop faster than the viscous rise (shape 'step').

    With the paper's linear decay the first return sticks within 0.1 cm of the target and the
    next break-away is minutes away; see docs/altino-model.md.
    """
    friction = ALTINO_PAPER.replace(shape="step")
    run = altino_step(KI20, friction=friction, start_cm=20.0, duration=60.0)
    rests = [run.signal("position")[i] for i, _ in stick_spans(run)]
    assert len(rests) >= 4
    sides = np.sign(np.asarray(rests) - TARGET)
    assert np.all(sides[1:] == -sides[:-1])  # alternates around the target
    assert all(abs(r - TARGET) > 0.5 for r in rests)  # and does not die out


def test_compensated_run_settles_fast_and_close_without_oscillating():
    run = altino_step(COMPENSATED, compensator=ALTINO_PAPER)
    m = run.metrics()
    band = 0.02 * STEP
    assert m.rise_time < 1.5  # 1.05 s; the paper's < 1 s is missed, docs/altino-model.md
    assert 1.0 < m.settling_time < 2.5  # known disagreement: the paper's < 1 s is out of reach
    assert m.steady_state_error < band
    assert TARGET - run.signal("position").min() < band  # no overshoot beyond the band
    tail = run.signal("position")[run.t >= 5.0]
    assert np.all(np.sign(tail - TARGET) == np.sign(tail[0] - TARGET))  # no oscillation


def test_compensation_beats_both_uncompensated_runs():
    comp = altino_step(COMPENSATED, compensator=ALTINO_PAPER, duration=20.0).metrics()
    for gains in (KI10, KI20):
        pid = altino_step(gains, duration=20.0).metrics()
        assert comp.settling_time < pid.settling_time
        assert comp.rise_time <= pid.rise_time


def test_derivative_on_the_error_kicks_the_first_command():
    on_error = altino_step(COMPENSATED, duration=0.5, derivative="error")
    on_measurement = altino_step(COMPENSATED, duration=0.5)
    kick = COMPENSATED.kd * STEP / ALTINO_DT  # 2100 units, beyond the 1000 limit
    assert on_error.signal("command")[0] == min(kick, ALTINO_PLANT.command_limit)
    assert on_measurement.signal("command")[0] < ALTINO_PLANT.command_limit
    np.testing.assert_array_equal(
        on_error.signal("stuck")[:2], [True, True]
    )  # dead time: no motion yet
    with pytest.raises(ValueError, match="derivative"):
        altino_step(COMPENSATED, derivative="filtered")  # type: ignore[arg-type]


def test_altino_runs_are_deterministic_and_start_from_rest():
    a = altino_step(KI20, duration=3.0)
    b = altino_step(KI20, duration=3.0)
    np.testing.assert_array_equal(a.signal("position"), b.signal("position"))
    assert a.signal("position")[0] == ALTINO_START_CM
    heavier = dataclasses.replace(ALTINO_PLANT, inertia=2.0 * ALTINO_PLANT.inertia)
    c = altino_step(KI20, duration=3.0, plant=heavier)
    assert (
        c.signal("position")[10] > a.signal("position")[10]
    )  # a heavier car has covered less ground after 0.5 s


def test_rotary_runs_never_collide():
    assert not rotary_step(duration=0.1).terminated[0]


# --- the experiments are rollout on the registered envs ------------------------------------


def assert_same_run(run: Rollout, expected: Rollout) -> None:
    """Every field of two records equal, bit for bit (NaN where neither recorded a value)."""
    for field in dataclasses.fields(Rollout):
        np.testing.assert_array_equal(
            getattr(run, field.name), getattr(expected, field.name), err_msg=field.name
        )


def test_the_servo_step_is_rollout_of_the_papers_pid_on_the_registered_env():
    env = gym.make("frictiongym/RotaryServo-v1")
    expected = rollout(env, PID.for_env(env, PIDGains(**ROTARY_PAPER_GAINS)))
    assert expected.t.size == 2501  # the registered 5 s episode, rotary_step's default
    assert_same_run(rotary_step(), expected)


@pytest.mark.parametrize(
    ("gains", "compensated", "start"),
    [(KI10, False, ALTINO_START_CM), (KI20, False, 45.0), (COMPENSATED, True, ALTINO_START_CM)],
)
def test_the_altino_experiment_is_rollout_on_the_registered_env(gains, compensated, start):
    """The paper's runs (and the Ki = 20 run that reaches the wall from 45 cm)."""
    env = gym.make("frictiongym/AltinoDistance-v1")
    pid = PID.for_env(env, gains)
    # altino_step's compensator: the "command" variant with an exact-zero rest band.
    controller = FrictionCompensator(pid, rest_speed=0.0) if compensated else pid
    expected = rollout(env, controller, options={"position": start})
    run = altino_step(
        gains, compensator=ALTINO_PAPER if compensated else None, start_cm=start, duration=20.0
    )
    assert_same_run(run, expected)
    assert run.terminated[0] == (start == 45.0)


# --- scripts/altino_phenomena.py -----------------------------------------------------------


def _script():
    path = Path(__file__).resolve().parents[1] / "scripts" / "altino_phenomena.py"
    spec = importlib.util.spec_from_file_location("altino_phenomena", path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while it executes
    spec.loader.exec_module(module)
    return module


def test_phenomena_script_prints_the_table(capsys, tmp_path):
    script = _script()
    png = tmp_path / "altino.png"
    args = ["--duration", "6", "--start", "45"]
    if importlib.util.find_spec("matplotlib") is not None:
        args += ["--plot", str(png)]
    assert script.main(args) == 0
    out = capsys.readouterr().out
    for label in ("PID Ki=10", "PID Ki=20", "compensated"):
        assert label in out
    assert "hit the wall" in out  # Ki = 20 from 45 cm
    if "--plot" in args:
        assert png.stat().st_size > 1000


def test_phenomena_script_rejects_a_dead_time_that_is_not_whole_periods(capsys):
    with pytest.raises(SystemExit) as info:
        _script().main(["--dead-time", "0.03"])
    assert info.value.code == 2
    assert "whole number of control periods" in capsys.readouterr().err
