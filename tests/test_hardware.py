"""The backend contract without I/O: URIs, the base class's safety rules, run logs, timing."""

from __future__ import annotations

import gc
import json
import math
import os
from fractions import Fraction

import numpy as np
import pytest

from frictiongym.hardware import Backend, DeviceInfo, HardwareError, Sample, resolve_backend
from frictiongym.hardware.base import _OPEN, _stop_all
from frictiongym.hardware.emulated import EmulatedBackend
from frictiongym.hardware.realtime import (
    REALTIME_PRIORITY,
    freeze_heap,
    realtime_priority,
    thaw_heap,
)
from frictiongym.hardware.runlog import RunLog, Timing, read_steps
from frictiongym.hardware.serial_backend import SerialBackend


class Recorder(Backend):
    """A backend that records what reached the 'device'."""

    def __init__(self, fail_with: BaseException | None = None) -> None:
        self.sent: list[float] = []
        self.stops = 0
        self.fail_with = fail_with

    def _open(self) -> DeviceInfo:
        return DeviceInfo("rotary", 500.0, 10.0, 0.001, 2048, 0.02)

    def _start(self, zero_position: bool) -> Sample:
        return Sample(0.0, 0.0, 0, 0)

    def _exchange(self, command: float) -> Sample:
        if self.fail_with is not None:
            raise self.fail_with
        self.sent.append(command)
        return Sample(0.0, command, 0, 0)

    def _stop(self) -> None:
        self.stops += 1

    def _close(self) -> None:
        pass


@pytest.mark.parametrize(
    ("uri", "port", "baud"),
    [
        ("serial:///dev/ttyACM0", "/dev/ttyACM0", 1_000_000),
        ("serial:///dev/ttyUSB1?baud=115200", "/dev/ttyUSB1", 115200),
        ("/dev/pts/4", "/dev/pts/4", 1_000_000),
        ("socket://127.0.0.1:5000", "socket://127.0.0.1:5000", 1_000_000),
        ("COM3", "COM3", 1_000_000),
    ],
)
def test_serial_uris(uri, port, baud):
    backend = resolve_backend(uri, "rotary")
    assert isinstance(backend, SerialBackend)
    assert (backend.port, backend.baud) == (port, baud)
    assert not backend.is_open  # nothing is opened before the env needs it


def test_other_uris_and_objects():
    assert resolve_backend("sim", "rotary") is None
    assert resolve_backend(None, "altino") is None
    emulated = resolve_backend("emulator://", "altino")
    assert isinstance(emulated, EmulatedBackend)
    assert emulated.kind == "altino"
    assert resolve_backend("emulator://rotary?lockstep=1", "altino").lockstep
    recorder = Recorder()
    assert resolve_backend(recorder, "rotary") is recorder


@pytest.mark.parametrize(
    ("spec", "error", "match"),
    [
        ("ftp://host", ValueError, "unknown backend 'ftp://host'"),
        ("serial://", ValueError, "names no port"),
        ("serial:///dev/x?speed=3", ValueError, r"unknown option\(s\) speed.*accepted: baud"),
        ("serial:///dev/x?baud=fast", ValueError, "baud must be an integer, got 'fast'"),
        ("serial:///dev/x?timeout=-1", ValueError, "timeout must be a positive number"),
        ("emulator://rotary?seed=x", ValueError, "seed must be an integer"),
        ("emulator://segway", ValueError, "unknown device 'segway'"),
        ("emulator://rotary?lockstep=maybe", ValueError, "must be 1 or 0"),
        (3.5, TypeError, "URI string or a Backend"),
    ],
)
def test_bad_backends_say_what_is_accepted(spec, error, match):
    with pytest.raises(error, match=match):
        resolve_backend(spec, "rotary")


def test_the_base_class_refuses_non_finite_commands_and_saturates():
    backend = Recorder()
    backend.start()
    backend.step(3.0)
    backend.step(25.0)
    backend.step(-1e300)
    assert backend.sent == [3.0, 10.0, -10.0]
    for bad in (math.nan, math.inf, -math.inf, 10**400, np.float32("nan")):
        with pytest.raises(ValueError, match="not a finite number"):
            backend.step(bad)
    for bad in (
        "1 V",
        "1.5",
        None,
        np.datetime64("2020-01-01"),
        np.timedelta64(3, "s"),
        True,
        np.True_,
        np.array([1.0]),
        np.array(1.0),
        [1.0],
        1 + 0j,
    ):
        with pytest.raises(ValueError, match=r"must be a real number.*got .*\(\w+\)"):
            backend.step(bad)
    assert backend.sent == [3.0, 10.0, -10.0]  # nothing more reached the device
    assert backend.stops >= 16
    with pytest.raises(HardwareError, match="stopped"):
        backend.step(1.0)  # the NaN stopped it: start again first
    backend.start()
    backend.step(1.0)
    for number in (2, np.int16(-3), np.float32(0.5), Fraction(1, 4)):  # real numbers are fine
        backend.step(number)
    assert backend.sent[-5:] == [1.0, 2.0, -3.0, 0.5, 0.25]
    assert all(type(value) is float for value in backend.sent)
    backend.close()


@pytest.mark.parametrize("failure", [KeyboardInterrupt(), OSError("gone"), HardwareError("x")])
def test_any_failure_inside_a_step_stops_the_device(failure):
    backend = Recorder(fail_with=failure)
    backend.start()
    with pytest.raises(type(failure)):
        backend.step(1.0)
    assert backend.stops == 1
    assert not backend.armed


def test_open_backends_are_stopped_at_exit():
    backend = Recorder()
    backend.start()
    assert backend in _OPEN
    _stop_all()
    assert backend.stops == 1
    assert not backend.is_open
    backend.close()  # idempotent
    assert backend.stops == 1


def test_run_log_survives_an_interruption_and_refuses_to_overwrite(tmp_path):
    log = RunLog(tmp_path / "run", ("angle", "velocity"), {"device": "rotary"})
    log.record((0, 0, 0.0, 1, 2, 3, 4, 0, 0, 0, 0.5, 0.5, 0.1, 0.1, 0.0, -1.0, 0))
    log.record((0, 1, 0.002, 1, 2, 3, 4, 1, 2, 16, 0.5, 0.5, 0.2, 0.2, 50.0, -1.0, 1))
    # Not closed (as after a crash): every recorded row is already on disk.
    steps = read_steps(tmp_path / "run")
    assert steps["step"].tolist() == [0.0, 1.0]
    assert steps["late"].tolist() == [0.0, 1.0]
    assert steps["obs_velocity"].tolist() == [0.0, 50.0]
    with (tmp_path / "run" / "steps.csv").open("a") as handle:
        handle.write("0,2,0.004")  # a half-written last line is dropped
    assert len(read_steps(tmp_path / "run")["step"]) == 2
    log.close(timing={"steps": 1})
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["device"] == "rotary"
    assert meta["rows"] == 2
    assert meta["timing"] == {"steps": 1}
    with pytest.raises(FileExistsError, match="own directory"):
        RunLog(tmp_path / "run", ("angle",), {})


def test_timing_statistics():
    periods = np.array([0.002] * 98 + [0.004, 0.0021])
    timing = Timing.from_periods(periods, 0.002, late=1, skipped=2)
    assert timing.steps == 100
    assert timing.rate_hz == pytest.approx(100 / periods.sum())
    assert timing.period_p50 == pytest.approx(0.0, abs=1e-12)
    assert timing.period_max == pytest.approx(0.002)
    assert (timing.late, timing.skipped) == (1, 2)


def test_realtime_priority_says_what_it_got_and_restores_the_thread(monkeypatch):
    policy = os.sched_getscheduler(0)
    with realtime_priority() as got:
        if got == f"SCHED_FIFO {REALTIME_PRIORITY}":
            assert os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO
        else:
            assert got.startswith("ordinary, SCHED_FIFO not permitted")
    assert os.sched_getscheduler(0) == policy

    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with realtime_priority() as got:
        assert got == (
            "ordinary, SCHED_FIFO not permitted (it needs root, CAP_SYS_NICE or an rtprio limit)"
        )
    assert os.sched_getscheduler(0) == policy


def test_frozen_objects_are_thawed_when_their_last_owner_lets_go():
    first, second = object(), object()
    freeze_heap(first)
    freeze_heap(second)
    assert gc.get_freeze_count() > 0
    thaw_heap(first)
    assert gc.get_freeze_count() > 0  # the second still holds them
    thaw_heap(second)
    thaw_heap(second)  # idempotent
    assert gc.get_freeze_count() == 0


def test_echo_times_bound_the_answer_from_below_and_ignore_host_stalls():
    from frictiongym.hardware.echo import EchoTimes

    ms = 1_000_000
    echoes = EchoTimes()
    echoes.sent(1, 0)
    echoes.reading(1 * ms)  # nothing of command 1 in this read
    echoes.reading(300 * ms)  # the host stalled 299 ms; the echo was waiting in this read
    echoes.echoed(1)
    assert echoes.age() == pytest.approx(0.001)  # it had not come at 1 ms: no more is known
    echoes.sent(2, 400 * ms)
    echoes.sent(3, 402 * ms)
    echoes.reading(650 * ms)  # neither answered by 650 ms: command 2 waited at least 250 ms
    assert echoes.age() == pytest.approx(0.25)
    echoes.reading(660 * ms)
    echoes.echoed(3)  # answers 2 as well (the device held the newer one)
    assert echoes.age() == pytest.approx(0.248)
    assert echoes.ours(2)
    assert not echoes.ours(40000)
    echoes.sent(4, 700 * ms)
    echoes.forget_pending()  # an episode's stops are not waited for
    echoes.reading(900 * ms)
    assert echoes.age() == 0.0


def test_place_takes_a_finite_real_number_only():
    with EmulatedBackend("rotary", lockstep=True) as backend:
        for bad in ("3", True, math.nan, np.datetime64("2020-01-01")):
            with pytest.raises(ValueError, match="position must be a finite real number"):
                backend.place(bad)
        backend.place(np.float32(0.5))
