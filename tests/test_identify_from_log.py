"""``frictiongym identify --from-log``: the laws fitted to a friction map measured elsewhere.

Tolerances, fixed before the runs:

* a map of 28 points drawn from the preset's law with noise (1 mV on the servo, 1 unit on
  the Altino, a few per cent of the Coulomb levels' spread over the Stribeck drop) gives
  every friction value within **four of its own standard errors** of the truth (the
  standard errors are the joint fit's, break-away included); a wrong law or unit misses by
  tens of them;
* the servo's map measured by ``identify``'s own constant runs gives the same law as
  ``identify`` within **0.5 %** (the two differ only in where ``u_s`` comes from: the ramps
  there, the extrapolation here);
* a bad file gets a one-line error naming the line and the column, exit status 2, and
  ``--out`` is not created.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from frictiongym import devices
from frictiongym.cli import tool_main
from frictiongym.identification.from_log import LogFileError, identify_map, read_map
from frictiongym.identification.from_trace import identify_trace, read_trace
from frictiongym.identification.identify import identify, make_env

ROTARY = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"
FRICTION = ("us_pos", "us_neg", "uc_pos", "uc_neg", "v0_pos", "v0_neg")


def _write(path: Path, rows: list[tuple[object, ...]], header=("velocity", "force")) -> Path:
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)
    return path


def _synthetic(path: Path, device: devices.Device, top: float, noise: float) -> Path:
    """A map of the preset's law: 14 speeds per direction from 5 % of v0 to ``top``."""
    law = device.paper_friction
    rng = np.random.default_rng(0)
    v = np.concatenate(
        [np.geomspace(0.05 * law.v0_pos, top, 14), -np.geomspace(0.05 * law.v0_neg, top, 14)]
    )
    u = law.force(v) + device.plant.damping * v + rng.normal(0.0, noise, v.size)
    return _write(path, list(zip(v, u, strict=True)))


@pytest.mark.parametrize(
    ("device", "top", "noise"), [(devices.ROTARY, 25.0, 1e-3), (devices.ALTINO, 20.0, 1.0)]
)
def test_a_map_of_the_law_gives_it_back_within_its_errors(tmp_path, device, top, noise):
    path = _synthetic(tmp_path / "map.csv", device, top, noise)
    params = identify_map(read_map(path, device), device).params("paper")
    law = device.paper_friction
    for key in FRICTION:
        error = getattr(params.friction, key) - getattr(law, key)
        assert abs(error) <= 4.0 * params.uncertainty[key], key
    b = device.plant.damping + law.viscous
    assert abs(params.damping - b) <= 4.0 * params.uncertainty["B"]
    assert params.inertia == device.plant.inertia  # not identified: the preset's
    assert "J" not in params.uncertainty


def test_the_servo_s_own_map_gives_identify_s_law(tmp_path):
    result = identify(make_env(ROTARY, sensor_noise=True), seed=0)
    rows = [(p.sign * p.velocity if p.moved else 0.0, p.sign * p.level) for p in result.points]
    path = _write(tmp_path / "map.csv", rows)
    from_map = identify_map(read_map(path, devices.ROTARY), devices.ROTARY).params("paper")
    for key in FRICTION:
        expected = getattr(result.params("paper").friction, key)
        assert getattr(from_map.friction, key) == pytest.approx(expected, rel=0.005), key


def test_the_command_writes_the_file_and_says_what_it_could_not_identify(tmp_path):
    path = _synthetic(tmp_path / "map.csv", devices.ROTARY, 25.0, 1e-3)
    # The same map in degrees per second and millivolts.
    scaled = [(float(v) * 180.0 / np.pi, float(u) * 1e3) for v, u in _rows(path)]
    other = _write(tmp_path / "deg.csv", scaled, header=("speed_deg", "cmd_mV"))
    out = tmp_path / "out"
    argv = ["--env", ROTARY, "--from-log", str(other), "--velocity-column", "speed_deg"]
    argv += ["--force-column", "cmd_mV", "--velocity-unit", "deg/s", "--force-unit", "mV"]
    argv += ["--inertia", "0.0071", "--out", str(out), "--quiet", "--no-figures"]
    assert tool_main("identify", argv) == 0
    data = json.loads((out / "friction.json").read_text())
    direct = identify_map(read_map(path, devices.ROTARY), devices.ROTARY).params("paper")
    for key in FRICTION:
        assert data[key] == pytest.approx(getattr(direct.friction, key), rel=1e-6), key
    assert data["J"] == 0.0071
    assert "given with --inertia" in data["metadata"]["source"]["not_identified"]["J"]
    summary = (out / "summary.md").read_text()
    assert "Not identified: us_pos, us_neg: a map holds no start from rest" in summary


def _rows(path: Path) -> list[tuple[float, float]]:
    with open(path) as handle:
        return [(float(v), float(u)) for v, u in list(csv.reader(handle))[1:]]


@pytest.mark.parametrize(
    ("content", "extra", "message"),
    [
        ("speed,force\n1,0.2\n", [], "its columns (force, speed) are neither a map's"),
        ("velocity,force\n1,0.2\n2,abc\n", [], "line 3, column 'force': 'abc' is not a number"),
        ("velocity,force\n1,0.2\nnan,0.3\n", [], "line 3, column 'velocity': 'nan' is not finite"),
        ("velocity,force\n1,0.2\n2,0.3,4\n", [], "line 3 has 3 fields, the header 2"),
        ("velocity,force\n1,-0.2\n", [], "line 2: the force -0.2 opposes the velocity 1"),
        ("velocity,force\n1,0.2\n2,0.3\n-1,-0.2\n", [], "2 moving points of positive speed"),
        ("velocity,force\n", [], "the header names the columns but no row follows"),
        ("", [], "empty; the first line must name the columns"),
        ("velocity,force\n1,0.2\n", ["--velocity-unit", "cm/s"], "velocity unit 'cm/s'"),
        ("velocity,force\n1,0.2\n", ["--backlash"], "drop --backlash"),
        ("velocity,force\n1,0.2\n", ["--inertia", "-1"], "--inertia must be > 0"),
    ],
)
def test_a_bad_file_or_option_gets_one_line_naming_it(tmp_path, capsys, content, extra, message):
    path = tmp_path / "map.csv"
    path.write_text(content)
    argv = ["--env", ROTARY, "--from-log", str(path), *extra, "--out", str(tmp_path / "o")]
    assert tool_main("identify", [*argv, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(LogFileError, match=r"nowhere\.csv: cannot read it"):
        read_map(tmp_path / "nowhere.csv", devices.ROTARY)


def test_inertia_without_a_log_is_refused(tmp_path, capsys):
    argv = ["--env", ROTARY, "--inertia", "0.007", "--out", str(tmp_path / "o"), "--quiet"]
    assert tool_main("identify", argv) == 2
    assert "--inertia applies to --from-log" in capsys.readouterr().err


# --- a log of time, command and position ----------------------------------------------------


def _log(path: Path, *options: str) -> Path:
    """A log of the simulated servo with its encoder noise, by ``scripts/simulated_log.py``."""
    script = Path(__file__).resolve().parents[1] / "scripts" / "simulated_log.py"
    done = subprocess.run(
        [sys.executable, str(script), str(path), "--noise", *options],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return path


def test_a_log_gives_back_the_law_j_and_b(tmp_path):
    """Four holds per direction from rest, with noise: every value within 1 %."""
    path = _log(tmp_path / "log.csv")
    out = tmp_path / "out"
    argv = ["--env", ROTARY, "--from-log", str(path), "--out", str(out), "--quiet"]
    assert tool_main("identify", [*argv, "--no-figures"]) == 0
    data = json.loads((out / "friction.json").read_text())
    law = devices.ROTARY.paper_friction
    for key in FRICTION:
        assert data[key] == pytest.approx(getattr(law, key), rel=0.01), key
    assert data["J"] == pytest.approx(devices.ROTARY.plant.inertia, rel=0.01)
    assert data["B"] == pytest.approx(devices.ROTARY.plant.damping, rel=0.01)
    source = data["metadata"]["source"]
    assert source["starts_from_rest"] == {"forward": 4, "backward": 4}
    assert source["not_identified"] == {}


def test_a_log_without_a_start_from_rest_names_the_break_away_unidentified(tmp_path):
    path = _log(tmp_path / "log.csv", "--no-rest")  # it reverses, never rests
    runs, dt = read_trace(path, devices.ROTARY)
    result = identify_trace(runs, devices.ROTARY, dt)
    assert set(result.source["not_identified"]) == {"us_pos", "us_neg"}
    assert "no start from rest forward" in result.source["not_identified"]["us_pos"]
    params = result.params("paper")
    assert "us_pos" not in params.uncertainty
    assert "us_neg" not in params.uncertainty
    assert "uc_pos" in params.uncertainty


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ([(0.0, 0.1, 0.0), (0.002, 0.1, 0.0), (0.001, 0.1, 0.0)], "line 4, column 'time'"),
        ([(k * 0.002, 0.1, 0.0) for k in range(5)] + [(0.013, 0.1, 0.0)], "line 7: the sampling"),
        ([(0.0, 0.1, 0.0), (0.002, 0.1, "nan")], "line 3, column 'position': 'nan' is not finite"),
    ],
)
def test_a_bad_log_names_the_line(tmp_path, capsys, rows, message):
    path = _write(tmp_path / "log.csv", rows, header=("time", "command", "position"))
    argv = ["--env", ROTARY, "--from-log", str(path), "--out", str(tmp_path / "o"), "--quiet"]
    assert tool_main("identify", argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_file_that_is_neither_a_map_nor_a_log_says_which_columns_it_wants(tmp_path, capsys):
    path = _write(tmp_path / "x.csv", [(1, 2)], header=("a", "b"))
    argv = ["--env", ROTARY, "--from-log", str(path), "--out", str(tmp_path / "o"), "--quiet"]
    assert tool_main("identify", argv) == 2
    assert "are neither a map's ('velocity', 'force') nor a log's" in capsys.readouterr().err


def test_a_run_log_is_read_by_its_own_columns_one_run_per_episode(tmp_path):
    from frictiongym.hardware.runlog import RESULT_COLUMNS, STEP_COLUMNS

    header = (*STEP_COLUMNS, "obs_angle", "obs_velocity", "obs_reference", *RESULT_COLUMNS)
    rows = []
    for episode in (0, 1):
        for k in range(50):
            values = dict.fromkeys(header, 0.0)
            values.update(episode=episode, time=k * 0.002, applied=0.3 * (episode + 1))
            values["measured"] = 0.01 * k * (episode + 1)
            values["requested"] = 9.9  # not the applied command: must not be read
            rows.append(tuple(values[name] for name in header))
    path = _write(tmp_path / "steps.csv", rows, header=header)
    runs, dt = read_trace(path, devices.ROTARY)
    assert dt == pytest.approx(0.002)
    assert [run.signal("command")[0] for run in runs] == [0.3, 0.6]
    assert runs[1].plant_output()[10] == pytest.approx(0.2)
    assert runs[1].t[0] == 0.0


def test_line_numbers_count_blank_lines_and_episodes_restart_their_time(tmp_path):
    # A blank line before the bad row: the message names the file's line, not the row's.
    path = tmp_path / "map.csv"
    path.write_text("velocity,force\n1,0.2\n\n2,-0.3\n")
    with pytest.raises(LogFileError, match=r"line 4: the force -0\.3 opposes"):
        read_map(path, devices.ROTARY)
    # Each episode's time starts again; the uneven interval is in the second one, line 9.
    rows = [(e, k * 0.002, 0.1, 0.0) for e in (0, 1) for k in range(4)]
    rows[7] = (1, 0.0075, 0.1, 0.0)
    log = _write(tmp_path / "log.csv", rows, header=("episode", "time", "command", "position"))
    with pytest.raises(LogFileError, match=r"line 9: the sampling interval 0\.0035"):
        read_trace(log, devices.ROTARY)
    # A one-sample episode holds no motion and is left out; a missing file is named.
    rows = [(0, 0.0, 0.1, 0.0), *[(1, k * 0.002, 0.1, 0.0) for k in range(4)]]
    log = _write(tmp_path / "one.csv", rows, header=("episode", "time", "command", "position"))
    runs, dt = read_trace(log, devices.ROTARY)
    assert (len(runs), dt) == (1, pytest.approx(0.002))
    with pytest.raises(LogFileError, match=r"nowhere\.csv: cannot read it"):
        read_trace(tmp_path / "nowhere.csv", devices.ROTARY)


# --- the Altino: an IR sensor that reads only near the wall ----------------------------------


def test_an_altino_log_gives_back_the_law_j_and_b(tmp_path):
    """A relay controller's log across 6-16 cm, IR noise on: identify's own 3 % tolerance."""
    path = _log(tmp_path / "log.csv", "--device", "altino")
    runs, dt = read_trace(path, devices.ALTINO)
    result = identify_trace(runs, devices.ALTINO, dt)
    params = result.params("paper")
    law = devices.ALTINO.paper_friction
    for key in (*FRICTION, "viscous"):
        assert getattr(params.friction, key) == pytest.approx(getattr(law, key), rel=0.03), key
    assert params.inertia == pytest.approx(devices.ALTINO.plant.inertia, rel=0.03)
    assert result.source["starts_from_rest"]["forward"] >= 5  # the five rests


def test_an_altino_log_s_out_of_range_samples_are_masked(tmp_path):
    rows = [(k * 0.05, 0.0, 21.4666667) for k in range(20)]  # the readout's 0: out of range
    rows += [(1.0 + k * 0.05, 0.0, 12.0 + 0.01 * (k % 2)) for k in range(20)]
    path = _write(tmp_path / "log.csv", rows, header=("time", "command", "position"))
    runs, _ = read_trace(path, devices.ALTINO)
    valid = runs[0].signal("valid")
    assert not valid[:20].any()
    assert valid[20:].all()


def test_an_altino_run_log_reads_the_readout_as_a_distance(tmp_path):
    from frictiongym.hardware.runlog import RESULT_COLUMNS, STEP_COLUMNS

    names = devices.ALTINO.observation_names
    header = (*STEP_COLUMNS, *(f"obs_{n}" for n in names), *RESULT_COLUMNS)
    rows = []
    for k, readout in enumerate((0.0, 0.0, 100.0, 120.0, 800.0, 140.0)):
        values = dict.fromkeys(header, 0.0)
        values.update(episode=0, time=k * 0.05, applied=250.0, measured=readout)
        rows.append(tuple(values[name] for name in header))
    runs, _ = read_trace(_write(tmp_path / "steps.csv", rows, header=header), devices.ALTINO)
    assert runs[0].signal("valid").tolist() == [False, False, True, True, False, True]
    assert runs[0].signal("measured")[2] == pytest.approx(966.0 / 145.0)  # Eq. (1), cm


@pytest.fixture(scope="module")
def planless_stage_fit(tmp_path_factory):
    """``identify --from-log`` on the ball-screw example without its identification plan.

    One fit for the two tests below (each fit takes about 20 s): the plan is for experiments,
    so a log needs only the device (docs/devices.md), and the law comes back the same.
    """
    from frictiongym import device_file

    tmp_path = tmp_path_factory.mktemp("planless")
    stage = (
        Path(__file__).resolve().parents[1] / "examples" / "ball_screw" / "ball_screw_stage.toml"
    )
    table = device_file.toml_loads(stage.read_text())
    del table["identification"]
    table.update(name="PlanlessStage", kind="planless")
    path = tmp_path / "planless.toml"
    path.write_text(device_file.render_toml(table))
    log = _log(tmp_path / "log.csv", "--device", str(path))
    out = tmp_path / "out"
    argv = ["--device", str(path), "--from-log", str(log), "--out", str(out), "--quiet"]
    status = tool_main("identify", [*argv, "--no-figures"])
    return status, out, devices.load(path)


def test_a_described_device_s_log_gives_back_its_law(planless_stage_fit):
    """The ball-screw example, in mm and V: its map's extrapolation to rest overshoots (one point
    per direction inside the drop), so the starts from rest bound break-away: within 1 %."""
    status, out, device = planless_stage_fit
    assert status == 0
    data = json.loads((out / "friction.json").read_text())
    for key in (*FRICTION, "viscous"):
        expected = getattr(device.paper_friction, key) or device.plant.damping
        assert data[key] == pytest.approx(expected, rel=0.01), key
    assert data["J"] == pytest.approx(device.plant.inertia, rel=0.01)


def test_a_device_without_an_identification_plan_fits_its_log(planless_stage_fit):
    """The plan is for experiments; a log needs only the device (docs/devices.md)."""
    status, out, device = planless_stage_fit
    assert not device.identification  # no plan, no reversal test: the file has none
    assert status == 0
    data = json.loads((out / "friction.json").read_text())
    assert data["device"] == "PlanlessStage"
    assert data["us_pos"] == pytest.approx(0.33, rel=0.01)
