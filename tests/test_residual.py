"""Residual control: the wrapper, its bound, the controller, and ``frictiongym train``.

torch and Stable-Baselines3 are imported inside the tests that train, never at import.
"""

import json
import pathlib
import subprocess
import sys
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.cli import main
from frictiongym.controllers import ControllerPolicy, ResidualController, rollout
from frictiongym.residual import (
    OBSERVATION_NAMES,
    ResidualConfig,
    ResidualEnv,
    bounded_residual,
    make_base,
    residual_observation,
)
from frictiongym.residual.selection import METRICS

SERVO = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"
IDS = [SERVO, ALTINO]
SHORT = {SERVO: 400, ALTINO: 200}  # steps of the test rollouts (0.8 s, 10 s)


class ConstantPolicy:
    """A stand-in for an SB3 model: ``predict`` returns one value, and records its input."""

    def __init__(self, value):
        self.value = value
        self.seen = []

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(observation)
        self.seen.append(obs.copy())
        shape = (*obs.shape[:-1], 1)
        value = self.value() if callable(self.value) else self.value
        return np.broadcast_to(np.asarray(value, dtype=np.float32), shape).copy(), state


def test_import_frictiongym_does_not_import_torch():
    code = (
        "import sys, frictiongym, frictiongym.controllers, frictiongym.residual\n"
        "from frictiongym.controllers import ResidualController\n"
        "from frictiongym.cli import build_parser; build_parser()\n"
        "print(sorted(m for m in ('torch', 'stable_baselines3') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_bounded_residual_clips_and_neutralises_nan():
    a = np.array([1e6, -1e6, np.nan, np.inf, -np.inf, 0.5])
    assert np.array_equal(bounded_residual(a, 2.0), [2.0, -2.0, 0.0, 2.0, -2.0, 1.0])


@pytest.mark.parametrize("env_id", IDS)
def test_zero_residual_reproduces_the_base_controller(env_id):
    steps = SHORT[env_id]
    base_run = rollout(gym.make(env_id), make_base(gym.make(env_id)), steps=steps, seed=3)
    env = ResidualEnv(gym.make(env_id))
    obs, _ = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    commands = []
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        assert info["residual"] == 0.0
        commands.append(info["command"])
        if terminated or truncated:
            break
    n = len(commands)
    np.testing.assert_allclose(commands, base_run.command[:n, 0], rtol=1e-6, atol=1e-4)


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("policy", ["plus", "minus", "nan", "random"])
def test_the_residual_bound_holds_for_any_policy_output(env_id, policy):
    rng = np.random.default_rng(0)
    outputs = {
        "plus": lambda: np.array([1e6]),
        "minus": lambda: np.array([-1e6]),
        "nan": lambda: np.array([np.nan]),
        "random": lambda: rng.normal(0.0, 1e3, 1),
    }
    env = ResidualEnv(gym.make(env_id, randomize={"friction": (0.5, 1.5)}))
    limit, scale = env.config.limit, env.scale
    assert scale == pytest.approx({SERVO: 1.0, ALTINO: 200.0}[env_id])
    obs, _ = env.reset(seed=1)
    for _ in range(SHORT[env_id]):
        obs, reward, terminated, truncated, info = env.step(outputs[policy]())
        applied, base = info["command"], info["base_action"]
        assert abs(info["residual"]) <= scale
        assert abs(applied - base) <= scale * (1 + 1e-6)
        assert abs(applied) <= limit
        assert env.observation_space.contains(obs)
        assert np.isfinite(reward)
        if terminated or truncated:
            obs, _ = env.reset()


def test_the_base_can_be_a_controller_or_a_factory_and_is_reset():
    env = gym.make(SERVO)
    pid = make_base(env, "pid")
    wrapped = ResidualEnv(env, pid, scale=0.5)
    assert wrapped.base is pid
    assert wrapped.scale == 0.5
    wrapped.reset(seed=0)
    for _ in range(50):
        wrapped.step(np.ones(1))
    assert pid.integral != 0.0
    wrapped.reset(seed=0)
    # reset, then one call on the first observation: an error of 1 rad for one period
    assert float(pid.integral) == pytest.approx(1.0 * 0.002)
    built = ResidualEnv(gym.make(SERVO), lambda e: make_base(e, "pid"))
    assert type(built.base).__name__ == "PID"
    with pytest.raises(ValueError, match="exceeds the action limit"):
        ResidualEnv(gym.make(SERVO), scale=20.0)


@pytest.mark.parametrize("env_id", IDS)
def test_the_controller_computes_the_observation_the_env_trains_on(env_id):
    """Same features, same bound: a policy sees in control exactly what it saw in training."""
    steps = SHORT[env_id]
    rng = np.random.default_rng(5)
    values = rng.uniform(-1.5, 1.5, steps)
    env = ResidualEnv(gym.make(env_id))
    obs, _ = env.reset(seed=2)
    trained_on, commands = [obs], []
    for k in range(steps):
        obs, *_, info = env.step(values[k : k + 1])
        trained_on.append(obs)
        commands.append(info["command"])
    it = iter(values)
    policy = ConstantPolicy(lambda: next(it))
    controller = ResidualController(make_base(gym.make(env_id)), policy, env.config)
    run = rollout(gym.make(env_id), controller, steps=steps, seed=2)
    np.testing.assert_array_equal(np.array(policy.seen), np.array(trained_on[:steps]))
    np.testing.assert_allclose(run.command[:steps, 0], commands, rtol=1e-6, atol=1e-4)
    assert len(OBSERVATION_NAMES) == trained_on[0].shape[0]


@pytest.mark.parametrize("env_id", IDS)
def test_an_adversarial_controller_stays_within_the_bound_on_a_vector_env(env_id):
    vec = gym.make_vec(
        env_id,
        num_envs=3,
        vectorization_mode="vector_entry_point",
        randomize={"friction": (0.5, 1.5)},
    )
    config = ResidualConfig.for_env(vec)
    for value in (1e6, -1e6, np.nan):
        controller = ResidualController(make_base(vec), ConstantPolicy(value), config)
        shadow = make_base(vec)  # sees the same observations as the controller's base
        obs, _ = vec.reset(seed=0)
        controller.reset()
        for _ in range(SHORT[env_id] // 4):
            action, base = controller(obs), shadow(obs)
            assert action.shape == base.shape == (3, 1)
            assert np.all(np.abs(action) <= config.limit)
            assert np.all(np.abs(action - base) <= config.scale * (1 + 1e-9))
            obs, *_ = vec.step(action)


def test_residual_observation_is_batched_and_normalised():
    env = gym.make(ALTINO)
    spec = make_base(env).spec
    config = ResidualConfig.for_env(env)
    # readout, distance 7 cm, moving toward the wall at 2 cm/s, reference 5 cm
    obs = np.array([[93.0, 7.0, -2.0, 5.0], [93.0, 5.0, 0.0, 5.0]])
    features = residual_observation(obs, spec, np.array([[100.0], [0.0]]), config)
    assert features.shape == (2, 6)
    assert features.dtype == np.float32
    # direction -1: the error asks for a positive (forward) command, the motion is forward
    np.testing.assert_allclose(features[0], [0.4, np.tanh(8.0), 0.2, -0.5, 0.1, 0.0], rtol=1e-6)
    np.testing.assert_allclose(features[1], [0.0, 0.0, 0.0, -0.5, 0.0, 1.0])
    single = residual_observation(obs[0], spec, np.array([100.0]), config)
    np.testing.assert_array_equal(single, features[0])


# --- training (SB3 and torch imported inside the tests) ---------------------------------------


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """One tiny PPO model per device, trained through ``frictiongym train``."""
    pytest.importorskip("stable_baselines3")
    out = {}
    for env_id in IDS:
        path = tmp_path_factory.mktemp("train") / "run"
        status = main(
            [
                "train",
                "--n-envs",
                "1",
                "--env",
                env_id,
                "--quick",
                "--steps",
                "512",
                "--out",
                str(path),
                "--seed",
                "1",
                "--checkpoint-every",
                "256",
                "--quiet",
            ]
        )
        assert status == 0
        out[env_id] = path
    return out


def test_training_writes_the_model_logs_checkpoints_and_summary(trained):
    path = trained[SERVO]
    summary = json.loads((path / "train.json").read_text())
    assert (summary["algo"], summary["steps"], summary["seed"]) == ("ppo", 512, 1)
    assert summary["env_kwargs"]["randomize"]["friction"] == [0.7, 1.3]
    assert summary["scale"] == 1.0
    assert summary["env_steps_per_s"] > 0
    assert {"torch", "stable_baselines3", "frictiongym"} <= set(summary["versions"])
    assert (path / "model.zip").is_file()
    assert sorted(p.name for p in (path / "checkpoints").iterdir()) == [
        "model_256_steps.zip",
        "model_512_steps.zip",
    ]
    logs = path / summary["logs"]["dir"].split(str(path))[-1].lstrip("/")
    assert (logs / "progress.csv").is_file()


def test_resume_continues_to_the_total_steps(trained, capsys):
    path = trained[ALTINO]
    status = main(
        ["train", "--env", ALTINO, "--steps", "1024", "--out", str(path), "--resume", "--quiet"]
    )
    assert status == 0
    summary = json.loads((path / "train.json").read_text())
    assert (summary["steps"], summary["steps_this_run"]) == (1024, 512)
    assert summary["resumed_from"].endswith("model.zip")
    # Nothing left to do, and another algorithm than the model's: exit 2 with a message.
    assert main(["train", "--env", ALTINO, "--steps", "1024", "--out", str(path), "--resume"]) == 2
    assert "give a larger --steps" in capsys.readouterr().err
    status = main(
        [
            "train",
            "--n-envs",
            "1",
            "--env",
            ALTINO,
            "--algo",
            "sac",
            "--out",
            str(path),
            "--resume",
            str(path / "checkpoints" / "model_256_steps.zip"),
        ]
    )
    assert status == 2
    assert "--algo ppo" in capsys.readouterr().err


@pytest.mark.parametrize("env_id", IDS)
def test_a_trained_controller_runs_through_rollout_and_controller_policy(trained, env_id):
    env = gym.make(env_id)
    controller = ResidualController.load(trained[env_id] / "model.zip", env)
    run = rollout(env, controller, steps=SHORT[env_id], seed=0)
    assert np.all(np.isfinite(run.command[: run.length[0]]))
    assert np.all(np.abs(run.command[: run.length[0]]) <= controller.config.limit)
    assert np.isfinite(run.metrics().itae)
    policy = ControllerPolicy(controller)
    obs, _ = env.reset(seed=0)
    action, _ = policy.predict(obs[np.newaxis], episode_start=np.array([True]))
    assert action.shape == (1, 1)
    assert action.dtype == np.float32
    with pytest.raises(ValueError, match="trained for"):
        ResidualController.load(trained[env_id] / "model.zip", gym.make(IDS[env_id == SERVO]))


def test_a_trained_controller_runs_on_a_device_backend(trained):
    env = gym.make(SERVO, backend="emulator://rotary?lockstep=1", log=False)
    try:
        controller = ResidualController.load(trained[SERVO] / "model.zip", env)
        run = rollout(env, controller, steps=50, seed=0)
    finally:
        env.close()
    assert run.length[0] == 51
    assert np.all(np.abs(run.command[:50]) <= 10.0)


def test_save_load_round_trip_gives_the_same_actions(tmp_path):
    sb3 = pytest.importorskip("stable_baselines3")
    env = ResidualEnv(gym.make(SERVO, reference="random_steps"))
    model = sb3.SAC("MlpPolicy", env, seed=0, learning_starts=10, buffer_size=100, device="cpu")
    model.learn(20)
    meta = {
        "env_id": SERVO,
        "algo": "sac",
        "config": env.config.to_dict(),
        "base": {"kind": "compensated"},
    }
    model.frictiongym_residual = meta
    model.save(tmp_path / "model.zip")
    loaded = ResidualController.load(tmp_path / "model.zip", gym.make(SERVO))
    original = ResidualController(make_base(gym.make(SERVO)), model)
    runs = [rollout(gym.make(SERVO), c, steps=300, seed=4) for c in (loaded, original)]
    np.testing.assert_array_equal(runs[0].command, runs[1].command)
    obs, _ = gym.make(SERVO).reset(seed=0)
    assert loaded.residual(obs)[1][0] != 0.0  # a non-trivial policy
    del model.frictiongym_residual
    model.save(tmp_path / "plain.zip")
    with pytest.raises(ValueError, match="without frictiongym residual metadata"):
        ResidualController.load(tmp_path / "plain.zip", gym.make(SERVO))


# --- the command's input checks ---------------------------------------------------------------


def test_bad_inputs_exit_2_with_a_message(tmp_path, capsys, monkeypatch):
    a_file = tmp_path / "file"
    a_file.write_text("")
    assert main(["train", "--env", "CartPole-v1", "--out", str(tmp_path / "x")]) == 2
    assert "unknown --env 'CartPole-v1'" in capsys.readouterr().err
    assert main(["train", "--env", SERVO, "--out", str(a_file)]) == 2
    assert "is a file" in capsys.readouterr().err
    assert main(["train", "--env", SERVO, "--scale", "2", "--out", str(tmp_path / "x")]) == 2
    assert "fraction of the action limit" in capsys.readouterr().err
    assert main(["train", "--env", SERVO, "--resume", "--out", str(tmp_path / "empty")]) == 2
    assert "no checkpoint" in capsys.readouterr().err
    for words in (["--algo", "a2c"], ["--steps", "0"], ["--n-envs", "-1"]):
        with pytest.raises(SystemExit) as info:
            main(["train", "--env", SERVO, *words])
        assert info.value.code == 2
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)  # import now fails
    assert main(["train", "--env", SERVO, "--out", str(tmp_path / "y")]) == 2
    assert 'pip install "frictiongym[rl]"' in capsys.readouterr().err
    assert not (tmp_path / "y").exists()


def test_help_explains_the_options(capsys):
    with pytest.raises(SystemExit) as info:
        main(["train", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for option in (
        "--env",
        "--algo",
        "--steps",
        "--seed",
        "--out",
        "--randomize",
        "--quick",
        "--resume",
        "--n-envs",
        "--checkpoint-every",
        "--quiet",
        "--scale",
    ):
        assert option in out


class _FakeModel:
    """What the validation callback uses of an SB3 model."""

    def __init__(self, steps: int) -> None:
        self.num_timesteps = steps
        self.logger = type("Logger", (), {"record": lambda *args: None})()

    def get_env(self) -> None:
        return None

    def save(self, path) -> None:
        pathlib.Path(path).write_bytes(b"model")


@pytest.mark.parametrize("validated_before", [False, True])
def test_a_run_resumed_on_a_validation_step_validates_there_once(tmp_path, validated_before):
    """A Ctrl-C during the validation at 6 144 steps saved a checkpoint there, and the resumed
    run went on to 8 192 with no row for 6 144. Now it validates first, unless the row is
    there already (a checkpoint taken after it)."""
    pytest.importorskip("stable_baselines3")
    from frictiongym.residual.train import _validation_callback

    scores = iter([3.0, 2.0, 1.0])

    def validation(model):
        ratios = {f"{p}/{m}": 1.0 for p in ("nominal", "randomised") for m in METRICS}
        return SimpleNamespace(score=next(scores), ratios=ratios, terminated=0)

    model = _FakeModel(6144)
    if validated_before:  # a run from 4 000 validates at 6 144, then saves its checkpoint
        model.num_timesteps = 4000
        first = _validation_callback(validation, 2048, tmp_path, lambda _: None, 0.0)
        first.init_callback(model)
        first.on_training_start({}, {})
        model.num_timesteps = 6144
        first.on_step()
    resumed = _validation_callback(validation, 2048, tmp_path, lambda _: None, 0.0)
    resumed.init_callback(model)
    resumed.on_training_start({}, {})
    rows = (tmp_path / "validation.csv").read_text().splitlines()[1:]
    assert [int(row.split(",")[0]) for row in rows] == [6144]
    assert resumed.due == 8192


def test_train_steps_32_envs_of_the_native_vector_env_by_default(tmp_path):
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "run"
    assert main(["train", "--env", ALTINO, "--quick", "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "train.json").read_text())
    assert summary["n_envs"] == 32
    assert summary["hyperparameters"]["batch_size"] == 256
    assert summary["steps"] == 2048  # one rollout of 64 steps in each of the 32 envs
    assert summary["best_score"] == summary["validation"]["best_score"]
    assert summary["stopped_by"] == "steps"
    # A resumed run keeps its 32 envs without being told.
    assert (
        main(
            ["train", "--env", ALTINO, "--steps", "4096", "--out", str(out), "--resume", "--quiet"]
        )
        == 0
    )
    assert json.loads((out / "train.json").read_text())["n_envs"] == 32


def test_max_time_stops_training_in_time_and_keeps_the_best_policy(tmp_path):
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "run"
    args = ["train", "--env", ALTINO, "--max-time", "12", "--validate-every", "4096"]
    assert main([*args, "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "train.json").read_text())
    assert summary["stopped_by"] == "max_time"
    assert summary["wall_time_s"] <= 12 + 3  # the last validation fits in; saving is quick
    assert summary["steps"] >= 2048  # at least a rollout, however busy the machine
    assert (out / "best.zip").is_file()
    rows = (out / "validation.csv").read_text().splitlines()
    assert rows[0].endswith(",time_s")
    best = min(float(r.split(",")[1]) for r in rows[1:])
    assert summary["best_score"] == pytest.approx(best, rel=1e-5)  # the CSV holds 6 digits


def test_max_time_must_be_a_positive_number_of_seconds(tmp_path, capsys):
    assert main(["train", "--env", SERVO, "--max-time", "0", "--out", str(tmp_path / "x")]) == 2
    assert "--max-time" in capsys.readouterr().err


@pytest.mark.parametrize("residual_cost", [0.0, 2.0])
def test_the_training_reward_keeps_crashing_worse_than_finishing(residual_cost):
    """The precision reward charges up to log(1 + e / one count) per step, more than the v1
    env's terminal cost covers; its own terminal term makes up the difference."""
    from frictiongym import devices

    def episode(action: float) -> float:
        env = ResidualEnv(
            gym.make(SERVO),
            base=lambda e: make_base(e, "pid", gains={"kp": 0.0, "ki": 0.0, "kd": 0.0}),
            scale=10.0,
            precision=devices.ROTARY.training_precision,
            residual_cost=residual_cost,
        )
        env.reset(seed=0, options={"position": -11.0})  # 1.6 rad inside the limit
        total = 0.0
        while True:
            _, reward, terminated, truncated, _ = env.step(np.array([action], np.float32))
            total += reward
            if terminated or truncated:
                return total

    assert episode(-1.0) < episode(0.0)  # into the limit at full command, or held still
