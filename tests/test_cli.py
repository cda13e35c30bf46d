import subprocess
import sys

import pytest

from frictiongym.cli import main


def test_demo_prints_the_step_metrics(capsys):
    assert main(["demo", "--duration", "1.0"]) == 0
    out = capsys.readouterr().out
    assert "nominal (no friction)" in out
    assert "friction: paper" in out
    assert "Kp=7.8 Ki=1.5 Kd=0.275" in out


def test_demo_plot(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    png = tmp_path / "demo.png"
    assert main(["demo", "--duration", "0.5", "--plot", str(png)]) == 0
    assert png.stat().st_size > 1000


def test_bad_arguments_exit_with_a_message(capsys):
    with pytest.raises(SystemExit) as info:
        main(["demo", "--duration", "-1"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: frictiongym demo")  # the demo's usage, not the top level's
    assert "argument --duration: must be a positive number" in err
    with pytest.raises(SystemExit):
        main(["demo", "--friction", "sandpaper"])
    assert "invalid choice" in capsys.readouterr().err


def test_console_script_help():
    out = subprocess.run(
        [sys.executable, "-m", "frictiongym.cli", "--help"], capture_output=True, text=True
    )
    assert out.returncode == 0
    assert "demo" in out.stdout


def test_plot_without_matplotlib_says_what_to_install(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import now raises ImportError
    png = tmp_path / "demo.png"
    assert main(["demo", "--duration", "0.2", "--plot", str(png)]) == 1
    assert "pip install matplotlib" in capsys.readouterr().err
    assert not png.exists()


def test_output_piped_into_a_closed_pipe_is_not_an_error():
    # Close the reading end before the demo writes: its first print meets a broken pipe, as
    # with `frictiongym demo | head -1`.
    proc = subprocess.Popen(
        [sys.executable, "-m", "frictiongym.cli", "demo", "--duration", "0.2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    proc.stdout.close()
    stderr = proc.stderr.read()
    assert proc.wait(timeout=120) == 0
    assert "Traceback" not in stderr


HEAVY = ("numba", "scipy", "gymnasium", "matplotlib", "torch", "ray")


def _imported(code_or_args):
    """Run Python under ``-X importtime``; return the top-level modules it imported."""
    args = ["-c", code_or_args] if isinstance(code_or_args, str) else code_or_args
    out = subprocess.run(
        [sys.executable, "-X", "importtime", *args], capture_output=True, text=True, check=True
    )
    lines = [line.split("|")[-1] for line in out.stderr.splitlines() if "|" in line]
    return {line.strip().split(".")[0] for line in lines}


@pytest.mark.parametrize("option", ["--help", "--version"])
def test_help_imports_no_heavy_module(option):
    imported = _imported(["-m", "frictiongym.cli", option])
    assert "frictiongym" in imported  # the check sees the package's own imports
    assert not imported & set(HEAVY), f"frictiongym {option} imported {imported & set(HEAVY)}"


def test_a_tool_help_shows_its_arguments():
    out = subprocess.run(
        [sys.executable, "-m", "frictiongym.cli", "benchmark", "--help"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("usage: frictiongym benchmark")
    assert "--group" in out.stdout
    assert "--heldout-seed" in out.stdout


def test_import_frictiongym_alone_is_light():
    imported = _imported("import frictiongym")
    assert not {"numba", "gymnasium"} & imported


@pytest.mark.parametrize(
    "order",
    [
        "import frictiongym\nimport gymnasium as gym",
        "import gymnasium as gym\nimport frictiongym",
        "import frictiongym.envs\nimport gymnasium as gym",  # gymnasium first imported by envs
    ],
)
def test_ids_registered_in_either_import_order(order):
    code = f"{order}\nenv = gym.make('frictiongym/RotaryServo-v1')\nprint(env.reset(seed=0)[0])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("[")
