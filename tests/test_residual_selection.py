"""Training choices of residual policies: the precision reward, validation and best.zip."""

import csv
import json
import math

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym import devices
from frictiongym.cli import main
from frictiongym.controllers import ResidualController
from frictiongym.residual import ResidualConfig, ResidualEnv
from frictiongym.residual.selection import Validation

SERVO = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"


class ConstantPolicy:
    """A stand-in for an SB3 model whose ``predict`` always returns ``value``."""

    def __init__(self, value):
        self.value = value

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        shape = (*np.asarray(observation).shape[:-1], 1)
        return np.full(shape, self.value, dtype=np.float32), state


@pytest.mark.parametrize("env_id", [SERVO, ALTINO])
def test_the_precision_reward_swaps_only_the_tracking_term(env_id):
    device = env_id.split("/")[1].split("-")[0]
    precision = devices.get(device).training_precision
    plain = ResidualEnv(gym.make(env_id, reference="random_steps"))
    shaped = ResidualEnv(gym.make(env_id, reference="random_steps"), precision=precision)
    plain.reset(seed=3)
    shaped.reset(seed=3)
    e0 = plain.unwrapped.sim.device.error_scale
    actions = np.random.default_rng(0).uniform(-1, 1, 60)
    for action in actions:
        _, r_plain, *_, info = plain.step([action])
        _, r_shaped, *_, info_shaped = shaped.step([action])
        assert info_shaped["command"] == info["command"]  # the reward changes nothing else
        error = abs(info["reference"] - info["position"])
        expected = r_plain + error / e0 - math.log1p(error / precision)
        assert r_shaped == pytest.approx(expected, rel=1e-12, abs=1e-12)
    # A perfect track costs nothing; one sensor step costs log 2 (before the effort term).
    assert -math.log1p(precision / precision) == pytest.approx(-math.log(2.0))
    with pytest.raises(ValueError, match=r"precision must be > 0, got 0.0 \(an error scale\)"):
        ResidualEnv(gym.make(env_id), precision=0.0)


@pytest.mark.parametrize("env_id", [SERVO, ALTINO])
def test_validation_scores_the_base_as_one_and_a_biased_policy_as_worse(env_id):
    device = env_id.split("/")[1].split("-")[0]
    config = ResidualConfig.for_device(device)
    validation = Validation(device, devices.get(device).randomization, config, plants=2)
    neutral = validation(ConstantPolicy(0.0))  # the residual adds exactly nothing
    assert set(neutral.ratios) == {
        "nominal/itae",
        "nominal/steady_state_error",
        "randomised/itae",
        "randomised/steady_state_error",
    }
    assert all(ratio == 1.0 for ratio in neutral.ratios.values())
    assert neutral.score == 1.0
    biased = validation(ConstantPolicy(0.5))  # a steady push of half the bound
    assert biased.score > 1.2


def test_training_keeps_the_best_validated_policy(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    torch = pytest.importorskip("torch")
    torch.set_num_threads(2)  # numba's OpenMP layer would also leave it at 2 (bench_training.py)
    out = tmp_path / "run"
    status = main(
        [
            "train",
            "--n-envs",
            "1",
            "--env",
            ALTINO,
            "--quick",
            "--steps",
            "1024",
            "--out",
            str(out),
            "--validate-every",
            "256",
            "--validation-plants",
            "1",
            "--reward",
            "precision",
            "--sb3",
            "gamma=0.98",
            "--sb3",
            "n_epochs=2",
            "--quiet",
        ]
    )
    assert status == 0
    with (out / "validation.csv").open() as file:
        rows = list(csv.DictReader(file))
    assert [int(row["steps"]) for row in rows] == [256, 512, 768, 1024]
    best = min(float(row["score"]) for row in rows)
    summary = json.loads((out / "train.json").read_text())
    assert summary["validation"]["best_score"] == pytest.approx(best, rel=1e-5)
    assert summary["reward"] == "precision"
    assert summary["precision"] == devices.ALTINO.training_precision
    assert summary["hyperparameters"]["gamma"] == 0.98
    assert summary["hyperparameters"]["n_epochs"] == 2
    assert summary["threads"] == 1
    assert torch.get_num_threads() == 1  # held at --threads (default 1) for the updates
    # best.zip is the policy that scored best: scoring it again gives that score.
    controller = ResidualController.load(out / "best.zip", gym.make(ALTINO))
    config = controller.config
    validation = Validation("AltinoDistance", devices.ALTINO.randomization, config, plants=1)
    assert validation(controller.model).score == pytest.approx(best, rel=1e-5)
    assert not list(out.glob(".*partial*"))
    # Continuing it with another objective would change what the policy optimises.
    status = main(
        [
            "train",
            "--n-envs",
            "1",
            "--env",
            ALTINO,
            "--steps",
            "2048",
            "--out",
            str(out),
            "--resume",
            "--reward",
            "env",
            "--quiet",
        ]
    )
    assert status == 2
    assert "trained with --reward precision" in capsys.readouterr().err


def test_bad_training_choices_exit_2(tmp_path, capsys):
    for words, message in (
        (["--sb3", "gamma"], "expected KEY=VALUE"),
        (["--sb3", "policy_kwargs={bad"], "is not JSON"),
        (["--reward", "sparse"], "invalid choice"),
    ):
        with pytest.raises(SystemExit) as info:
            main(["train", "--env", SERVO, *words])
        assert info.value.code == 2
        assert message in capsys.readouterr().err
    out = str(tmp_path / "x")
    assert main(["train", "--env", SERVO, "--residual-cost", "-1", "--out", out]) == 2
    assert "--residual-cost must be >= 0" in capsys.readouterr().err
    assert main(["train", "--env", SERVO, "--validate-every", "-5", "--out", out]) == 2
    assert "--validate-every must be a positive number" in capsys.readouterr().err


@pytest.mark.parametrize("device", ["rotary", "altino"])
def test_the_shipped_policy_beats_the_compensated_pid_on_the_nominal_plant(device):
    pytest.importorskip("stable_baselines3")
    from pathlib import Path

    from frictiongym.benchmark.run import run_scenario
    from frictiongym.benchmark.scenarios import residual_scenarios

    model = Path(__file__).parents[1] / "models" / "residual" / f"{device}.zip"
    nominal = [s for s in residual_scenarios(device, str(model), plants=1) if "nominal" in s.name]
    base, residual = (run_scenario(s)[0] for s in nominal)
    assert not residual.terminated
    assert residual.metrics.itae < base.metrics.itae
    assert residual.metrics.steady_state_error < base.metrics.steady_state_error
