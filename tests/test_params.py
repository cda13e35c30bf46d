"""Identified parameters: the friction.json format, save/load, gym.make(params=), compensators."""

import itertools
import json
import math

import gymnasium as gym
import numpy as np
import pytest

import frictiongym
from frictiongym.controllers import PID, FrictionCompensator, LoopSpec, PIDGains, rollout
from frictiongym.friction import (
    ALTINO_PAPER,
    ROTARY_LUGRE,
    ROTARY_PAPER,
    CoulombViscous,
    StictionCoulomb,
)
from frictiongym.params import (
    FILE_NAME,
    FORMAT,
    PARAM_KEYS,
    DeviceParams,
    ParamsFileError,
    load_params,
    resolve_params,
    save_params,
)
from frictiongym.plants import PlantParams
from frictiongym.plants.presets import ALTINO_PLANT, ROTARY_PAPER_GAINS, ROTARY_PLANT

SERVO = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"

#: A servo "identified" a little off the paper's preset, so that file and preset differ.
SERVO_LAW = StictionCoulomb(
    us_pos=0.25,
    us_neg=0.18,
    uc_pos=0.13,
    uc_neg=0.09,
    v0_pos=2.5,
    v0_neg=2.0,
    viscous=0.04,
)
SERVO_J, SERVO_B = 8.0e-3, 0.05


def servo_params(friction=SERVO_LAW, **kwargs):
    kwargs.setdefault("device", "RotaryServo")
    return DeviceParams.from_model(friction, inertia=SERVO_J, damping=SERVO_B, **kwargs)


def valid_mapping():
    return servo_params().to_dict()


def write(tmp_path, data, name=FILE_NAME):
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else json.dumps(data), encoding="utf-8")
    return path


# --- format ----------------------------------------------------------------------------------


LAWS = [
    ("paper", SERVO_LAW),
    ("paper", SERVO_LAW.replace(shape="smooth")),
    ("paper", SERVO_LAW.replace(shape="step")),
    ("paper", SERVO_LAW.replace(shape="exponential")),
    ("stribeck", SERVO_LAW.replace(shape="exponential")),
    ("coulomb", CoulombViscous(0.12, 0.1, 0.04)),
]


@pytest.mark.parametrize(("law", "friction"), LAWS)
def test_round_trip_keeps_law_shape_uncertainty_and_metadata(tmp_path, law, friction):
    params = DeviceParams.from_model(
        friction,
        inertia=SERVO_J,
        damping=SERVO_B,
        law=law,
        device="RotaryServo",
        env_id=SERVO,
        uncertainty={"us_pos": 0.004, "J": 2e-4},
        metadata={
            "experiments": ["ramp", {"n": 3}],
            "residual": np.float32(0.5),
            "ok": True,
            "map": np.array([[1.0, 2.0]]),
            "tau": math.nan,
            "aic": -math.inf,
        },
    )
    path = save_params(tmp_path / "servo.json", params)
    loaded = load_params(path)
    assert loaded.law == law
    assert loaded.friction == friction
    assert type(loaded.friction) is type(friction)
    assert loaded.uncertainty == {"us_pos": 0.004, "J": 2e-4}
    assert loaded.metadata == {
        "experiments": ["ramp", {"n": 3}],
        "residual": 0.5,
        "ok": True,
        "map": [[1.0, 2.0]],
        "tau": None,
        "aic": None,  # JSON has no NaN: null
    }
    assert loaded.units["velocity"] == "rad/s"  # the device's units by default
    assert loaded == DeviceParams.from_dict(json.loads(path.read_text()))
    assert load_params(save_params(tmp_path / "again.json", loaded)) == loaded


def test_file_lists_the_issue_keys_first_with_a_format_tag(tmp_path):
    path = save_params(tmp_path / "p.json", servo_params())
    text = path.read_text(encoding="utf-8")
    data = json.loads(text)
    assert list(data)[:10] == [*PARAM_KEYS, "J", "B", "law"]
    assert data["format"] == FORMAT
    assert data["shape"] == "linear"
    assert text.endswith("}\n")
    assert "\n  " in text  # indented


def test_coulomb_file_has_no_stiction_and_no_decay():
    data = DeviceParams.from_model(
        CoulombViscous(0.12, 0.1, 0.04), inertia=1.0, damping=0.1
    ).to_dict()
    assert (data["us_pos"], data["us_neg"]) == (data["uc_pos"], data["uc_neg"])
    assert data["v0_pos"] is None
    assert data["v0_neg"] is None
    assert "shape" not in data
    data["us_pos"] = data["us_neg"] = None  # null stiction is accepted too
    data["v0_pos"] = 1.0
    assert DeviceParams.from_dict(data).friction == CoulombViscous(0.12, 0.1, 0.04)


def test_from_model_takes_the_law_from_the_model():
    assert servo_params().law == "paper"
    assert servo_params(CoulombViscous(0.1, 0.1)).law == "coulomb"
    assert servo_params(device=None).units == {}
    with pytest.raises(ParamsFileError, match="'lugre' has no params-file form"):
        servo_params(ROTARY_LUGRE)
    with pytest.raises(ParamsFileError, match="shape='exponential'"):
        servo_params(law="stribeck")


def test_plant_and_plant_friction_apply_the_b_convention():
    params = servo_params()
    plant = params.plant(ROTARY_PLANT)
    assert (plant.inertia, plant.damping) == (SERVO_J, SERVO_B)
    assert plant.command_limit == ROTARY_PLANT.command_limit
    assert params.plant_friction() == SERVO_LAW.replace(viscous=0.0)
    assert params.friction.viscous == 0.04  # kept as identified


def test_callers_dicts_are_copied():
    metadata = {"runs": [1, 2]}
    params = servo_params(metadata=metadata)
    metadata["runs"].append(3)
    assert params.metadata == {"runs": [1, 2]}


# --- paths and atomic writes -----------------------------------------------------------------


def test_directory_paths(tmp_path):
    params = servo_params()
    written = save_params(tmp_path, params)
    assert written == tmp_path / FILE_NAME
    assert load_params(tmp_path) == params
    nested = save_params(tmp_path / "runs" / "servo", params)  # created, then friction.json
    assert nested == tmp_path / "runs" / "servo" / FILE_NAME
    assert resolve_params(str(tmp_path / "runs" / "servo")) == params
    assert resolve_params(params) is params
    with pytest.raises(TypeError, match=r"friction\.json"):
        resolve_params(3)  # type: ignore[arg-type]


def test_save_is_atomic_and_leaves_no_temporary_files(tmp_path):
    first = servo_params()
    save_params(tmp_path, first)
    save_params(tmp_path, servo_params(metadata={"second": True}))  # replaces
    assert load_params(tmp_path).metadata == {"second": True}
    assert [p.name for p in tmp_path.iterdir()] == [FILE_NAME]
    before = (tmp_path / FILE_NAME).read_bytes()
    with pytest.raises(ParamsFileError, match="cannot write as JSON"):
        save_params(tmp_path, servo_params(metadata={"x": object()}))
    assert (tmp_path / FILE_NAME).read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == [FILE_NAME]


# --- bad input -------------------------------------------------------------------------------


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(ParamsFileError, match="no such file") as err:
        load_params(tmp_path / "nope.json")
    assert "nope.json" in str(err.value)
    with pytest.raises(ParamsFileError, match=r"directory has no friction\.json"):
        load_params(tmp_path)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("{not json", "not valid JSON"),
        ('{"us_pos": NaN}', "not valid JSON.*NaN"),
        ("[1, 2]", "one JSON object"),
        ("\udcff", "not valid JSON|UTF-8"),
    ],
)
def test_unreadable_files(tmp_path, text, match):
    path = tmp_path / FILE_NAME
    path.write_bytes(text.encode("utf-8", "surrogateescape"))
    with pytest.raises(ParamsFileError, match=match) as err:
        load_params(path)
    assert str(path) in str(err.value)


def test_missing_keys_are_listed_with_an_example(tmp_path):
    data = valid_mapping()
    del data["us_neg"], data["B"]
    with pytest.raises(ParamsFileError) as err:
        load_params(write(tmp_path, data))
    message = str(err.value)
    assert "missing keys us_neg, B" in message
    assert '"law": "paper"' in message
    assert "frictiongym identify --out DIR" in message
    assert str(tmp_path) in message


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"us_neg": -0.18}, r"'us_neg' must be >= 0, got -0.18 \(levels are magnitudes"),
        ({"uc_pos": 0.3}, "uc_pos=0.3 exceeds us_pos=0.25 in the positive direction"),
        ({"uc_neg": 0.2}, "uc_neg=0.2 exceeds us_neg=0.18 in the negative direction"),
        ({"v0_pos": 0.0}, "'v0_pos' must be > 0"),
        ({"J": 0.0}, "'J' must be > 0"),
        ({"B": -1.0}, "'B' must be >= 0"),
        ({"J": "8e-3"}, "'J' must be a real number, got '8e-3' \\(str\\)"),
        ({"viscous": True}, "'viscous' must be a real number"),
        ({"us_pos": None}, "'us_pos' must be a real number"),
        ({"law": "lugre"}, "unknown law 'lugre'; supported: paper, stribeck, coulomb"),
        ({"shape": "cubic"}, "'shape' must be one of"),
        ({"shape": ["linear"]}, "'shape' must be one of"),
        ({"law": "stribeck", "shape": "linear"}, "exponential decay"),
        ({"law": "coulomb", "shape": "linear"}, "no decay shape"),
        ({"law": "coulomb", "shape": None}, "us_pos=0.25 must equal uc_pos=0.13 or be null"),
        ({"device": 3}, "'device' must be a string or null"),
        ({"units": ["V"]}, "'units' must be a JSON object"),
        ({"units": {"force": 1}}, "'units' must map names to strings"),
        ({"uncertainty": {"us_pos": -1.0}}, "'uncertainty.us_pos' must be >= 0"),
        ({"uncertainty": {"mass": 1.0}}, "uncertainty of unknown key 'mass'"),
        ({"vicous": 0.0}, "unknown keys 'vicous'.*metadata"),
        ({"format": "frictiongym.params/2"}, "format 'frictiongym.params/2'"),
    ],
)
def test_invalid_values_name_the_problem(tmp_path, change, match):
    path = write(tmp_path, {**valid_mapping(), **change})
    with pytest.raises(ParamsFileError, match=match) as err:
        load_params(path)
    assert str(path) in str(err.value)


def test_non_finite_values(tmp_path):
    text = json.dumps(valid_mapping()).replace('"J": 0.008', '"J": 1e999')  # parses as inf
    with pytest.raises(ParamsFileError, match="'J' must be finite"):
        load_params(write(tmp_path, text))


def test_a_file_without_format_or_optional_keys_loads():
    data = {k: valid_mapping()[k] for k in (*PARAM_KEYS, "J", "B", "law")}
    params = DeviceParams.from_dict(data)
    assert params.device is None
    assert params.friction == SERVO_LAW


# --- environments ----------------------------------------------------------------------------


def test_make_with_params_simulates_the_file(tmp_path):
    path = save_params(tmp_path, servo_params())
    env = gym.make(SERVO, params=path)
    sim = env.unwrapped.sim
    assert sim.plant.inertia == SERVO_J
    assert sim.plant.damping == SERVO_B
    assert sim.friction == SERVO_LAW.replace(viscous=0.0)
    assert sim.model_friction == SERVO_LAW
    plant = PlantParams(SERVO_J, SERVO_B, ROTARY_PLANT.command_limit)
    same = gym.make(SERVO, friction=SERVO_LAW.replace(viscous=0.0), plant=plant)
    gains = PIDGains(**ROTARY_PAPER_GAINS)
    a = rollout(env, PID.for_env(env, gains), 800, seed=0)
    b = rollout(same, PID.for_env(same, gains), 800, seed=0)
    np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_array_equal(a.command, b.command)
    assert np.ptp(a.position) > 0.5  # it did move


def test_altino_preset_as_a_file_gives_identical_trajectories(tmp_path):
    """B is the total damping: the file B = viscous = 10.93 is the preset (damping 0 + law)."""
    params = DeviceParams.from_model(
        ALTINO_PAPER, inertia=ALTINO_PLANT.inertia, damping=10.93, device="AltinoDistance"
    )
    env = gym.make(ALTINO, params=save_params(tmp_path, params))
    default = gym.make(ALTINO)
    rng = np.random.default_rng(3)
    actions = np.clip(np.cumsum(rng.normal(0.0, 120.0, 400)), -900, 900).astype(np.float32)
    env.reset(seed=1)
    default.reset(seed=1)
    for u in actions:
        obs, reward, terminated, _, info = env.step(np.array([u]))
        obs_d, reward_d, terminated_d, _, info_d = default.step(np.array([u]))
        np.testing.assert_array_equal(obs, obs_d)
        assert (reward, info["position"], info["velocity"]) == (
            reward_d,
            info_d["position"],
            info_d["velocity"],
        )
        if terminated or terminated_d:
            assert terminated == terminated_d
            break


def test_vector_env_takes_params(tmp_path):
    path = save_params(tmp_path, servo_params())
    vec = gym.make_vec(SERVO, num_envs=3, vectorization_mode="vector_entry_point", params=path)
    assert vec.unwrapped.sim.plant.inertia == SERVO_J
    assert vec.unwrapped.sim.friction == SERVO_LAW.replace(viscous=0.0)
    single = gym.make(SERVO, params=path)
    obs, _ = vec.reset(seed=0)
    single.reset(seed=0)
    for _ in range(50):
        obs, *_ = vec.step(np.full((3, 1), 0.6, dtype=np.float32))
        one, *_ = single.step(np.array([0.6], dtype=np.float32))
    np.testing.assert_array_equal(obs[0], one)
    vec.close()


def test_params_exclude_other_physics_and_other_devices(tmp_path):
    path = save_params(tmp_path, servo_params())
    with pytest.raises(ValueError, match="params and plant both set"):
        gym.make(SERVO, params=path, plant=ROTARY_PLANT)
    with pytest.raises(ValueError, match=r"params and friction both set.*pick one"):
        gym.make(SERVO, params=path, friction="coulomb")
    assert gym.make(SERVO, params=path, friction="paper").unwrapped.sim.plant.inertia == SERVO_J
    with pytest.raises(ParamsFileError, match=r"identified on device 'RotaryServo'.*units differ"):
        gym.make(ALTINO, params=path)
    anonymous = save_params(tmp_path / "anon.json", servo_params(device=None))
    gym.make(ALTINO, params=anonymous)  # no device named: accepted
    with pytest.raises(ParamsFileError, match="no such file"):
        gym.make(SERVO, params=tmp_path / "missing.json")


# --- controllers -----------------------------------------------------------------------------


def test_compensator_accepts_a_path_or_params(tmp_path):
    params = servo_params()
    path = save_params(tmp_path, params)
    env = gym.make(SERVO)
    gains = PIDGains(**ROTARY_PAPER_GAINS)
    obs = np.array([[0.0, 0.0, 1.0], [0.2, 1.5, 1.0], [0.9, -3.5, 1.0], [1.0, 0.05, 1.0]])
    for model in (path, str(path), tmp_path, params):
        by_model = FrictionCompensator(PID.for_env(env, gains), model=SERVO_LAW)
        by_file = FrictionCompensator(PID.for_env(env, gains), model=model)
        assert by_file.model == SERVO_LAW
        for o in obs:
            np.testing.assert_array_equal(by_file(o), by_model(o))
    with pytest.raises(ParamsFileError):
        FrictionCompensator(PID.for_env(env, gains), model=tmp_path / "missing")


def test_controllers_built_for_a_params_env_model_the_file(tmp_path):
    path = save_params(tmp_path, servo_params())
    env = gym.make(SERVO, params=path)
    assert LoopSpec.from_env(env).friction == SERVO_LAW
    compensator = FrictionCompensator(PID.for_env(env, PIDGains(**ROTARY_PAPER_GAINS)))
    assert compensator.model == SERVO_LAW
    vec = gym.make_vec(SERVO, num_envs=2, vectorization_mode="vector_entry_point", params=path)
    assert LoopSpec.from_env(vec).friction == SERVO_LAW
    vec.close()
    # Without params the default stays the device's preset, whatever law is simulated.
    for friction in ("paper", "coulomb", "none"):
        assert LoopSpec.from_env(gym.make(SERVO, friction=friction)).friction == ROTARY_PAPER


def test_package_reexports_lazily():
    assert frictiongym.load_params is load_params
    assert frictiongym.save_params is save_params
    assert frictiongym.DeviceParams is DeviceParams
    with pytest.raises(AttributeError):
        _ = frictiongym.not_there


@pytest.mark.parametrize(
    ("key", "value"),
    [("B", 1e308), ("J", 1e-300), ("J", 1e7), ("us_pos", 1e7), ("v0_neg", 1e-20), ("viscous", 2e6)],
)
def test_values_outside_their_physical_range_are_refused(tmp_path, key, value):
    path = write(tmp_path, {**valid_mapping(), key: value})
    with pytest.raises(ParamsFileError, match=f"'{key}' = .* physically meaningful range"):
        load_params(path)


def test_an_integer_beyond_the_float_range_is_a_params_file_error(tmp_path):
    path = write(tmp_path, {**valid_mapping(), "B": 10**400})  # JSON allows any integer
    with pytest.raises(ParamsFileError, match="'B' must be finite, got an integer too large"):
        load_params(path)


def test_deeply_nested_json_is_a_params_file_error(tmp_path):
    path = tmp_path / "friction.json"
    path.write_text('{"metadata": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(ParamsFileError, match="nested too deeply"):
        load_params(path)


@pytest.mark.parametrize("env_id", [SERVO, ALTINO])
def test_the_range_s_corners_simulate_finite_values(env_id):
    """At the extremes of every range the env still returns finite numbers."""
    amplitude = 10.0 if env_id == SERVO else 1000.0
    rng = np.random.default_rng(0)
    for inertia, damping, level in itertools.product((1e-9, 1e6), (0.0, 1e6), (0.0, 1e6)):
        levels = {k: level for k in ("us_pos", "us_neg", "uc_pos", "uc_neg")}
        data = {**valid_mapping(), "J": inertia, "B": damping, "viscous": damping, **levels}
        data["device"] = data["env_id"] = None
        env = gym.make(env_id, params=DeviceParams.from_dict(data)).unwrapped
        env.reset(seed=0)
        for _ in range(100):
            obs, reward, terminated, _, info = env.step(rng.uniform(-amplitude, amplitude, 1))
            assert np.all(np.isfinite(obs))
            assert np.isfinite(reward)
            assert np.isfinite(info["position"])
            if terminated:
                env.reset()
