"""frictiongym sim2real on the emulator: the report, the gap, what friction modelling closes."""

from __future__ import annotations

import gc
import json
import select
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from frictiongym.cli import main
from frictiongym.controllers import PIDGains
from frictiongym.hardware.errors import DeviceTimeoutError
from frictiongym.metrics import response_metrics
from frictiongym.sim2real import fit_percent, rmse, run_sim2real, write_report

SERVO = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"


def test_rmse_and_fit_are_exact_on_known_signals():
    y = np.array([0.0, 1.0, 2.0, 3.0])
    assert rmse(y, y + 0.5) == 0.5
    assert fit_percent(y, y) == 100.0
    assert fit_percent(np.full(4, y.mean()), y) == 0.0


@pytest.mark.parametrize("controller", ["pid", "compensated"])
def test_the_friction_model_closes_most_of_the_gap_on_the_emulated_servo(tmp_path, controller):
    result = run_sim2real(
        SERVO,
        "emulator://rotary?lockstep=1&noise=1",
        controller=controller,
        repeats=3,
        steps=750,
        log=tmp_path / "log",
    )
    assert len(result.device) == 3
    # The emulated device is the paper's plant: its friction model is far closer than the
    # frictionless nominal one, down to the device's own spread (its sensor noise).
    nominal, friction = result.gap("nominal", "output"), result.gap("friction", "output")
    assert friction < 0.2 * nominal
    assert result.spread("output") > 0.0
    assert friction < 5 * result.spread("output") + 1e-3
    path = write_report(result, tmp_path / "out", "frictiongym sim2real ...", figures=True)
    text = path.read_text()
    assert "## Gap to the device" in text
    assert "closes" in text
    for name in ("overlay.png", "timing.png", "sim2real.json"):
        assert (tmp_path / "out" / name).stat().st_size > 1000
    data = json.loads((tmp_path / "out" / "sim2real.json").read_text())
    assert data["gap_closed"]["friction"]["output"] > 0.8
    assert data["timing"]["steps"] == 3 * 750
    # Every step metric is of the output the controller measured, as on the device.
    runs = [*result.device, *result.models.values()]
    metrics = [*data["device_metrics"], *data["model_metrics"].values()]
    for run, recorded in zip(runs, metrics, strict=True):
        measured = run.signal("measured")
        expected = response_metrics(
            run.t, measured, run.signal("reference")[-1], run.signal("command"), y0=measured[0]
        ).as_dict()
        assert json.dumps(recorded) == json.dumps(expected)


def test_an_identified_model_and_explicit_gains_are_used(tmp_path):
    from frictiongym.friction.presets import ALTINO_PAPER
    from frictiongym.params import DeviceParams, save_params
    from frictiongym.plants.presets import ALTINO_PLANT

    params = tmp_path / "friction.json"
    total_damping = ALTINO_PLANT.damping + ALTINO_PAPER.viscous  # B of a file is the total
    save_params(
        params,
        DeviceParams.from_model(
            ALTINO_PAPER,
            inertia=ALTINO_PLANT.inertia,
            damping=total_damping,
            law="paper",
            device="AltinoDistance",
        ),
    )
    result = run_sim2real(
        ALTINO,
        "emulator://altino?lockstep=1",
        params=str(params),
        repeats=1,
        steps=200,
        gains=PIDGains(25.0, 10.0, 12.0),
        log=False,
    )
    assert set(result.models) == {"nominal", "friction", "identified"}
    assert result.gains == {"kp": 25.0, "ki": 10.0, "kd": 12.0}
    assert result.gap("identified", "output") < result.gap("nominal", "output")


def test_the_command_writes_the_report_and_refuses_bad_input(tmp_path, capsys):
    out = tmp_path / "report"
    status = main(
        [
            "sim2real",
            "--env",
            SERVO,
            "--backend",
            "emulator://rotary?lockstep=1",
            "--repeats",
            "2",
            "--steps",
            "300",
            "--out",
            str(out),
            "--no-figures",
        ]
    )
    assert status == 0
    assert "friction" in capsys.readouterr().out
    assert (out / "report.md").exists()
    (log,) = (out / "device-logs").iterdir()
    assert (log / "steps.csv").exists()
    rerun = [
        "sim2real",
        "--env",
        SERVO,
        "--backend",
        "emulator://rotary?lockstep=1",
        "--repeats",
        "1",
        "--steps",
        "10",
        "--out",
        str(out),
        "--quiet",
    ]
    assert main(rerun) == 2  # the earlier report is not replaced without --overwrite
    assert "give --overwrite" in capsys.readouterr().err
    assert main([*rerun, "--overwrite"]) == 0
    assert len(list((out / "device-logs").iterdir())) == 2  # a rerun keeps the first log
    file = tmp_path / "a-file"
    file.write_text("x")
    assert main(["sim2real", "--env", SERVO, "--backend", "emulator://", "--out", str(file)]) == 2
    assert (
        main(
            [
                "sim2real",
                "--env",
                SERVO,
                "--backend",
                "/dev/frictiongym-none",
                "--out",
                str(tmp_path / "x"),
            ]
        )
        == 2
    )
    assert "could not open" in capsys.readouterr().err
    assert (
        main(
            [
                "sim2real",
                "--env",
                "frictiongym/Nope-v0",
                "--backend",
                "emulator://",
                "--out",
                str(tmp_path / "y"),
            ]
        )
        == 2
    )
    assert "unknown env id 'frictiongym/Nope-v0'" in capsys.readouterr().err


def test_a_reference_beyond_the_safety_limit_is_refused_up_front(tmp_path, capsys):
    out = tmp_path / "out"
    assert (
        main(
            [
                "sim2real",
                "--env",
                SERVO,
                "--backend",
                "emulator://rotary?lockstep=1",
                "--reference",
                "100",
                "--out",
                str(out),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "reference 100 rad lies beyond the safety limit of 12.57 rad of a QUBE-Servo 2" in err
    assert not out.exists()
    with pytest.raises(ValueError, match="at or behind the safety limit of 0 cm"):
        run_sim2real(ALTINO, "emulator://altino?lockstep=1", reference=-2.0, log=False)
    # Beyond the IR sensor's farthest reading the car never sees the target (it backed away
    # blind at full reverse for the whole run, and the report said "complete").
    with pytest.raises(ValueError, match=r"beyond the IR sensor's range .* at most 21 cm"):
        run_sim2real(ALTINO, "emulator://altino?lockstep=1", reference=30.0, log=False)


def test_runs_the_safety_limit_ends_are_reported_not_compared(tmp_path, capsys):
    """12.5 rad is inside the 4π limit, but the paper's PID overshoots past it after ~90 steps:
    every run ends there, so there is nothing to compare, and the report says why."""
    out = tmp_path / "out"
    status = main(
        [
            "sim2real",
            "--env",
            SERVO,
            "--backend",
            "emulator://rotary?lockstep=1",
            "--reference",
            "12.5",
            "--repeats",
            "2",
            "--steps",
            "300",
            "--out",
            str(out),
            "--no-figures",
        ]
    )
    err = capsys.readouterr().err
    assert status == 1
    assert "error: no device run completed (2 by the safety limit)" in err
    data = json.loads((out / "sim2real.json").read_text())
    assert data["complete_runs"] == 0
    assert [run["ended"] for run in data["runs"]] == ["safety limit"] * 2
    assert all(80 < run["steps"] < 120 for run in data["runs"])
    assert data["gap"] is None
    assert data["gap_closed"] is None
    assert data["model_stops"]["friction"] is not None
    text = (out / "report.md").read_text()
    assert "the safety limit ended it after" in text
    assert "(\\|angle\\| passed 12.57 rad) |" in text  # escaped: one cell in the runs table
    assert "No device run completed, so there is no gap to report." in text
    assert "closes" not in text


class _StallingController:
    """The paper's controller, but the host stalls past the watchdog at one step of one run."""

    def __init__(self, controller, run, step, seconds):
        self.controller, self.run, self.step, self.seconds = controller, run, step, seconds
        self.runs, self.steps = 0, 0

    def __getattr__(self, name):
        return getattr(self.controller, name)

    def reset(self):
        self.runs, self.steps = self.runs + 1, 0
        self.controller.reset()

    def __call__(self, obs):
        self.steps += 1
        if (self.runs, self.steps) == (self.run, self.step):
            time.sleep(self.seconds)
        return self.controller(obs)


def test_a_watchdog_trip_marks_its_run_and_the_others_go_on(tmp_path, monkeypatch):
    import frictiongym.sim2real.run as run_module

    original = run_module.build_controller
    monkeypatch.setattr(
        run_module,
        "build_controller",
        lambda env, kind, gains: _StallingController(original(env, kind, gains), 2, 100, 0.3),
    )
    result = run_sim2real(
        SERVO,
        "emulator://rotary?lockstep=1&watchdog_ms=100",
        repeats=3,
        steps=300,
        log=tmp_path / "log",
    )
    assert [run.ended for run in result.runs] == ["complete", "watchdog", "complete"]
    assert result.runs[1].steps == 99
    assert "watchdog tripped" in result.runs[1].detail
    assert len(result.device) == 2
    assert result.gap("friction", "output") < result.gap("nominal", "output")
    path = write_report(result, tmp_path / "out", "frictiongym sim2real ...", figures=False)
    text = path.read_text()
    assert "| 2 | 99 | **watchdog**:" in text
    assert "1 of 3 runs (2) ended early and is left out" in text
    assert "the 2 runs that completed" in text
    data = json.loads((tmp_path / "out" / "sim2real.json").read_text())
    assert (data["repeats"], data["complete_runs"]) == (3, 2)
    assert data["runs"][1]["ended"] == "watchdog"
    (fault,) = json.loads((tmp_path / "log" / "meta.json").read_text())["faults"]
    assert (fault["episode"], fault["error"]) == (1, "WatchdogTripError")


class _FreezingController(_StallingController):
    """The paper's controller; at one step of one run the device sends nothing until the host
    has given up on that step (a stalled emulator or link, which then recovers)."""

    def __init__(self, controller, env, run, step):
        super().__init__(controller, run, step, 0.0)
        backend = env.unwrapped.sim.backend
        self.emulator, step_on_device = backend.emulator, backend.step

        def step_then_thaw(command):
            try:
                return step_on_device(command)
            except DeviceTimeoutError:
                self.emulator._frozen = False
                raise

        backend.step = step_then_thaw

    def __call__(self, obs):
        self.steps += 1
        if (self.runs, self.steps) == (self.run, self.step):
            self.emulator.freeze()
        return self.controller(obs)


def test_a_link_fault_marks_its_run_and_the_others_go_on(tmp_path, monkeypatch, capsys):
    """No state frame in time in run 2 (a stalled emulator or link): that run is marked and
    left out, the others run, and the report says so (before, the whole command failed)."""
    import frictiongym.sim2real.run as run_module

    original = run_module.build_controller
    monkeypatch.setattr(
        run_module,
        "build_controller",
        lambda env, kind, gains: _FreezingController(original(env, kind, gains), env, 2, 50),
    )
    out = tmp_path / "out"
    argv = ["sim2real", "--env", SERVO, "--backend", "emulator://rotary?lockstep=1"]
    status = main([*argv, "--repeats", "3", "--steps", "200", "--out", str(out), "--no-figures"])
    err = capsys.readouterr().err
    assert status == 0
    assert "device run 2 ended by the link after 49 steps: no state frame" in err
    data = json.loads((out / "sim2real.json").read_text())
    assert [run["ended"] for run in data["runs"]] == ["complete", "link", "complete"]
    assert data["complete_runs"] == 2
    text = (out / "report.md").read_text()
    assert "| 2 | 49 | **link**: no state frame" in text
    assert "A link fault means no state frame came in time" in text


def test_a_device_gone_mid_run_ends_the_runs_and_keeps_the_report(tmp_path, monkeypatch, capsys):
    import frictiongym.sim2real.run as run_module

    class Unplugging(_StallingController):
        def __call__(self, obs):
            self.steps += 1
            if (self.runs, self.steps) == (self.run, self.step):
                self.controller.env_unplug()
            return self.controller(obs)

    original = run_module.build_controller

    def build(env, kind, gains):
        controller = original(env, kind, gains)
        controller.env_unplug = env.unwrapped.sim.backend.emulator.unplug
        return Unplugging(controller, 2, 30, 0.0)

    monkeypatch.setattr(run_module, "build_controller", build)
    out = tmp_path / "out"
    argv = ["sim2real", "--env", SERVO, "--backend", "emulator://rotary?lockstep=1"]
    status = main([*argv, "--repeats", "3", "--steps", "100", "--out", str(out), "--no-figures"])
    err = capsys.readouterr().err
    assert status == 0, err
    assert "device run 2 ended by a disconnect after 29 steps" in err
    data = json.loads((out / "sim2real.json").read_text())
    assert [run["ended"] for run in data["runs"]] == ["complete", "disconnect"]
    assert "the runs after it were not tried" in (out / "report.md").read_text()


class _CollectingController(_StallingController):
    """The paper's controller, and a full garbage collection at one step of every run."""

    def __call__(self, obs):
        self.steps += 1
        if self.steps == self.step:
            gc.collect()
        return self.controller(obs)


def test_the_device_example_holds_up_with_a_core_busy(tmp_path, monkeypatch):
    """The README's two shells: ``frictiongym emulate`` in another process, sim2real on its pty
    in this one, while a third process keeps a core busy and, in the middle of every run, a full
    garbage collection runs over a large heap (a few tens of ms unfrozen: longer than the old
    20 ms watchdog). Every run completes, with no fault in the device log."""
    import frictiongym.sim2real.run as run_module

    heap = [[] for _ in range(1_000_000)]  # a large process, as one that has imported torch
    original = run_module.build_controller
    monkeypatch.setattr(
        run_module,
        "build_controller",
        lambda env, kind, gains: _CollectingController(original(env, kind, gains), 0, 300, 0.0),
    )
    # Each in a session of its own, as from other shells (Linux shares a session's CPU time).
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)
    emulator = subprocess.Popen(
        [sys.executable, "-m", "frictiongym.cli", "emulate", "--device", "rotary", "--quiet"],
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        ready, _, _ = select.select([emulator.stdout], [], [], 60.0)
        assert ready, "the emulator printed no port"
        port = emulator.stdout.readline().strip()
        result = run_sim2real(SERVO, f"serial://{port}", repeats=3, steps=750, log=tmp_path / "log")
    finally:
        busy.kill()
        emulator.send_signal(signal.SIGINT)
        busy.wait()
        emulator.wait(timeout=10)
    assert len(heap) == 1_000_000
    assert [run.ended for run in result.runs] == ["complete"] * 3
    assert result.timing.steps == 3 * 750
    assert "faults" not in json.loads((tmp_path / "log" / "meta.json").read_text())


def test_a_run_the_altino_guard_stops_is_told_from_one_the_safety_limit_ends():
    from types import SimpleNamespace

    from frictiongym import devices
    from frictiongym.controllers import Rollout
    from frictiongym.hardware import Sample
    from frictiongym.hardware.protocol import Status
    from frictiongym.sim2real.run import DEVICE_LIMIT, SAFETY_LIMIT, _ended_early

    zeros = np.zeros(80)
    trace = Rollout.of_one_run(np.arange(80) * 0.05, terminated=True, measured=zeros)
    guard = SimpleNamespace(last_sample=Sample(0.0, 0.0, 0, 0, status=int(Status.LIMIT)))
    assert _ended_early(guard, trace, 0.0, devices.ALTINO) == (
        DEVICE_LIMIT,
        "the device's distance guard stopped it after 79 steps",
    )
    wall = SimpleNamespace(last_sample=Sample(0.0, 0.0, 0, 0))
    assert _ended_early(wall, trace, 0.0, devices.ALTINO) == (
        SAFETY_LIMIT,
        "the safety limit ended it after 79 steps (its distance fell to 0 cm)",
    )
    _, detail = _ended_early(wall, trace, 12.566, devices.ROTARY)
    assert detail.endswith("(|angle| passed 12.57 rad)")
