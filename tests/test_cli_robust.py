"""The tools under user mistakes and interruptions: output folders, reruns, Ctrl-C, bad values.

Every tool that writes results (benchmark, identify, tune, sim2real, train) checks its --out
before the work starts, refuses an --out holding an earlier run's results unless --overwrite
replaces all of them, and leaves --out as it was on an error or a Ctrl-C (exit 130, one line).
"""

from __future__ import annotations

import errno
import json
import os
import pathlib
import re
import signal
import subprocess
import threading
import time

import pytest

from frictiongym.benchmark import command as benchmark_command
from frictiongym.cli import main
from frictiongym.identification import command as identify_command
from frictiongym.residual import train as train_module
from frictiongym.sim2real import command as sim2real_command
from frictiongym.tuning import command as tune_command

SERVO = "frictiongym/RotaryServo-v1"
EMULATOR = "emulator://rotary?lockstep=1"

#: tool -> (its arguments besides --out, (module, attribute) doing the work, its OUTPUTS)
TOOLS = {
    "benchmark": (
        ["--quick", "--quiet"],
        (benchmark_command, "run_benchmark"),
        benchmark_command.OUTPUTS,
    ),
    "identify": (
        ["--env", SERVO, "--quiet"],
        (identify_command, "make_env"),
        identify_command.OUTPUTS,
    ),
    "tune": (["--quiet"], (tune_command, "random_search"), tune_command.OUTPUTS),
    "sim2real": (
        ["--env", SERVO, "--backend", EMULATOR, "--quiet"],
        (sim2real_command, "run_sim2real"),
        sim2real_command.OUTPUTS,
    ),
    "train": (
        ["--env", SERVO, "--quick", "--quiet"],
        (train_module, "_train"),
        train_module.OUTPUTS,
    ),
}


def _no_work(monkeypatch, tool, effect=None):
    """Make the tool's work raise ``effect`` (by default: fail the test if it starts)."""
    module, name = TOOLS[tool][1]

    def work(*args, **kwargs):
        raise effect or AssertionError("the work started")

    monkeypatch.setattr(module, name, work)


def _one_line(text):
    lines = text.strip().splitlines()
    assert len(lines) == 1, text
    return lines[0]


# --- an --out that cannot be written: refused before the work, one line, exit 2 ----------------


@pytest.mark.parametrize("tool", TOOLS)
def test_an_out_under_a_regular_file_is_refused_before_the_work(
    tool, tmp_path, monkeypatch, capsys
):
    _no_work(monkeypatch, tool)
    a_file = tmp_path / "a-file"
    a_file.write_text("keep")
    for out in (a_file, a_file / "results"):
        assert main([tool, *TOOLS[tool][0], "--out", str(out)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert line.startswith(f"error: --out {out}")
        assert "is a file, not a directory" in line
    assert a_file.read_text() == "keep"


@pytest.mark.parametrize("tool", TOOLS)
def test_a_read_only_file_system_is_refused_before_the_work(tool, tmp_path, monkeypatch, capsys):
    _no_work(monkeypatch, tool)

    def read_only(self, *args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))

    monkeypatch.setattr(pathlib.Path, "mkdir", read_only)
    out = tmp_path / "new" / "results"
    assert main([tool, *TOOLS[tool][0], "--out", str(out)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == (
        f"error: cannot write to --out {out}: Read-only file system; give a writable --out"
    )
    assert not (tmp_path / "new").exists()


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes anywhere")
def test_a_folder_without_write_permission_is_refused(tmp_path, monkeypatch, capsys):
    _no_work(monkeypatch, "tune")
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        assert main(["tune", "--out", str(locked / "results")]) == 2
        assert "Permission denied" in _one_line(capsys.readouterr().err)
        assert main(["tune", "--out", str(locked)]) == 2
        assert "Permission denied" in _one_line(capsys.readouterr().err)
    finally:
        locked.chmod(0o700)


def test_demo_plot_into_a_missing_folder_is_refused_before_the_simulation(
    tmp_path, monkeypatch, capsys
):
    import frictiongym.loops

    monkeypatch.setattr(frictiongym.loops, "rotary_step", lambda *a: pytest.fail("simulated"))
    png = tmp_path / "missing" / "step.png"
    assert main(["demo", "--plot", str(png)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"error: --plot {png}: the folder {png.parent} does not exist")
    assert main(["demo", "--plot", str(tmp_path)]) == 2
    assert "is a directory; give a file name" in _one_line(capsys.readouterr().err)
    pytest.importorskip("matplotlib")
    assert main(["demo", "--plot", str(tmp_path / "step.txt")]) == 2
    assert "matplotlib cannot write .txt files" in _one_line(capsys.readouterr().err)
    assert list(tmp_path.iterdir()) == []


# --- a rerun: refused without --overwrite; with it, the earlier run's files all go ------------


@pytest.mark.parametrize("tool", TOOLS)
def test_an_out_with_an_earlier_run_is_refused_without_overwrite(
    tool, tmp_path, monkeypatch, capsys
):
    _no_work(monkeypatch, tool)
    earlier = tmp_path / TOOLS[tool][2][-1]
    earlier.write_text("earlier run")
    assert main([tool, *TOOLS[tool][0], "--out", str(tmp_path)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"error: --out {tmp_path} holds the results of an earlier run")
    assert "give --overwrite to replace them" in line
    assert ("--resume to continue them" in line) == (tool == "train")
    assert earlier.read_text() == "earlier run"
    assert sorted(p.name for p in tmp_path.iterdir()) == [earlier.name]


def test_benchmark_overwrite_replaces_every_file_of_the_earlier_run(tmp_path, capsys):
    for name in ("results.json", "rotary_response.png", "compensator_mismatch.png"):
        (tmp_path / name).write_text("earlier run")
    (tmp_path / "notes.txt").write_text("mine")
    argv = ["benchmark", "--scenario", "paper-rotary-pid", "--no-figures", "--quiet"]
    assert main([*argv, "--overwrite", "--out", str(tmp_path)]) == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["notes.txt", "results.csv", "results.json", "results.md"]
    (record,) = json.loads((tmp_path / "results.json").read_text())
    assert record["scenario"] == "paper-rotary-pid"
    assert (tmp_path / "notes.txt").read_text() == "mine"


def test_identify_writes_only_its_declared_outputs_and_replaces_them_whole(tmp_path, capsys):
    out = tmp_path / "id"
    assert main(["identify", "--env", SERVO, "--out", str(out), "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(identify_command.OUTPUTS)
    assert (
        main(
            [
                "identify",
                "--env",
                SERVO,
                "--out",
                str(out),
                "--quiet",
                "--no-figures",
                "--overwrite",
            ]
        )
        == 0
    )
    assert sorted(p.name for p in out.iterdir()) == ["friction.json", "summary.md"]
    assert f"wrote {out / 'friction.json'}" in capsys.readouterr().out


def test_train_overwrite_drops_the_earlier_validation_and_best_model(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    (tmp_path / "validation.csv").write_text("steps,score\n999999,0.001\n")
    (tmp_path / "best.zip").write_text("an earlier run's policy")
    (tmp_path / "tb" / "ppo_1").mkdir(parents=True)
    (tmp_path / "tb" / "ppo_1" / "earlier").write_text("")
    (tmp_path / "notes.txt").write_text("mine")
    argv = [
        "train",
        "--n-envs",
        "1",
        "--env",
        SERVO,
        "--quick",
        "--steps",
        "64",
        "--validate-every",
        "0",
        "--out",
        str(tmp_path),
        "--quiet",
    ]
    assert main(argv) == 2
    assert "give --overwrite" in capsys.readouterr().err
    assert main([*argv, "--overwrite"]) == 0
    names = {p.name for p in tmp_path.iterdir()}
    assert names <= {*train_module.OUTPUTS, "notes.txt"}
    assert {"model.zip", "train.json", "notes.txt"} <= names
    assert not {"validation.csv", "best.zip"} & names  # --validate-every 0 writes neither
    assert not (tmp_path / "tb" / "ppo_1" / "earlier").exists()
    assert main([*argv, "--overwrite", "--resume"]) == 2
    assert "give one of them" in _one_line(capsys.readouterr().err)


# --- Ctrl-C: one line, exit 130, no partial outputs ---------------------------------------


@pytest.mark.parametrize("tool", TOOLS)
def test_an_interrupt_leaves_a_new_out_uncreated(tool, tmp_path, monkeypatch, capsys):
    _no_work(monkeypatch, tool, KeyboardInterrupt())
    out = tmp_path / "new" / "results"
    assert main([tool, *TOOLS[tool][0], "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert _one_line(err) == f"frictiongym {tool}: interrupted; --out {out} not created"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("tool", ["benchmark", "identify", "tune", "sim2real"])
def test_an_interrupt_keeps_the_earlier_results(tool, tmp_path, monkeypatch, capsys):
    _no_work(monkeypatch, tool, KeyboardInterrupt())
    earlier = tmp_path / TOOLS[tool][2][0]
    earlier.write_text("earlier run")
    assert main([tool, *TOOLS[tool][0], "--out", str(tmp_path), "--overwrite"]) == 130
    line = _one_line(capsys.readouterr().err)
    assert line == f"frictiongym {tool}: interrupted; --out {tmp_path} left as it was"
    assert sorted(p.name for p in tmp_path.iterdir()) == [earlier.name]
    assert earlier.read_text() == "earlier run"


def test_an_interrupt_while_writing_removes_the_files_already_written(
    tmp_path, monkeypatch, capsys
):
    written = []

    def figures_interrupted(results, folder):
        written.extend(p.name for p in folder.iterdir())
        raise KeyboardInterrupt

    monkeypatch.setattr(benchmark_command, "write_figures", figures_interrupted)
    out = tmp_path / "results"
    argv = ["benchmark", "--scenario", "paper-rotary-pid", "--quiet", "--out", str(out)]
    assert main(argv) == 130
    assert {"results.json", "results.csv", "results.md"} <= set(written)  # then interrupted
    assert "interrupted" in _one_line(capsys.readouterr().err)
    assert not out.exists()


def _read_stderr(proc):
    """Collect a process's stderr in a thread; return the list its chunks go to."""
    chunks: list[str] = []

    def read():
        for chunk in iter(lambda: proc.stderr.read(1), ""):
            chunks.append(chunk)

    threading.Thread(target=read, daemon=True).start()
    return chunks


def _wait_for(chunks, pattern, proc, timeout=180.0):
    """Wait until the stderr read so far matches ``pattern``; return the match."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        found = re.search(pattern, "".join(chunks))
        if found:
            return found
        assert proc.poll() is None, "".join(chunks)
        time.sleep(0.05)
    pytest.fail(f"no {pattern!r} on stderr in {timeout} s: {''.join(chunks)[-500:]}")


def _interrupt(proc, chunks, sig=signal.SIGINT):
    proc.send_signal(sig)
    status = proc.wait(timeout=120)
    time.sleep(0.2)  # the reader thread's last chunks
    return status, "".join(chunks)


@pytest.mark.parametrize(
    ("earlier", "sig"),
    [(False, signal.SIGINT), (True, signal.SIGINT), (False, signal.SIGTERM), (True, signal.SIGHUP)],
    ids=["new-out", "earlier-results", "sigterm-new-out", "sighup-earlier-results"],
)
def test_ctrl_c_on_a_running_benchmark(tmp_path, earlier, sig):
    """A Ctrl-C, a ``kill`` or a closed terminal: one line, no partial outputs (a SIGTERM had
    left --out/.frictiongym-partial-* behind)."""
    out = tmp_path / "results"
    argv = ["frictiongym", "benchmark", "--out", str(out)]
    if earlier:
        out.mkdir()
        (out / "results.json").write_text("earlier run")
        argv.append("--overwrite")
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        chunks = _read_stderr(proc)
        _wait_for(chunks, r"\b[1-9]\d*/\d+ \[", proc)  # mid-run: a scenario is done
        status, err = _interrupt(proc, chunks, sig)
    finally:
        proc.kill()
    assert "Traceback" not in err
    kept = "left as it was" if earlier else "not created"
    if sig == signal.SIGINT:
        assert status == 130
        assert err.splitlines()[-1] == f"frictiongym benchmark: interrupted; --out {out} {kept}"
    else:
        assert status == 128 + sig
        assert err.splitlines()[-1] == (
            f"frictiongym benchmark: terminated by {sig.name}; --out {out} {kept}"
        )
    if earlier:
        assert sorted(p.name for p in out.iterdir()) == ["results.json"]
        assert (out / "results.json").read_text() == "earlier run"
    else:
        assert not out.exists()


def test_ctrl_c_on_training_saves_a_checkpoint_that_resume_continues(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [
            "frictiongym",
            "train",
            "--n-envs",
            "1",
            "--env",
            SERVO,
            "--quick",
            "--steps",
            "100000",
            "--out",
            str(out),
            "--validate-every",
            "0",
            "--threads",
            "1",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        chunks = _read_stderr(proc)
        _wait_for(chunks, r"\b[1-9]\d{2,}/100000 \[", proc)  # some hundred steps trained
        status, err = _interrupt(proc, chunks)
    finally:
        proc.kill()
    assert status == 130
    assert "Traceback" not in err
    last = err.splitlines()[-1]
    found = re.fullmatch(
        r"frictiongym train: interrupted; checkpoint of (\d+) steps saved as "
        r"(\S+); continue with --resume",
        last,
    )
    assert found, last
    steps, checkpoint = int(found.group(1)), pathlib.Path(found.group(2))
    assert steps > 0
    assert checkpoint == out / "checkpoints" / f"model_{steps}_steps.zip"
    assert train_module.saved_steps(checkpoint) == steps
    assert not [p for p in out.rglob(".*") if p.is_file()]  # no temporary file left
    argv = [
        "train",
        "--n-envs",
        "1",
        "--env",
        SERVO,
        "--steps",
        str(steps + 1),
        "--out",
        str(out),
        "--resume",
        "--validate-every",
        "0",
        "--quiet",
    ]
    assert main(argv) == 0
    summary = json.loads((out / "train.json").read_text())
    assert summary["resumed_from"] == str(checkpoint)
    assert summary["steps"] - summary["steps_this_run"] == steps
    assert summary["steps"] > steps


# --- bad values: one line, exit 2, nothing created ----------------------------------------


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["identify", "--env", SERVO, "--seed", "-1"], "--seed must be a whole number from 0"),
        (["train", "--env", SERVO, "--seed", "-1"], "--seed must be a whole number from 0"),
        (["train", "--env", SERVO, "--seed", str(2**32)], "from 0 to 4294967295, got 4294967296"),
        (["tune", "--seed", "-1"], "--seed must be a whole number from 0"),
        (["tune", "--seed", str(2**32)], "from 0 to 4294967295, got 4294967296"),
        (["train", "--env", SERVO, "--sb3", "bogus=1"], "--sb3 bogus: PPO takes no such argument"),
        (["train", "--env", SERVO, "--sb3", "seed=3"], "--sb3 seed: frictiongym train sets it"),
        (["train", "--env", SERVO, "--sb3", "n_steps=-1"], "--sb3 n_steps=-1: PPO refused them"),
        (["sim2real", "--env", SERVO, "--backend", "sim"], "--backend sim is the simulator"),
    ],
)
def test_bad_values_get_one_line(argv, message, tmp_path, capsys):
    if argv[0] == "train" and "--sb3" in argv:
        pytest.importorskip("stable_baselines3")
    out = tmp_path / "out"
    assert main([*argv, "--out", str(out), "--quiet"]) == 2
    assert message in _one_line(capsys.readouterr().err)
    assert not out.exists()


def test_emulate_refuses_a_negative_seed(capsys):
    assert main(["emulate", "--device", "rotary", "--seed", "-1"]) == 2
    assert _one_line(capsys.readouterr().err) == (
        "error: --seed must be a whole number from 0 to 4294967295, got -1"
    )


def test_demo_bad_values_show_the_demo_usage(capsys):
    for words in (["--duration", "0"], ["--duration", "abc"], ["--reference", "0"]):
        with pytest.raises(SystemExit) as info:
            main(["demo", *words])
        assert info.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith("usage: frictiongym demo")
        assert f"frictiongym demo: error: argument {words[0]}: must be" in err


def test_every_tool_documents_overwrite(capsys):
    for tool in TOOLS:
        with pytest.raises(SystemExit):
            main([tool, "--help"])
        assert "--overwrite" in capsys.readouterr().out
