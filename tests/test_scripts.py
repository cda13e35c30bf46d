import subprocess
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def run_script(script: str, *args: str, timeout: float = 120) -> str:
    """Run ``scripts/<script>`` with ``args``; return its standard output (it must succeed)."""
    done = subprocess.run(
        [sys.executable, str(SCRIPTS / script), *args],
        capture_output=True,
        text=True,
        check=False,
        timeout=timeout,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_plot_friction_writes_a_png(tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "laws.png"
    run_script("plot_friction.py", "--out", str(out))
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
    out = run_script(script, "--help")
    for option in options:
        assert option in out


def test_bench_envs_quick_reports_both_headline_ratios():
    out = run_script("bench_envs.py", "--quick", "--markdown", "--part", "cartpole")
    assert "single env, time per step ours / CartPole-v1 (target <= 1)" in out
    assert "env-steps/s ours / CartPoleVectorEnv (target >= 1.5)" in out
    for name in ("RotaryServo-v1", "AltinoDistance-v1"):
        assert name in out
    assert "| comparison | target |" in out  # the markdown tables


@pytest.mark.parametrize(
    ("script", "extra"), [("bench_envs.py", ()), ("bench_plants.py", ("--tuner-chunk", "0"))]
)
def test_threads_part_compares_the_default_with_both_kernels(script, extra):
    short = ("--quick", "--markdown", "--repeats", "1", "--seconds", "0.02")
    loads = ("--loads", "quiet", "busy", "--thread-sizes", "512")
    out = run_script(script, "--part", "threads", *short, *loads, *extra)
    assert "| load | N | serial kernel" in out
    for load in ("quiet", "busy"):
        assert f"| {load} | 512 |" in out
    assert "default within 5% of the serial kernel or faster (median) in every case:" in out


def test_loads_part_reports_the_threads_gain_beside_the_ratios():
    short = ("--quick", "--markdown", "--repeats", "1", "--seconds", "0.02")
    out = run_script("bench_envs.py", "--part", "loads", *short, "--loads", "quiet", timeout=180)
    assert "| ratio | threads' gain, scalar | threads' gain, SIMD |" in out
    quiet = [line for line in out.splitlines() if line.startswith("| quiet |")]
    assert len(quiet) == 1
    assert quiet[0].count("|") == 9  # 8 cells: load, CartPole, two envs' rate and ratio, gains
    gains = quiet[0].split("|")[-3:-1]
    assert all(float(gain.split()[0]) > 0 for gain in gains)


def test_passes_part_splits_each_plant_step_into_its_passes():
    out = run_script("bench_envs.py", "--part", "passes", "--quick", "--markdown", timeout=300)
    assert "| env | pass 1 | pending list | pass 1b | pass 2 | all |" in out
    for name in ("RotaryServo-v1", "AltinoDistance-v1"):
        row = next(line for line in out.splitlines() if line.startswith(f"| {name} |"))
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        medians = [float(cell.split()[0]) for cell in cells[1:6]]  # increments may be < 0
        assert medians[0] > 0  # pass 1: a whole pass
        assert medians[4] > 0  # all
        after_one, after_one_b = (float(cell.removesuffix(" %")) for cell in cells[6:8])
        assert 0 < after_one_b < after_one < 100  # pass 1b finishes most pending plants


def test_passes_part_refuses_a_block_too_small_for_the_passes():
    done = subprocess.run(
        [sys.executable, str(SCRIPTS / "bench_envs.py"), "--part", "passes", "--num-envs", "257"],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    assert done.returncode != 0
    assert "--num-envs 257 leaves one of 1" in done.stderr


def test_autoreset_part_times_the_autoreset_in_the_kernel_against_one_before_it():
    out = run_script(
        "bench_envs.py",
        "--part",
        "autoreset",
        "--quick",
        "--num-envs",
        "1024",
        "--markdown",
        timeout=600,
    )
    assert "| env | step | µs per step | ratio, median of rounds [quartiles] |" in out
    for name in ("RotaryServo-v1", "AltinoDistance-v1"):
        rows = [line for line in out.splitlines() if line.startswith(f"| {name} |")]
        assert len(rows) == 4  # serial, before, the control, in the kernel
        cells = [[cell.strip() for cell in row.strip("|").split("|")] for row in rows]
        assert all(float(row[2].split()[0]) > 0 for row in cells)  # µs per step
        assert cells[1][3].startswith("1.000")  # the reference, against itself


def test_split_part_splits_a_vector_step():
    out = run_script("bench_envs.py", "--part", "split", "--quick", "--markdown", timeout=600)
    assert "| env | vector step | env kernel | plant | observation |" in out
    for name in ("RotaryServo-v1", "AltinoDistance-v1"):
        row = next(line for line in out.splitlines() if line.startswith(f"| {name} |"))
        assert float(row.strip("|").split("|")[1].split()[0]) > 0
