"""The benchmark command: a --quick run's files, record schema and the paper phenomena."""

import csv
import json
import math

import gymnasium as gym
import pytest

from frictiongym.benchmark.command import OUTPUTS
from frictiongym.benchmark.scenarios import BACKLASH_WIDTHS, DEAD_ZONE_FRACTIONS, all_scenarios
from frictiongym.cli import main
from frictiongym.devices import DEVICES

REQUIRED = ("scenario", "env_id", "controller", "gains", "seed", "metrics")
METRICS = (
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
)
FIGURES = (
    "rotary_response.png",
    "altino_response.png",
    "compensator_mismatch.png",
    "friction_curves.png",
)


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    assert main(["benchmark", "--quick", "--quiet", "--out", str(out)]) == 0
    records = json.loads((out / "results.json").read_text())
    return out, records, {r["scenario"]: r["metrics"] for r in records}


def test_quick_run_writes_every_file(quick):
    out, records, _ = quick
    for name in ("results.json", "results.csv", "results.md", *FIGURES):
        assert (out / name).stat().st_size > 500, name
    assert not list(out.glob(".*"))  # no temporary file or staging folder left behind
    assert {p.name for p in out.iterdir()} <= set(OUTPUTS)  # --overwrite replaces them all
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["scenario"] for r in rows] == [r["scenario"] for r in records]
    table = (out / "results.md").read_text()
    assert "The paper's claims on our model" in table
    assert all(r["scenario"] in table for r in records)


def test_records_follow_the_schema(quick):
    _, records, _ = quick
    assert [r["scenario"] for r in records] == [s.name for s in all_scenarios(quick=True)]
    for r in records:
        assert set(REQUIRED) <= set(r)
        assert r["env_id"] in ("frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1")
        assert r["controller"] in ("pid", "compensated-pid")
        assert set(r["gains"]) == {"kp", "ki", "kd"}
        assert isinstance(r["seed"], int)
        assert set(METRICS) <= set(r["metrics"])
        for name, value in r["metrics"].items():
            assert value is None or (isinstance(value, float | int) and math.isfinite(value)), name
        assert (r["compensator"] is None) == (r["controller"] == "pid")


def test_the_paper_phenomena_our_model_reproduces(quick):
    _, _, m = quick
    # The paper's servo gains meet its four specs on the nominal model (§3.1).
    nominal = m["paper-rotary-nominal"]
    assert nominal["rise_time"] < 0.05
    assert nominal["peak_time"] < 0.1
    assert nominal["settling_time"] < 1.5
    assert nominal["overshoot_pct"] < 20.0
    # Friction leaves a steady-state error under PID; compensation reduces it (§5.1).
    pid, comp = m["paper-rotary-pid"], m["paper-rotary-compensated"]
    assert pid["steady_state_error_pct"] > 0.5
    assert comp["steady_state_error_pct"] < 0.7 * pid["steady_state_error_pct"]
    # Altino: Ki 10 stops short of the target (an offset held by stiction), Ki 20 overshoots
    # more, and the compensated PID ends closer to the target than either (§5.2).
    ki10, ki20 = m["paper-altino-pid-ki10"], m["paper-altino-pid-ki20"]
    altino_comp = m["paper-altino-compensated"]
    assert ki10["steady_state_error"] > 0.2
    assert ki20["overshoot_pct"] > 5.0 * ki10["overshoot_pct"]
    assert altino_comp["steady_state_error"] < min(
        ki10["steady_state_error"], ki20["steady_state_error"]
    )
    for name in ("paper-altino-compensated", "paper-rotary-compensated"):
        assert m[name]["limit_cycle_amplitude"] == 0.0
        assert m[name]["limit_cycle_period"] is None
    # An over-estimating compensator drives the Altino into a limit cycle; under-estimating
    # does not (docs/results.md).
    assert m["mismatch-altino-command-x1.5"]["limit_cycle_amplitude"] > 1.0
    assert m["mismatch-altino-command-x0.5"]["limit_cycle_amplitude"] == 0.0


def test_list_and_selection(capsys):
    assert main(["benchmark", "--list", "--group", "paper"]) == 0
    listed = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in listed] == [
        "paper-rotary-nominal",
        "paper-rotary-pid",
        "paper-rotary-compensated",
        "paper-altino-pid-ki10",
        "paper-altino-pid-ki20",
        "paper-altino-compensated",
    ]
    assert main(["benchmark", "--list", "--scenario", "noise-*-on", "--seeds", "3"]) == 0
    assert "(seeds 0..2)" in capsys.readouterr().out


def test_bad_input_is_reported(tmp_path, capsys):
    assert main(["benchmark", "--scenario", "no-such-*", "--out", str(tmp_path)]) == 2
    assert "no scenario matches" in capsys.readouterr().err
    target = tmp_path / "a-file"
    target.write_text("keep me")
    assert main(["benchmark", "--quick", "--out", str(target)]) == 2
    assert "not a directory" in capsys.readouterr().err
    assert target.read_text() == "keep me"
    assert main(["benchmark", "--seeds", "0", "--list"]) == 2


# --- residual policies (SB3 and torch imported inside the tests) -----------------------------


@pytest.fixture(scope="module")
def residual_model(tmp_path_factory):
    """A tiny PPO servo model, trained through ``frictiongym train``."""
    pytest.importorskip("stable_baselines3")
    path = tmp_path_factory.mktemp("train") / "run"
    status = main(
        [
            "train",
            "--n-envs",
            "1",
            "--env",
            "frictiongym/RotaryServo-v1",
            "--quick",
            "--steps",
            "512",
            "--out",
            str(path),
            "--quiet",
        ]
    )
    assert status == 0
    return path / "model.zip"


def test_a_residual_model_runs_next_to_the_compensated_pid(residual_model, tmp_path, capsys):
    args = [
        "benchmark",
        "--quick",
        "--no-figures",
        "--heldout",
        "3",
        "--out",
        str(tmp_path),
        "--residual",
        f"rotary={residual_model}",
    ]
    assert main([*args, "--list", "--group", "residual"]) == 0
    listed = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    assert listed == [
        f"residual-rotary-{plants}-{kind}"
        for plants in ("nominal", "heldout")
        for kind in ("compensated", "residual")
    ]
    assert main([*args, "--quiet"]) == 0
    records = json.loads((tmp_path / "results.json").read_text())
    assert "paper-rotary-compensated" in {r["scenario"] for r in records}  # the rest still runs
    mine = [r for r in records if r["group"] == "residual"]
    by = {(r["scenario"], r["seed"]): r for r in mine}
    assert len(mine) == 2 * (1 + 3)
    heldout = [r for r in mine if "heldout" in r["scenario"]]
    assert {r["seed"] for r in heldout} == {1000, 1001, 1002}  # disjoint from training's
    assert heldout[0]["env_kwargs"]["randomize"]["friction"] == [0.7, 1.3]
    for (name, seed), r in by.items():
        if name.endswith("-residual"):
            assert r["controller"] == "residual"
            assert r["residual"]["model"] == str(residual_model)
            assert by[name.replace("-residual", "-compensated"), seed]["controller"] == (
                "compensated-pid"
            )
            assert math.isfinite(r["metrics"]["itae"])
    # The same plants for both controllers: the compensated PID's runs do not depend on the
    # model, and the paired table is in results.md.
    text = (tmp_path / "results.md").read_text()
    assert "## Residual policy vs compensated PID" in text
    assert "| rotary | heldout | 3 |" in text
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    assert {r["controller"] for r in rows if r["group"] == "residual"} == {
        "compensated-pid",
        "residual",
    }


def test_residual_options_are_checked(residual_model, tmp_path, capsys):
    for bad, message in (
        ("rotary", "rotary=MODEL"),
        ("arm=x.zip", "rotary=MODEL"),
        (f"altino={residual_model}", "not for altino"),
        (f"rotary={tmp_path / 'none.zip'}", "no model at"),
    ):
        assert main(["benchmark", "--list", "--residual", bad]) == 2
        assert message in capsys.readouterr().err
    assert (
        main(
            [
                "benchmark",
                "--list",
                "--residual",
                f"rotary={residual_model}",
                "--heldout",
                "2",
                "--heldout-seed",
                "2000",
                "--scenario",
                "*heldout*",
            ]
        )
        == 0
    )
    assert "(seeds 2000..2001)" in capsys.readouterr().out
    assert main(["benchmark", "--list", "--group", "residual"]) == 2  # no model given
    assert "no scenario matches" in capsys.readouterr().err


def test_residual_runs_get_their_figures(residual_model, tmp_path):
    status = main(
        [
            "benchmark",
            "--group",
            "residual",
            "--heldout",
            "3",
            "--quiet",
            "--residual",
            f"rotary={residual_model}",
            "--out",
            str(tmp_path),
        ]
    )
    assert status == 0
    pngs = {p.name for p in tmp_path.glob("*.png")}
    assert {"residual_rotary_response.png", "residual_plants.png"} <= pngs
    assert pngs <= set(OUTPUTS)  # a rerun with --overwrite replaces them all
    assert "residual_altino_response.png" not in pngs  # no Altino model given
    assert "rotary_response.png" not in pngs  # the paper's group did not run


def test_the_drivetrain_group_puts_a_dead_zone_in_the_plant_and_models_it_or_not():
    drivetrain = [s for s in all_scenarios() if s.group == "drivetrain"]
    scenarios = [s for s in drivetrain if "deadzone" in s.env_kwargs]
    assert len(scenarios) == 3 * len(DEAD_ZONE_FRACTIONS) * len(DEVICES)
    for device in DEVICES:
        breakaway = max(device.paper_friction.breakaway)
        mine = [s for s in scenarios if s.env_id == device.env_id]
        widths = sorted({s.env_kwargs["deadzone"] for s in mine})
        assert widths == [f * breakaway for f in DEAD_ZONE_FRACTIONS]
        assert {s.mode for s in mine} == {None, "command"}
        for s in mine:  # the compensated-zone runs model the plant's zone, the others none
            modelled = s.env_kwargs["deadzone"] if s.name.endswith("-zone") else 0.0
            assert s.dead_zone == modelled
        env = gym.make(device.env_id, **mine[-1].env_kwargs)
        assert env.unwrapped.sim.plant.dead_zone == widths[-1]
        controller = mine[-1].controller(env)
        assert controller.dead_zone == widths[-1]
        assert controller.model == device.paper_friction


def test_the_drivetrain_group_puts_a_play_in_the_plant_for_pid_and_compensated_pid():
    plays = [s for s in all_scenarios() if "backlash" in s.env_kwargs]
    assert {s.group for s in plays} == {"drivetrain"}
    for device in DEVICES:
        mine = [s for s in plays if s.env_id == device.env_id]
        widths = [width for _, width in BACKLASH_WIDTHS[device.kind]]
        assert sorted({s.env_kwargs["backlash"] for s in mine}) == widths
        names = sorted(s.controller_name for s in mine)
        assert names == sorted(["pid", "compensated-pid"] * len(widths))
        env = gym.make(device.env_id, **mine[-1].env_kwargs)
        assert env.unwrapped.sim.plant.backlash == widths[-1]
