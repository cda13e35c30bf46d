"""Device description files: the built-in devices are files, any rig is one, bad files are named.

The oracle of "loaded through the same code" is the built-in devices' description before the
files existed, recorded field by field with types (tests/data/builtin_devices.txt, written at
b1da488 by the repr below): each field of the loaded device must print the same.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import frictiongym.envs as envs
from frictiongym import device_file, devices
from frictiongym.data import device_path
from frictiongym.devices import ALTINO, DEVICES, ROTARY, DeviceFileError
from frictiongym.envs.axis import AxisEnv

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "ball_screw" / "ball_screw_stage.toml"
RECORD = Path(__file__).parent / "data" / "builtin_devices.txt"


def variant(tmp_path: Path, name: str, **changes: object) -> Path:
    """A copy of the example with ``changes``, as another device ``name`` (its own kind)."""
    table = {**device_file.toml_loads(EXAMPLE.read_text()), **changes}
    table.update(name=name, kind=name.lower())
    path = tmp_path / f"{name}.toml"
    path.write_text(device_file.render_toml(table))
    return path


def typed(value: object) -> str:
    """A value's repr with the type of every leaf (1 and 1.0 differ)."""
    if isinstance(value, dict):
        return "{" + ",".join(f"{k!r}:{typed(x)}" for k, x in value.items()) + "}"
    if isinstance(value, tuple | list):
        return type(value).__name__ + "(" + ",".join(typed(x) for x in value) + ")"
    return f"{type(value).__name__}:{value!r}"


def test_the_built_in_devices_are_their_files_field_for_field():
    lines = [
        f"{d.name}.{f.name}={typed(getattr(d, f.name))}"
        for d in (ROTARY, ALTINO)
        for f in dataclasses.fields(d)
        if f.name not in ("source", "tuning")  # fields the files brought
    ]
    assert lines == RECORD.read_text().splitlines()
    assert ROTARY.source == str(device_path("rotary"))


@pytest.mark.parametrize("device", DEVICES, ids=lambda d: d.kind)
def test_a_written_description_reads_back_as_the_same_device(device, tmp_path):
    path = tmp_path / "copy.toml"
    path.write_text(device_file.dump(device))
    copy = devices.Device(**device_file.read(path))
    assert dataclasses.replace(copy, source="") == dataclasses.replace(device, source="")


def test_a_json_description_reads_as_the_toml_one(tmp_path):
    table = device_file.toml_loads(EXAMPLE.read_text())
    path = tmp_path / "stage.json"
    path.write_text(json.dumps(table))
    from_json = devices.Device(**device_file.read(path))
    from_toml = devices.Device(**device_file.read(EXAMPLE))
    assert dataclasses.replace(from_json, source="") == dataclasses.replace(from_toml, source="")


def test_the_example_makes_single_and_vector_envs_of_its_units():
    env = gym.make("frictiongym/Axis-v0", device=str(EXAMPLE))
    assert isinstance(env.unwrapped, AxisEnv)
    assert env.action_space.high[0] == 24.0
    obs, _ = env.reset(seed=3)
    assert obs.tolist() == [0.0, 0.0, 10.0]  # at rest at 0 mm, the 10 mm step
    steps = 0
    while True:
        obs, _reward, terminated, truncated, info = env.step(np.array([1.0], np.float32))
        steps += 1
        if terminated or truncated:
            break
    assert (steps, terminated, truncated) == (3000, False, True)  # the file's episode_steps
    assert obs[0] / 0.0025 == pytest.approx(round(obs[0] / 0.0025))  # counts of 5 mm / 2000
    assert info["position"] > 20.0  # 1 V is three times break-away: it slides
    vec = envs.make_vec(str(EXAMPLE), num_envs=4)
    assert vec.unwrapped.max_episode_steps == 3000
    first, _ = vec.reset(seed=3)
    np.testing.assert_array_equal(first[0], [0.0, 0.0, 10.0])
    env.close()
    vec.close()


def test_the_vector_env_steps_as_the_single_env():
    single = envs.make(str(EXAMPLE), sensor_noise=True)
    vec = envs.make_vec(str(EXAMPLE), num_envs=2, sensor_noise=True)
    s_obs, _ = single.reset(seed=5)
    v_obs, _ = vec.reset(seed=5)
    for u in (0.2, 0.5, -1.0, 0.0, 2.0):
        s_obs, s_r, *_ = single.step(np.array([u], np.float32))
        v_obs, v_r, *_ = vec.step(np.full((2, 1), u, np.float32))
        np.testing.assert_array_equal(v_obs[0], s_obs)
        assert v_r[0] == s_r


def test_identify_takes_the_description_file_and_writes_its_device(tmp_path):
    from frictiongym.cli import main

    assert main(["identify", "--device", str(EXAMPLE), "--out", str(tmp_path), "--quiet"]) == 0
    written = json.loads((tmp_path / "friction.json").read_text())
    assert (written["device"], written["env_id"]) == ("BallScrewStage", envs.AXIS_ID)
    assert written["units"] == {
        "force": "V",
        "velocity": "mm/s",
        "viscous": "V·s/mm",
        "J": "V·s²/mm",
        "B": "V·s/mm",
    }
    truth = devices.load(EXAMPLE)
    law = written
    for name in ("us_pos", "us_neg", "uc_pos", "uc_neg"):
        assert law[name] == pytest.approx(getattr(truth.paper_friction, name), rel=0.01)
    assert written["J"] == pytest.approx(truth.plant.inertia, rel=0.01)
    env = envs.make(str(EXAMPLE), params=str(tmp_path / "friction.json"))
    assert env.unwrapped.sim.plant.inertia == written["J"]
    env.close()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"dt": -0.001}, r"stage\.toml: dt: = -0\.001 \(control period, s\): must be > 0"),
        (
            {"plant": {"inertia": 0.0, "damping": 0.1, "command_limit": 24.0}},
            r"plant\.inertia: must be > 0, got 0\.0 \(V·s²/mm\)",
        ),
        ({"sensor": "laser"}, r"sensor: = 'laser': must be one of encoder, ir"),
        ({"counts_per_rev": 0}, r"counts_per_rev: must be 1\.\.65535 with sensor = 'encoder'"),
        ({"limit": "far"}, r"limit: = 'far' \(safety limit.*mm\): must be a number"),
        ({"bogus": 1}, r"unknown field\(s\) bogus"),
        ({"friction": {"us_pos": 0.3}}, r"friction\.us_neg: missing: give it \(V\)"),
        ({"output": "angle"}, r"output: must name the measured output, one of \['position'\]"),
        (
            {"gains": {"pid": {"kp": 1.0, "ki": -1.0, "kd": 0.0}}},
            r"gains\.pid\.ki: = -1\.0: must be a number",
        ),
        ({"references": {"sine": {"amplitude": 1.0, "period": 1.0}}}, r"references\.step: missing"),
        ({"drawing": "draw_robot"}, r"drawing: = 'draw_robot'"),
        ({"name": "Rotary Servo"}, r"name: = 'Rotary Servo'.*letters, digits and _"),
    ],
)
def test_a_bad_field_is_named_with_its_unit_and_range(tmp_path, change, message):
    table = {**device_file.toml_loads(EXAMPLE.read_text()), **change}
    path = tmp_path / "stage.toml"
    path.write_text(device_file.render_toml(table))
    with pytest.raises(DeviceFileError, match=message):
        devices.load(path)


def test_a_missing_field_is_named_with_its_unit(tmp_path):
    table = device_file.toml_loads(EXAMPLE.read_text())
    del table["dt"]
    path = tmp_path / "stage.toml"
    path.write_text(device_file.render_toml(table))
    with pytest.raises(
        DeviceFileError, match=r"stage\.toml: dt: missing: give dt \(control period, s\)"
    ):
        devices.load(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("name = ", r"not valid TOML"),
        ("", r"name: missing"),
    ],
)
def test_a_file_that_is_not_a_description_says_so(tmp_path, text, message):
    path = tmp_path / "stage.toml"
    path.write_text(text)
    with pytest.raises(DeviceFileError, match=message):
        devices.load(path)


def test_a_missing_file_and_a_bad_reference_are_named(tmp_path):
    with pytest.raises(DeviceFileError, match=r"cannot read device file .*nowhere\.toml"):
        envs.make(str(tmp_path / "nowhere.toml"))
    references = device_file.toml_loads(EXAMPLE.read_text())["references"]
    references["sine"] = {"amplitude": 1.0, "period": -2.0}
    path = variant(tmp_path, "BadSine", references=references)
    with pytest.raises(DeviceFileError, match=r"BadSine\.toml: references\.sine: .*period"):
        gym.make("frictiongym/Axis-v0", device=str(path))


def test_a_file_cannot_take_a_built_in_device_s_name(tmp_path):
    table = {**device_file.toml_loads(EXAMPLE.read_text()), "kind": "rotary"}
    path = tmp_path / "stage.toml"
    path.write_text(device_file.render_toml(table))
    with pytest.raises(DeviceFileError, match="a built-in device's"):
        devices.load(path)
    assert devices.load(device_path("rotary")) is ROTARY
    copy = tmp_path / "rotary.toml"  # an unchanged copy of a built-in file is that device
    copy.write_text(device_path("rotary").read_text())
    assert devices.load(copy) is ROTARY


def test_axis_needs_a_device():
    with pytest.raises(TypeError, match="needs device="):
        gym.make("frictiongym/Axis-v0")


def test_the_lugre_law_is_built_from_the_friction_when_the_file_gives_none():
    stage = devices.load(EXAMPLE)
    law, lugre = stage.paper_friction, stage.lugre_friction
    assert (lugre.us_pos, lugre.uc_neg) == (law.us_pos, law.uc_neg)
    # within 1 % of u_c at v0, as the presets
    assert math.exp(-((law.v0_pos / lugre.vs_pos) ** 2)) == pytest.approx(0.01)
    assert lugre.sigma1 == pytest.approx(2.0 * math.sqrt(lugre.sigma0 * stage.plant.inertia))
    env = envs.make(str(EXAMPLE), friction="lugre")
    env.reset(seed=0)
    env.step(np.array([0.5], np.float32))
    env.close()


def test_tune_takes_the_device_s_plant_step_and_pid_and_the_specs_given(tmp_path):
    from frictiongym.cli import main

    out = tmp_path / "tune"
    args = ["tune", "--device", str(EXAMPLE), "--samples", "2000", "--out", str(out)]
    assert main([*args, "--settling-time", "0.5", "--kd", "0.0", "0.25", "--quiet"]) == 0
    record = json.loads((out / "tune.json").read_text())
    assert record["reference_step"] == 10.0  # mm: the file's demo step
    assert record["model"]["device"] == "BallScrewStage"
    assert record["dt"] == 0.001
    assert record["paper_gains"]["kp"] == 4.8  # the file's PID, evaluated beside
    assert record["specs"]["settling_time"] == 0.5  # the option's, over the file's 0.2 s
    assert record["specs"]["overshoot_pct"] == 5.0  # the file's
    assert record["bounds"] == {"kp": [0.0, 30.0], "ki": [0.0, 100.0], "kd": [0.0, 0.25]}
    assert record["n_feasible"] > 0
    for candidate in record["feasible"]:
        assert candidate["settling_time"] < 0.5


def test_tune_refuses_a_device_it_cannot_step_and_names_a_missing_bound(tmp_path, capsys):
    from frictiongym.cli import main

    assert main(["tune", "--device", "altino", "--out", str(tmp_path / "a")]) == 2
    assert "encoder device" in capsys.readouterr().err
    table = device_file.toml_loads(EXAMPLE.read_text())
    table["gains"]["pid"]["ki"] = 0.0
    del table["tuning"]  # without bounds, tune takes 0 to 5 times the PID's gains
    table.update(name="NoKi", kind="noki")
    path = tmp_path / "stage.toml"
    path.write_text(device_file.render_toml(table))
    assert main(["tune", "--device", str(path), "--out", str(tmp_path / "b")]) == 2
    assert "give its bounds (--ki LOW HIGH" in capsys.readouterr().err


def test_the_example_draws_its_carriage_where_it_is():
    env = envs.make(str(EXAMPLE), render_mode="rgb_array")
    env.reset(seed=0, options={"position": -100.0})
    left = env.render()
    env.reset(seed=0, options={"position": 100.0})
    right = env.render()
    env.close()
    carriage = np.array([196, 78, 82])  # STUCK: at rest after a reset, it holds

    def columns(frame: np.ndarray) -> np.ndarray:
        return np.flatnonzero((frame == carriage).all(axis=2).any(axis=0))

    columns_left, columns_right = columns(left), columns(right)
    assert columns_left.mean() < 200 < 400 < columns_right.mean()  # ±100 of ±140 mm


def test_device_show_writes_a_file_that_check_reads(tmp_path, capsys):
    from frictiongym.cli import main

    assert main(["device", "show", "rotary", "--name", "MyServo"]) == 0
    text = capsys.readouterr().out
    path = tmp_path / "copy.toml"
    path.write_text(text)
    assert main(["device", "check", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("MyServo (myservo): a QUBE-Servo 2, frictiongym/Axis-v0")
    assert "encoder, 2048 counts per 6.28319 rad" in out
    path.write_text(text.replace("dt = 0.002", 'dt = "fast"'))
    assert main(["device", "check", str(path)]) == 2
    assert "dt: = 'fast' (control period, s): must be a number" in capsys.readouterr().err


def test_the_table_keys_are_the_fields_of_the_classes_that_read_them():
    from frictiongym.controllers.residual_core import ResidualConfig
    from frictiongym.identification.backlash import ReversalPlan
    from frictiongym.identification.identify import Plan
    from frictiongym.plants.randomization import DomainRandomization
    from frictiongym.tuning.specs import GainBounds, StepSpecs

    def names(*classes: type) -> set[str]:
        return {f.name for cls in classes for f in dataclasses.fields(cls)}

    from frictiongym.device_tables import TABLE_RULES

    keys = {k: set(v) for k, v in TABLE_RULES.items()}
    assert keys["identification"] == names(Plan) | {"reversal"}
    assert keys["identification.reversal"] == names(ReversalPlan)
    assert keys["residual"] == names(ResidualConfig) - {"device", "limit"}
    assert set(device_file.RANDOMIZATION_KEYS) == names(DomainRandomization)
    assert keys["tuning"] == names(StepSpecs, GainBounds)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"identification": {"levels": [1.1], "bogus": 1}}, r"identification\.bogus: unknown"),
        ({"identification": {"reversal": {"hold": "long"}}}, r"identification\.reversal\.hold"),
        ({"residual": {"scale": float("nan")}}, r"residual\.scale: = nan"),
        ({"randomization": {"friction": [1.3, 0.7]}}, r"randomization\.friction: .*low <= high"),
        ({"randomization": {"mass": [0.9, 1.1]}}, r"randomization\.mass: unknown"),
        ({"tuning": {"overshoot": 5}}, r"tuning\.overshoot: unknown; \[tuning\] takes"),
    ],
)
def test_a_bad_entry_of_a_tool_s_table_is_named(tmp_path, table, message):
    data = device_file.toml_loads(EXAMPLE.read_text())
    for key, entries in table.items():  # into the example's own tables
        merged = {**data.get(key, {}), **entries}
        if "reversal" in entries:
            merged["reversal"] = {**data[key]["reversal"], **entries["reversal"]}
        data[key] = merged if key != "randomization" else entries
    path = tmp_path / "stage.toml"
    path.write_text(device_file.render_toml(data))
    with pytest.raises(DeviceFileError, match=message):
        devices.load(path)


def test_the_docs_list_every_field_and_table():
    text = (REPO / "docs" / "devices.md").read_text()
    for key in device_file.SCALARS:
        assert f"`{key}`" in text, key
    for table in ("plant", "friction", "lugre", "figures", *device_file.MAPPINGS):
        assert f"[{table}" in text, table


# --- what an independent attack found (each a file a stranger could write) -------------------


def _residual() -> dict[str, object]:
    return dict(device_file.toml_loads(EXAMPLE.read_text())["residual"])


def _plant(**changes: object) -> dict[str, object]:
    return {**device_file.toml_loads(EXAMPLE.read_text())["plant"], **changes}


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"env_id": "frictiongym/RotaryServo-v1"}, r"env_id: .*is frictiongym/Axis-v0; omit"),
        ({"plant": _plant(dead_time=0.0015)}, r"plant\.dead_time: = 0\.0015: must be a whole"),
        ({"plant": _plant(jitter=0.001)}, r"plant\.jitter: = 0\.001: must be below"),
        ({"limit": -5.0}, r"limit: = -5\.0: the safety limit ±limit must hold the start"),
        ({"start": 1e6}, r"limit: .*must hold the start 1000000\.0"),
        ({"end_stop": -5.0}, r"end_stop: = -5\.0: the end stop must lie ahead of the start"),
        ({"dt": 1e300}, r"dt: = 1e\+300 .*at most 10 s"),
        ({"position_unit": "deg", "drawing": "draw_servo"}, r"draw_servo draws a disk, in rad"),
        ({"references": {"step": {}}}, r"references\.step\.value: = None: must be a nonzero"),
        ({"references": {"step": 5}}, r"references\.step: = 5: must be a table"),
        ({"references": {"step": {"value": "ten"}}}, r"references\.step\.value: = 'ten'"),
        ({"references": {"step": {"value": 0.0}}}, r"references\.step\.value: = 0\.0"),
        ({"figures": 5}, r"figures: = 5: must be a table"),
        ({"figures": {"response": 5}}, r"figures\.response: = 5: must be a title"),
        ({"observation_names": "abc"}, r"observation_names: = 'abc': must be an array of 3"),
        ({"observation_names": ["x", "x", "r"], "output": "x"}, r"3 distinct names"),
        ({"gains": {"pid": {"kp": True, "ki": 1.0, "kd": 0.0}}}, r"gains\.pid\.kp: = True"),
        ({"tuning": {"kp": 5.0}}, r"tuning\.kp: = 5\.0: must be \[low, high\]"),
        ({"residual": {**_residual(), "scale": -1.0}}, r"residual\.scale: = -1\.0: must be a"),
        ({"residual": {"scale": 1.0}}, r"residual\.error_scale: missing: \[residual\] needs"),
        ({"identification": {"levels": []}}, r"identification\.constant_duration: missing"),
        ({"command_scale": 10_000}, r"stage\.toml: BallScrewStage: .*= 240000 counts.*lower"),
        ({"plant": _plant(inertia=1e308)}, r"lugre: built from \[friction\] and \[plant\]"),
    ],
)
def test_a_stranger_s_bad_file_gets_one_line(tmp_path, changes, message):
    path = tmp_path / "stage.toml"
    path.write_text(
        device_file.render_toml({**device_file.toml_loads(EXAMPLE.read_text()), **changes})
    )
    with pytest.raises(DeviceFileError, match=message):
        devices.load(path)


def test_a_file_that_is_not_utf8_or_repeats_a_key_is_named(tmp_path):
    path = tmp_path / "stage.toml"
    path.write_bytes(EXAMPLE.read_bytes() + b"\n# \xff\n")
    with pytest.raises(DeviceFileError, match=r"stage\.toml: not UTF-8 text"):
        devices.load(path)
    twice = tmp_path / "stage.json"
    twice.write_text('{"name": "A", "name": "B"}')
    with pytest.raises(DeviceFileError, match=r"stage\.json: key 'name' given twice"):
        devices.load(twice)


def test_two_files_cannot_share_a_name_or_kind_but_an_edited_file_replaces_itself(tmp_path):
    first = variant(tmp_path, "Twin", dt=0.001)
    assert devices.load(first).dt == 0.001
    other = tmp_path / "other" / "Twin.toml"
    other.parent.mkdir()
    other.write_text(first.read_text().replace("dt = 0.001", "dt = 0.002"))
    with pytest.raises(DeviceFileError, match=r"is also that of .*Twin\.toml, loaded in this"):
        devices.load(other)
    first.write_text(first.read_text().replace("dt = 0.001", "dt = 0.002"))  # edited
    assert devices.load(first).dt == 0.002
    assert devices.get("twin").dt == 0.002


def test_a_file_without_a_suffix_is_read(tmp_path):
    path = tmp_path / "stage_description"
    path.write_text(variant(tmp_path, "NoSuffix").read_text())
    assert devices.get(str(path)).name == "NoSuffix"


def test_an_unpickled_axis_env_makes_its_device_known(tmp_path):
    import pickle

    path = variant(tmp_path, "Pickled")
    env = envs.make(str(path))
    env.reset(seed=0)
    data = pickle.dumps(env.unwrapped)
    del devices._LOADED["Pickled"]  # as in a fresh process
    copy = pickle.loads(data)
    assert devices.get("Pickled") == copy.device
    env.close()


def test_device_check_builds_what_the_tools_build(tmp_path, capsys):
    from frictiongym.cli import main

    path = variant(tmp_path, "BadTraining", training_env={"reference": "nonsense"})
    assert main(["device", "check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "BadTraining.toml: [training_env]: unknown reference 'nonsense'" in err
    path = variant(tmp_path, "BigResidual", residual={**_residual(), "scale": 100.0})
    assert main(["device", "check", str(path)]) == 2
    assert "[residual]: ResidualConfig.scale=100.0 exceeds the action limit" in (
        capsys.readouterr().err
    )


def test_train_and_benchmark_refuse_a_bad_file_in_one_line(tmp_path, capsys):
    from frictiongym.cli import main

    references = device_file.toml_loads(EXAMPLE.read_text())["references"]
    references["sine"] = {"amplitude": 1.0, "period": 0.0}
    bad = variant(tmp_path, "ZeroPeriod", references=references)
    assert main(["benchmark", "--device", str(bad), "--out", str(tmp_path / "b")]) == 2
    assert "references.sine: Sine.period must be > 0" in capsys.readouterr().err
    table = device_file.toml_loads(EXAMPLE.read_text())
    del table["residual"]
    table.update(name="NoResidual", kind="noresidual")
    path = tmp_path / "NoResidual.toml"
    path.write_text(device_file.render_toml(table))
    assert main(["train", "--device", str(path), "--quick", "--out", str(tmp_path / "t")]) == 2
    assert "[residual] missing: train needs" in capsys.readouterr().err


def test_one_file_named_by_two_paths_is_one_device(monkeypatch):
    monkeypatch.chdir(REPO)
    relative = devices.load("examples/ball_screw/ball_screw_stage.toml")
    absolute = devices.load(EXAMPLE)
    assert dataclasses.replace(relative, source="") == dataclasses.replace(absolute, source="")


def test_a_compensator_refuses_another_device_s_model(tmp_path):
    from frictiongym.controllers import PID, FrictionCompensator, PIDGains
    from frictiongym.identification.identify import identify, make_env
    from frictiongym.params import save_params

    env = make_env(str(EXAMPLE))
    result = identify(env, seed=0)
    env.close()
    path = tmp_path / "friction.json"
    save_params(path, result.params("paper"))
    servo = gym.make("frictiongym/RotaryServo-v1")
    with pytest.raises(ValueError, match=r"identified on BallScrewStage, but the loop runs on"):
        FrictionCompensator(PID.for_env(servo, PIDGains(1.0, 0.0, 0.0)), model=path)
    stage = envs.make(str(EXAMPLE))
    FrictionCompensator(PID.for_env(stage, PIDGains(1.0, 0.0, 0.0)), model=path)  # its own
    servo.close()
    stage.close()
