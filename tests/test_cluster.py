"""``frictiongym sweep`` and ``frictiongym tune --ray`` on a local Ray with 2 CPUs.

The Ray tests start and stop Ray themselves: ``tune --ray`` its own local Ray (as the command
does), the sweep tests one Ray for the module (the command then uses it as it is). The sweep
trains for a few hundred steps and evaluates on one held-out plant.
"""

from __future__ import annotations

import builtins
import csv
import json
import os
import shlex
import signal
import socket
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

from frictiongym.cli import main
from frictiongym.residual.train import TrainSettings, train
from frictiongym.sweep.grid import SweepError, check_grid, expand, parse_grid, train_command
from frictiongym.sweep.trial import train_trial

SERVO = "frictiongym/RotaryServo-v1"
#: A trial of a few seconds: 256 steps of 2 envs, one validation on one plant.
TINY = [
    "--env",
    SERVO,
    "--steps",
    "256",
    "--n-envs",
    "2",
    "--sb3",
    "n_steps=64",
    "--validate-every",
    "128",
    "--validation-plants",
    "1",
    "--heldout",
    "1",
    "--quiet",
]


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


# --- without Ray, and bad input (no Ray started) ------------------------------------------------


def test_without_ray_the_ray_commands_exit_2_and_the_others_work(tmp_path, capsys, monkeypatch):
    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray" or name.startswith("ray."):
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    for words in (
        ["sweep", *TINY, "--out", str(tmp_path / "sweep")],
        ["tune", "--samples", "100", "--ray", "--no-figures", "--out", str(tmp_path / "tune")],
    ):
        assert main(words) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1, err
        assert 'pip install "frictiongym[cluster]"' in err
        assert not (tmp_path / words[0]).exists()
    assert (
        main(["tune", "--samples", "100", "--no-figures", "--quiet", "--out", str(tmp_path)]) == 0
    )
    assert (tmp_path / "tune.json").is_file()


def test_grid_values_are_json_and_keys_are_checked():
    assert parse_grid("n-envs=8,32") == ("n_envs", [8, 32])
    assert parse_grid('policy_kwargs={"net_arch":[64,64]},{"net_arch":[8]}') == (
        "policy_kwargs",
        [{"net_arch": [64, 64]}, {"net_arch": [8]}],
    )
    assert parse_grid('reward="env","precision"') == ("reward", ["env", "precision"])
    for bad, says in (
        ("n_envs", "KEY=V1,V2"),
        ("reward=env", "strings need quotes"),
        ("steps=", "gives no value"),
    ):
        with pytest.raises(ValueError, match=says):
            parse_grid(bad)
    pytest.importorskip("stable_baselines3")
    base = TrainSettings(env_id=SERVO)
    check_grid([("learning_rate", [1e-3]), ("n_envs", [2, 4])], base)
    for grid, says in (
        ([("learning_rat", [1e-3])], "unknown --grid key 'learning_rat'"),
        ([("steps", [1.5])], "steps takes a whole number"),
        ([("scale", [True])], "scale takes"),
        ([("seed", [1])], "--seeds"),
        ([("steps", [1]), ("steps", [2])], "given twice"),
    ):
        with pytest.raises(SweepError, match=says):
            check_grid(grid, base)


def test_trials_are_seeds_times_the_grid_and_say_their_train_command(tmp_path):
    base = TrainSettings(env_id=SERVO, threads=1, hyperparameters={"gamma": 0.99})
    grid = [("n_envs", [2, 4]), ("learning_rate", [0.001])]
    trials = expand(base, [0, 7], grid, tmp_path, {"plants": 1, "first_seed": 1000})
    assert [t.name for t in trials] == [
        "000-seed0-n_envs=2-learning_rate=0.001",
        "001-seed7-n_envs=2-learning_rate=0.001",
        "002-seed0-n_envs=4-learning_rate=0.001",
        "003-seed7-n_envs=4-learning_rate=0.001",
    ]
    t = trials[3]
    assert (t.settings.seed, t.settings.n_envs, t.settings.out.parent) == (
        7,
        4,
        tmp_path / "trials",
    )
    assert t.settings.hyperparameters == {"gamma": 0.99, "learning_rate": 0.001}
    words = shlex.split(train_command(t.settings))
    assert words[:6] == ["frictiongym", "train", "--env", SERVO, "--seed", "7"]
    assert {"--n-envs", "learning_rate=0.001", "--threads"} <= set(words)
    with pytest.raises(SweepError, match=r"trial 000-seed0-scale=2: --scale"):
        expand(base, [0], [("scale", [2])], tmp_path, {"plants": 1, "first_seed": 1000})
    with pytest.raises(SweepError, match="names a seed twice"):
        expand(base, [1, 1], [], tmp_path, {"plants": 1, "first_seed": 1000})


def test_bad_sweep_options_exit_2_before_ray_starts(tmp_path, capsys):
    pytest.importorskip("ray")
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "sweep"
    for words, says in (
        (["--grid", "bogus=1"], "unknown --grid key 'bogus'"),
        (["--grid", "scale=2"], "(0, 1]"),
        (["--address", f"127.0.0.1:{_free_port()}"], "cannot reach a Ray cluster"),
        (["--address", "nowhere"], "is not HOST:PORT"),
        (["--resume"], "holds no sweep"),
        (["--resume", "--overwrite"], "give one of them"),
    ):
        started = time.perf_counter()
        assert main(["sweep", *TINY, *words, "--out", str(out)]) == 2, words
        err = capsys.readouterr().err
        assert says in err, err
        assert err.count("\n") == 1, err
        assert time.perf_counter() - started < 15
    unreachable = ["--ray", f"127.0.0.1:{_free_port()}", "--out", str(tmp_path / "tune")]
    assert main(["tune", "--samples", "10", *unreachable]) == 2
    assert "cannot reach a Ray cluster at --ray" in capsys.readouterr().err
    assert not (tmp_path / "tune").exists()
    (out / "trials").mkdir(parents=True)
    assert main(["sweep", *TINY, "--out", str(out)]) == 2
    assert "--overwrite to replace them, --resume to continue them" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["sweep", *TINY, "--grid", "n_envs=[1", "--out", str(out)])
    assert info.value.code == 2


def test_a_trial_continues_its_folder(tmp_path):
    """A checkpoint short of the steps is resumed; a finished trial is read, not retrained."""
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "trial"
    settings = TrainSettings(
        env_id=SERVO,
        steps=256,
        n_envs=2,
        checkpoint_every=128,
        validate_every=None,
        quiet=True,
        out=out,
        hyperparameters={"n_steps": 64},
    )
    train(settings)
    for name in ("train.json", "model.zip"):  # as if stopped after the checkpoint at 256
        (out / name).unlink()
    summary = train_trial(TrainSettings(**{**settings.__dict__, "steps": 384}))
    assert summary["resumed_from"].endswith("model_256_steps.zip")
    assert summary["steps"] == 384
    assert train_trial(settings) == json.loads((out / "train.json").read_text())


# --- on Ray --------------------------------------------------------------------------------------


def test_tune_on_ray_gives_the_serial_result(tmp_path):
    """``tune --ray`` starts a local Ray, spreads the chunks over it and shuts it down."""
    ray = pytest.importorskip("ray")
    common = ["tune", "--samples", "3000", "--chunk", "700", "--no-figures", "--quiet"]
    assert main([*common, "--out", str(tmp_path / "serial")]) == 0
    assert main([*common, "--ray", "--out", str(tmp_path / "ray")]) == 0
    assert not ray.is_initialized()
    serial, on_ray = (
        json.loads((tmp_path / d / "tune.json").read_text()) for d in ("serial", "ray")
    )
    assert on_ray.pop("ray")["cpus"] >= 1
    for record in (serial, on_ray):
        for provenance in ("wall_time_s", "command"):
            record.pop(provenance)
    assert on_ray == serial
    assert serial["n_feasible"] > 0


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    pytest.importorskip("stable_baselines3")
    ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING", log_to_driver=False)
    yield ray
    ray.shutdown()


def _weights(path: Path) -> dict:
    import io

    import torch

    with zipfile.ZipFile(path) as archive:
        return torch.load(io.BytesIO(archive.read("policy.pth")), map_location="cpu")


def test_a_sweep_trial_trains_the_policy_train_trains_and_is_evaluated_as_the_benchmark_does(
    local_ray, tmp_path
):
    out = tmp_path / "sweep"
    assert main(["sweep", *TINY, "--seeds", "3", "--out", str(out)]) == 0
    trial = out / "trials" / "000-seed3"
    summary = json.loads((trial / "train.json").read_text())
    assert (summary["seed"], summary["steps"], summary["n_envs"]) == (3, 256, 2)

    # The trial's own train command, into another folder, gives the same weights.
    words = shlex.split(summary["command_line"])
    words[words.index("--out") + 1] = str(tmp_path / "plain")
    assert main([*words[1:], "--quiet"]) == 0
    for name in ("best.zip", "model.zip"):
        ours, plain = _weights(trial / name), _weights(tmp_path / "plain" / name)
        assert ours.keys() == plain.keys()
        assert all(bool((ours[k] == plain[k]).all()) for k in ours), name

    # The held-out ratios are those of the benchmark's evaluation of best.zip.
    heldout = json.loads((trial / "heldout.json").read_text())
    bench = tmp_path / "bench"
    assert main([*shlex.split(heldout["command_line"])[1:], "--out", str(bench), "--quiet"]) == 0
    runs = json.loads((bench / "results.json").read_text())
    itae = {
        r["scenario"]: r["metrics"]["itae"]
        for r in runs
        if r["scenario"].endswith("heldout-residual")
        or r["scenario"].endswith("heldout-compensated")
    }
    ratio = itae["residual-rotary-heldout-residual"] / itae["residual-rotary-heldout-compensated"]
    assert heldout["heldout"]["itae_ratio"] == pytest.approx(ratio, rel=1e-12)

    rows = list(csv.DictReader((out / "sweep.csv").open()))
    assert [(r["rank"], r["trial"], r["status"]) for r in rows] == [("1", "000-seed3", "done")]
    assert float(rows[0]["heldout_itae_ratio"]) == pytest.approx(ratio, rel=1e-5)
    assert (out / "best" / "best.zip").read_bytes() == (trial / "best.zip").read_bytes()
    assert "000-seed3" in (out / "sweep.md").read_text()
    assert local_ray.is_initialized()  # a Ray the command found is left running


@pytest.mark.slow
def test_an_interrupted_sweep_continues_with_resume(tmp_path):
    """Ctrl-C stops the trials (exit 130, no table); --resume finishes them from checkpoints."""
    pytest.importorskip("ray")
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "sweep"
    args = [
        *TINY,
        "--seeds",
        "0",
        "1",
        "--steps",
        "20000",
        "--checkpoint-every",
        "512",
        "--validate-every",
        "4096",
        "--out",
        str(out),
    ]
    command = [sys.executable, "-m", "frictiongym.cli", "sweep", *args]
    proc = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, env=os.environ.copy())
    deadline = time.monotonic() + 240
    while not list(out.glob("trials/*/checkpoints/model_1024_steps.zip")):
        assert proc.poll() is None
        assert time.monotonic() < deadline
        time.sleep(1)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "continue with --resume" in err
    assert not (out / "sweep.csv").exists()
    assert not (out / "best").exists()

    assert main(["sweep", *args, "--resume"]) == 0
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    assert sorted(r["status"] for r in rows) == ["done", "done"]
    resumed = [json.loads((out / "trials" / r["trial"] / "train.json").read_text()) for r in rows]
    assert any(s["resumed_from"] for s in resumed)
    assert all(s["steps"] >= 20000 for s in resumed)
    # Resumed again, the finished sweep only rewrites its table.
    assert main(["sweep", *args, "--resume"]) == 0
