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
