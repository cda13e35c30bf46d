"""The reversal test: a play between motor and load estimated from the load's position.

The experiment runs through the simulated env with a known play; the estimator gets the rigid
model (the preset's true ``J``, ``B`` and law, so these tests measure the reversal test alone;
the command's tests and the slow pipeline test identify the rigid model too).

Tolerances, fixed before the runs and not tuned to them:

* given the true rigid model, every estimate lies within **three of its own standard
  errors** of the truth: the standard error is the reversals' scatter over ``sqrt(n)``, so
  this checks that it is honest for the noise (a three-sigma band misses by chance 0.3 % of
  the time); it does not cover errors of an identified rigid model (the command's test);
* servo, 1 degree: also within **2 %**, 0.00035 rad, a ninth of an encoder count (the effect
  of a play on the disc's path is about half its width, so a count of effect is 2 counts of
  play: the test resolves far below the quantisation by fitting many samples);
* Altino, 0.2 cm, readout quantised: also within **5 %**, 0.01 cm, half a readout count at
  the band's near end (4 cm from the wall, 0.018 cm per count). With 2 counts of noise the
  scatter over seeds is 0.013 cm (docs/identification.md), so only the three standard errors
  apply there.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import gymnasium as gym
import pytest

from frictiongym import devices
from frictiongym.cli import tool_main
from frictiongym.identification.backlash import BacklashEstimate, ReversalPlan, reversal_test
from frictiongym.identification.drivetrain import PLAY_ROUNDS
from frictiongym.identification.experiments import Runner
from frictiongym.identification.identify import Plan, identify, make_env, plan_for
from frictiongym.params import Backlash, DeviceParams, ParamsFileError, load_params, save_params

ROTARY = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"
ONE_DEGREE = math.radians(1.0)  # 0.01745 rad
ALTINO_PLAY = 0.2  # cm


def _rigid(device: devices.Device) -> DeviceParams:
    """The preset's true rigid model, as an identification's file holds it (B total)."""
    law = device.paper_friction
    return DeviceParams.from_model(
        law,
        inertia=device.plant.inertia,
        damping=device.plant.damping + law.viscous,
        device=device.name,
    )


def _estimate(
    env_id: str,
    width: float,
    *,
    noise: bool = False,
    seed: int = 0,
    shares: tuple[float, float] | None = None,
) -> BacklashEstimate:
    """Run the device's reversal test on its simulated preset with a play of ``width``."""
    device = devices.get(env_id)
    plan = plan_for(env_id)
    reversal = ReversalPlan.for_device(device)
    if shares is not None:
        reversal = replace(reversal, shares=shares)
    runner = Runner(make_env(env_id, plan, backlash=width, sensor_noise=noise), plan.span, seed)
    return reversal_test(
        runner, _rigid(device), device.paper_friction.breakaway, reversal, reading=plan.reading
    )


def _within_three_standard_errors(estimate: BacklashEstimate, truth: float) -> None:
    assert estimate.resolved, estimate.describe()
    assert abs(estimate.width - truth) <= 3.0 * estimate.stderr, estimate.describe()


# --- a known play is recovered ------------------------------------------------------------


@pytest.mark.parametrize("noise", [False, True], ids=["quantised", "noise"])
def test_the_servo_play_of_one_degree_is_recovered(noise):
    estimate = _estimate(ROTARY, ONE_DEGREE, noise=noise)
    _within_three_standard_errors(estimate, ONE_DEGREE)
    assert estimate.width == pytest.approx(ONE_DEGREE, rel=0.02)
    assert estimate.value == estimate.width
    assert len(estimate.per_reversal) == ReversalPlan.for_device(ROTARY).reversals
    assert estimate.rms < estimate.rms_rigid  # the play explains what the rigid model cannot


def test_the_altino_play_is_recovered_through_the_ir_sensor():
    estimate = _estimate(ALTINO, ALTINO_PLAY)
    _within_three_standard_errors(estimate, ALTINO_PLAY)
    assert estimate.width == pytest.approx(ALTINO_PLAY, rel=0.05)
    # The legs reverse inside the band, where the sensor reads: every sample valid.
    trace = estimate.trace
    measured = trace.signal("measured")
    assert trace.signal("valid").all()
    assert 3.0 < measured.min()
    assert measured.max() < 15.0
    assert len(estimate.per_reversal) == ReversalPlan.for_device(ALTINO).reversals


def test_the_altino_play_is_recovered_under_sensor_noise():
    _within_three_standard_errors(_estimate(ALTINO, ALTINO_PLAY, noise=True), ALTINO_PLAY)


# --- no play: not resolved ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("env_id", "noise", "limit"),
    [
        (ROTARY, False, math.radians(0.5)),
        (ROTARY, True, math.radians(0.5)),
        (ALTINO, False, 0.1),
        (ALTINO, True, 0.15),
    ],
)
def test_without_a_play_the_test_reports_it_not_resolved_with_a_bound(env_id, noise, limit):
    estimate = _estimate(env_id, 0.0, noise=noise)
    assert not estimate.resolved
    assert estimate.value is None
    # The bound comes from the sensor's resolution: a play below it hides in one step.
    assert estimate.bound <= estimate.upper < limit
    assert "not resolved" in estimate.describe()
    assert "not measured" in estimate.describe()  # the shares are stated as assumptions


# --- the estimate depends on the assumed shares ------------------------------------------------


@pytest.mark.parametrize(
    ("env_id", "width", "wrong"),
    [(ROTARY, ONE_DEGREE, (0.6, 0.0)), (ALTINO, ALTINO_PLAY, (0.5, 0.5))],
)
def test_wrong_shares_give_a_clearly_wrong_play(env_id, width, wrong):
    """The load's sensor sees the play only through the motor's crossing: the shares matter.

    The preset's shares recover the play (the tests above); shares an estimator ignored would
    give the same width either way. Wrong shares move it by far more than the tolerances.
    """
    right = _estimate(env_id, width)
    off = _estimate(env_id, width, shares=wrong)
    assert (off.load_inertia, off.load_friction) == wrong
    assert "ReversalPlan.shares" in off.describe()
    assert abs(off.width / width - 1.0) > 0.2
    assert abs(off.width - right.width) > 5.0 * max(right.stderr, off.stderr)


# --- the file format -----------------------------------------------------------------------


def test_a_play_in_the_file_drives_the_simulated_plant(tmp_path):
    play = Backlash(0.01745, 0.8, 0.0)
    path = save_params(tmp_path, replace(_rigid(devices.ROTARY), backlash=play))
    data = json.loads(path.read_text())
    assert data["backlash"] == {"width": 0.01745, "load_inertia": 0.8, "load_friction": 0.0}
    assert load_params(path).backlash == play
    plant = gym.make(ROTARY, params=path).unwrapped.sim.plant
    assert (plant.backlash, plant.load_inertia, plant.load_friction) == (0.01745, 0.8, 0.0)
    assert gym.make(ROTARY, params=path, backlash=0.0).unwrapped.sim.plant.backlash == 0.0


def test_a_file_without_a_play_loads_as_before(tmp_path):
    path = save_params(tmp_path, _rigid(devices.ROTARY))
    assert "backlash" not in json.loads(path.read_text())
    assert load_params(path).backlash is None
    assert gym.make(ROTARY, params=path).unwrapped.sim.plant.backlash == 0.0


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (0.02, "'backlash' must be a JSON object"),
        ({"width": 0.02, "load_inertia": 0.8}, "'backlash' lacks load_friction"),
        ({"width": 0.02, "load_inertia": 0.8, "load_friction": 0, "psi": 1}, "unknown keys"),
        ({"width": -0.02, "load_inertia": 0.8, "load_friction": 0.0}, "'backlash.width'"),
        ({"width": "wide", "load_inertia": 0.8, "load_friction": 0.0}, "'backlash.width'"),
        ({"width": 0.02, "load_inertia": 1.0, "load_friction": 0.0}, "'backlash.load_inertia'"),
        ({"width": 0.02, "load_inertia": 0.8, "load_friction": 1.5}, "'backlash.load_friction'"),
    ],
)
def test_a_bad_play_in_the_file_is_refused_naming_the_field(tmp_path, value, message):
    data = _rigid(devices.ROTARY).to_dict()
    data["backlash"] = value
    path = tmp_path / "friction.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ParamsFileError, match=message):
        load_params(path)


def test_a_play_needs_a_law_with_the_exact_step():
    stribeck = devices.ROTARY.paper_friction.replace(shape="exponential")
    with pytest.raises(ParamsFileError, match="'backlash' needs a law with the event-exact"):
        DeviceParams.from_model(
            stribeck, inertia=0.007, damping=0.04, law="stribeck", backlash=Backlash(0.02, 0.8, 0)
        )


# --- identify and the command ------------------------------------------------------------


def test_identify_without_the_test_is_unchanged():
    result = identify(make_env(ROTARY), seed=0)
    assert result.backlash is None
    params = result.params()
    assert params.backlash is None
    assert "backlash" not in params.metadata
    assert "backlash" not in params.to_dict()


def test_the_command_writes_a_resolved_play_with_its_assumptions(tmp_path, capsys):
    """The whole procedure on the servo: the rigid model identified, then the play."""
    argv = ["--env", ROTARY, "--backlash", "--true-backlash", str(ONE_DEGREE), "--noise"]
    assert tool_main("identify", [*argv, "--out", str(tmp_path), "--quiet", "--no-figures"]) == 0
    data = json.loads((tmp_path / "friction.json").read_text())
    width = data["backlash"]["width"]
    assert data["uncertainty"]["backlash"] > 0.0
    # The identified rigid model's errors add a bias the standard error does not cover: 0.3 %
    # on u_s moves the estimate by 8 % (docs/identification.md), and the ramps leave u_s and
    # v_0 up to 0.3 % off; so 10 % here, not three standard errors.
    assert width == pytest.approx(ONE_DEGREE, rel=0.10)
    record = data["metadata"]["backlash"]
    assert record["assumed_shares"]["source"] == "the device preset's, not measured"
    assert data["metadata"]["env_kwargs"]["backlash"] == ONE_DEGREE
    summary = (tmp_path / "summary.md").read_text()
    assert "Reversal test: play W =" in summary
    assert "Simulated truth: W = 0.0174533" in summary
    assert gym.make(ROTARY, params=tmp_path).unwrapped.sim.plant.backlash == width


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--backlash", "--law", "coulomb"], "--backlash is estimated with the paper law"),
        (["--backend", "emulator://rotary", "--true-backlash", "0.01"], "simulator only"),
    ],
)
def test_the_command_refuses_what_the_test_cannot_do(tmp_path, capsys, extra, message):
    argv = ["--env", ROTARY, *extra, "--out", str(tmp_path / "o"), "--quiet"]
    assert tool_main("identify", argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_bad_reversal_plan_names_what_is_wrong():
    with pytest.raises(ValueError, match=r"level=0.9 must be > 1.*shares=\(1.0, 0.0\)"):
        replace(ReversalPlan.for_device(ROTARY), level=0.9, shares=(1.0, 0.0))
    # A coarser grid snapped every reversal's own fit to 0: a standard error of 0.
    with pytest.raises(ValueError, match=r"grid=3 must be an integer >= 11"):
        replace(ReversalPlan.for_device(ROTARY), grid=3)


def test_a_play_wider_than_the_search_says_so_and_a_wider_search_finds_it(tmp_path, capsys):
    argv = ["--env", ROTARY, "--backlash", "--true-backlash", "0.3", "--quiet", "--no-figures"]
    assert tool_main("identify", [*argv, "--out", str(tmp_path / "a")]) == 0
    summary = (tmp_path / "a" / "summary.md").read_text()
    assert "at least this wide, and biases the rigid parameters: raise --max-backlash" in summary
    assert "backlash" not in json.loads((tmp_path / "a" / "friction.json").read_text())
    wider = [*argv, "--max-backlash", "0.5", "--out", str(tmp_path / "b")]
    assert tool_main("identify", wider) == 0
    play = json.loads((tmp_path / "b" / "friction.json").read_text())["backlash"]
    assert play["width"] == pytest.approx(0.3, rel=0.05)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--backlash", "-1"], "--backlash must be >= 0"),
        (["--backlash", "nan"], "--backlash must be finite"),
        (["--backlash", "0.01", "--shares", "1.5,0"], "shares=(1.5, 0.0) must be"),
        (["--shares", "0.8,0.3"], "give --backlash too"),
        (["--backlash", "0.01", "--seeds", "x"], "--seeds takes integers"),
    ],
)
def test_validate_names_a_bad_option_in_one_line(capsys, argv, message):
    from frictiongym.identification.validate import main

    assert main(["--env", ROTARY, *argv]) == 2
    assert message in capsys.readouterr().err


def test_the_reversal_tests_come_from_the_device_descriptions():
    for device in (devices.ROTARY, devices.ALTINO):
        settings = device.identification["reversal"]
        assert ReversalPlan.for_device(device) == ReversalPlan(**settings)
    rigid_only = replace(
        devices.ROTARY,
        identification={k: v for k, v in devices.ROTARY.identification.items() if k != "reversal"},
    )
    assert Plan.for_device(rigid_only) == Plan.for_device(devices.ROTARY)  # entry ignored
    with pytest.raises(ValueError, match=r"has no reversal test.*'reversal' entry"):
        ReversalPlan.for_device(rigid_only)


@pytest.mark.slow
def test_the_altino_procedure_refines_its_rigid_model_with_the_play_held():
    """Its relay runs reverse, so a rigid refinement takes up part of the play's effect.

    Without the refit with the play, a 0.2 cm play came out 0.152 ± 0.018 cm (seed 0, noise
    on) and ``u_c-`` 3.6 % low; with it, both are within their noise (the issue's 3 % for
    ``u_c-``).
    """
    env = make_env(ALTINO, backlash=ALTINO_PLAY, sensor_noise=True)
    result = identify(env, seed=0, backlash=True)
    play = result.backlash
    assert play is not None
    assert len(play.earlier) == PLAY_ROUNDS
    assert play.refinement_width == pytest.approx(ALTINO_PLAY, rel=0.1)
    _within_three_standard_errors(play, ALTINO_PLAY)
    params = result.params()
    assert params.backlash is not None
    assert params.backlash.width == play.width
    assert params.friction.uc_neg == pytest.approx(devices.ALTINO.paper_friction.uc_neg, rel=0.03)
