import subprocess
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def test_plot_friction_writes_a_png(tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "laws.png"
    done = subprocess.run(
        [sys.executable, str(SCRIPTS / "plot_friction.py"), "--out", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert out.stat().st_size > 10_000


@pytest.mark.parametrize(
    ("script", "options"),
    [
        (
            "bench_plants.py",
            (
                "--batches",
                "--repeats",
                "--quick",
                "--markdown",
                "--part",
                "--thread-sizes",
                "--loads",
                "--tuner-chunk",
            ),
        ),
        (
            "bench_envs.py",
            (
                "--repeats",
                "--seconds",
                "--num-envs",
                "--quick",
                "--markdown",
                "--seed",
                "--part",
                "--thread-sizes",
                "--loads",
            ),
        ),
        (
            "bench_rl_loops.py",
            (
                "--repeats",
                "--rollout",
                "--loads",
                "--loops",
                "--quick",
                "--torch-threads",
                "--markdown",
            ),
        ),
        ("benchmark.py", ("--out", "--quick", "--group", "--scenario", "--seeds", "--no-figures")),
        ("identify.py", ("--env", "--out", "--backend", "--law", "--noise", "--seed")),
        ("tune.py", ("--samples", "--seed", "--out", "--model", "--params", "--rule")),
        (
            "emulate.py",
            (
                "--device",
                "--tcp",
                "--params",
                "--lockstep",
                "--drop",
                "--corrupt",
                "--delay",
                "--unplug-after",
            ),
        ),
        (
            "sim2real.py",
            ("--env", "--backend", "--controller", "--gains", "--params", "--repeats", "--out"),
        ),
        ("bench_hardware.py", ("--seconds", "--frames")),
        (
            "train_residual.py",
            (
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
            ),
        ),
    ],
)
def test_script_help_explains_its_options(script, options):
    done = subprocess.run(
        [sys.executable, str(SCRIPTS / script), "--help"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    for option in options:
        assert option in done.stdout


def test_bench_envs_quick_reports_both_headline_ratios():
    done = subprocess.run(
        [
            sys.executable,
            str(SCRIPTS / "bench_envs.py"),
            "--quick",
            "--markdown",
            "--part",
            "cartpole",
        ],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "single env, time per step ours / CartPole-v1 (target <= 1)" in out
    assert "env-steps/s ours / CartPoleVectorEnv (target >= 1.5)" in out
    for name in ("RotaryServo-v1", "AltinoDistance-v1"):
        assert name in out
    assert "| comparison | target |" in out  # the markdown tables


@pytest.mark.parametrize(
    ("script", "extra"), [("bench_envs.py", ()), ("bench_plants.py", ("--tuner-chunk", "0"))]
)
def test_threads_part_compares_the_default_with_both_kernels(script, extra):
    done = subprocess.run(
        [
            sys.executable,
            str(SCRIPTS / script),
            "--part",
            "threads",
            "--quick",
            "--markdown",
            "--loads",
            "quiet",
            "busy",
            "--thread-sizes",
            "512",
            "--repeats",
            "1",
            "--seconds",
            "0.02",
            *extra,
        ],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "| load | N | serial kernel" in done.stdout
    for load in ("quiet", "busy"):
        assert f"| {load} | 512 |" in done.stdout
    assert "default within 5% of the serial kernel or faster (median) in every case:" in done.stdout


def test_loads_part_reports_the_threads_gain_beside_the_ratios():
    done = subprocess.run(
        [
            sys.executable,
            str(SCRIPTS / "bench_envs.py"),
            "--part",
            "loads",
            "--quick",
            "--markdown",
            "--loads",
            "quiet",
            "--repeats",
            "1",
            "--seconds",
            "0.02",
        ],
        capture_output=True,
        text=True,
        check=False,
        timeout=180,
    )
    assert done.returncode == 0, done.stderr
    assert "| ratio | threads' gain |" in done.stdout
    quiet = [line for line in done.stdout.splitlines() if line.startswith("| quiet |")]
    assert len(quiet) == 1
    assert quiet[0].count("|") == 8  # 7 cells: load, CartPole, two envs' rate and ratio, gain
