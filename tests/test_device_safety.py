"""Device safety under faults and untrusted input (issue 17): every path that could leave a
motor running, stale samples, signals, a second host on one port, loose commands and URIs."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from _altino_stock_device import FakeStockAltino

import frictiongym  # registers the ids
from frictiongym.controllers import PID, PIDGains
from frictiongym.envs import device as device_module
from frictiongym.hardware import (
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceNotFoundError,
    protocol,
    resolve_backend,
    stop_devices_on_signals,
    stop_signals,
)
from frictiongym.hardware.altino_frames import STOP_REPEATS
from frictiongym.hardware.altino_stock import AltinoStockBackend
from frictiongym.hardware.emulated import EmulatedBackend
from frictiongym.hardware.emulator import Emulator, Faults
from frictiongym.hardware.errors import DeviceBusyError, StaleSampleError
from frictiongym.hardware.serial_backend import SerialBackend
from frictiongym.hardware.stop_signals import STOP_SIGNALS
from frictiongym.plants.presets import ROTARY_PAPER_GAINS

SERVO = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"
STOCK_RATE = 50.0
LOCKSTEP = "emulator://rotary?lockstep=1"


def wait_until(condition: Callable[[], bool], timeout: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.005)
    return condition()


# -- item 5: every exception inside a step zeroes the motor ------------------------------------


@dataclass
class Rig:
    """An env on a device, and what its motor holds now."""

    env: Any
    motor: Callable[[], float]
    stopped: Callable[[], bool]


@pytest.fixture(params=["firmware", "stock"])
def rig(request: pytest.FixtureRequest, tmp_path: Any) -> Iterator[Rig]:
    if request.param == "firmware":
        # No watchdog: only a stop from the host can zero the motor.
        env = gym.make(SERVO, backend=f"{LOCKSTEP}&watchdog_ms=0", log=tmp_path)
        emulator = env.unwrapped.sim.backend.emulator

        def stopped() -> bool:
            return emulator.motor == 0.0 and bool(emulator.status & protocol.Status.DISABLED)

        yield Rig(env, lambda: emulator.motor, stopped)
        env.close()
        return
    with FakeStockAltino(start_cm=40.0, rate_hz=STOCK_RATE) as fake:
        backend = AltinoStockBackend(fake.port, rate_hz=STOCK_RATE, timeout=0.3)
        env = gym.make(ALTINO, backend=backend, log=tmp_path)

        def motor() -> float:
            return float(fake.commands[-1].left) if fake.commands else 0.0

        def stop_sent() -> bool:
            tail = fake.commands[-STOP_REPEATS:]
            return len(tail) == STOP_REPEATS and all(c.stop and c.left == 0 for c in tail)

        yield Rig(env, motor, stop_sent)
        env.close()


def _wrong_shape(env: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    env.step(np.array([1.0, 2.0]))


def _not_a_number(env: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    env.step(np.array(["1.5"]))


def _a_date(env: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    env.step(np.datetime64("2020-01-01"))


def _disk_full(env: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    def record(row: Any) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(env.unwrapped.sim.log, "record", record)
    env.step(np.array([-250.0]))


def _observation_fails(env: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    def observe(*args: Any) -> None:
        raise RuntimeError("observation code failed")

    monkeypatch.setattr(device_module.env_kernel, "observe_device", observe)
    env.step(np.array([-250.0]))


def _ctrl_c_inside_the_exchange(env: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    def interrupted(command: float) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(env.unwrapped.sim.backend, "_exchange", interrupted)
    env.step(np.array([-250.0]))


FAILURES: dict[str, tuple[Callable[..., None], type[BaseException]]] = {
    "wrong shape": (_wrong_shape, ValueError),
    "not a number": (_not_a_number, ValueError),
    "a date": (_a_date, ValueError),
    "disk full": (_disk_full, OSError),
    "observation fails": (_observation_fails, RuntimeError),
    "ctrl-c": (_ctrl_c_inside_the_exchange, KeyboardInterrupt),
}


@pytest.mark.parametrize("failure", list(FAILURES))
def test_every_exception_inside_a_step_zeroes_the_motor(
    rig: Rig, failure: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The stock Altino kept driving at -250 after a refused action until close()."""
    env = rig.env
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.array([-250.0 if env.unwrapped.device.name == "AltinoDistance" else 3.0]))
    assert rig.motor() != 0.0
    cause, error = FAILURES[failure]
    with pytest.raises(error):
        cause(env, monkeypatch)
    assert wait_until(rig.stopped), f"the motor still holds {rig.motor()} after: {failure}"
    monkeypatch.undo()
    env.reset()  # and the env carries on
    env.step(np.array([0.0]))


def test_a_refused_reset_option_does_not_leave_the_motor_running() -> None:
    env = gym.make(SERVO, backend=f"{LOCKSTEP}&watchdog_ms=0", log=False, max_episode_steps=3)
    emulator = env.unwrapped.sim.backend.emulator
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.array([2.0]))  # truncated by the time limit: the motor still holds 2 V
    with pytest.raises(ValueError, match="velocity"):
        env.reset(options={"velocity": 1.0})
    assert wait_until(lambda: emulator.motor == 0.0)
    env.close()


# -- item 3: a bound on a sample's age ----------------------------------------------------------


def test_a_delayed_link_stops_the_motor_instead_of_steering_on_old_samples() -> None:
    """Frames delayed by 0.2 s (100 periods): before, every step returned an old sample marked
    late and a PID loop ran past the 4 pi limit; now the step refuses it and stops the motor."""
    backend = EmulatedBackend("rotary", faults=Faults(delay=0.2), watchdog_ms=0)
    env = gym.make(SERVO, backend=backend, log=False, reference=1.0)
    emulator = backend.emulator
    assert backend.sample_age_limit == pytest.approx(0.1)  # max(5 periods, 0.1 s)
    pid = PID.for_env(env, PIDGains(**ROTARY_PAPER_GAINS))
    obs, _ = env.reset(seed=0)
    worst = 0.0
    with pytest.raises(StaleSampleError, match=r"took \d+ ms to answer a command \(limit 100 ms\)"):  # noqa: PT012
        for _ in range(200):
            obs, *_ = env.step(pid(obs))
            worst = max(worst, abs(emulator.position))
    assert wait_until(lambda: emulator.motor == 0.0)
    assert worst < 4 * np.pi
    (fault,) = env.unwrapped.sim.faults
    assert fault["error"] == "StaleSampleError"
    env.close()


def test_the_sample_age_bound_is_a_device_setting() -> None:
    assert resolve_backend("serial:///dev/x?max_age=0.5", "rotary").max_sample_age == 0.5
    stock = resolve_backend("altino-stock:///dev/x?max_age=0.3", "altino")
    assert stock.max_sample_age == 0.3
    with pytest.raises(ValueError, match="max_age must be a positive number"):
        resolve_backend("serial:///dev/x?max_age=0", "rotary")
    emulated = resolve_backend("emulator://rotary?lockstep=1&max_age=0.3", "rotary")
    assert emulated.max_sample_age == 0.3
    altino = EmulatedBackend("altino", lockstep=True)
    with altino:
        assert altino.sample_age_limit == pytest.approx(0.25)  # 5 periods of 50 ms
        sample = altino.start()
        assert 0.0 <= sample.age < altino.sample_age_limit


# -- item 6: SIGTERM and SIGHUP stop the motor ----------------------------------------------------

DRIVER = """
import sys
from frictiongym.hardware.altino_stock import AltinoStockBackend
from frictiongym.hardware.serial_backend import SerialBackend

kind, port = sys.argv[1:]
if kind == "stock":
    backend = AltinoStockBackend(port, rate_hz=50.0)
    command = -250.0
else:
    backend = SerialBackend(port)
    command = 2.0
backend.start()
backend.step(command)
print("driving", flush=True)
while True:
    backend.step(command)
"""


@pytest.mark.parametrize("sig", STOP_SIGNALS, ids=lambda s: signal.Signals(s).name)
@pytest.mark.parametrize("kind", ["firmware", "stock"])
def test_a_terminated_process_stops_the_motor_first(kind: str, sig: int) -> None:
    """`kill PID` or a closed terminal: atexit does not run, and a stock Altino (no watchdog)
    kept its last command indefinitely. Here the device's watchdog is off too."""
    device = Emulator("rotary", watchdog_ms=0) if kind == "firmware" else FakeStockAltino()
    with device:
        port = device.serve_pty() if kind == "firmware" else device.port
        child = subprocess.Popen(
            [sys.executable, "-c", DRIVER, kind, port],
            stdout=subprocess.PIPE,
            text=True,
            cwd=Path(frictiongym.__file__).parents[1],  # this checkout's frictiongym
        )
        try:
            assert child.stdout is not None
            assert child.stdout.readline() == "driving\n"
            if kind == "firmware":
                assert wait_until(lambda: device.motor == 2.0)
            else:
                assert wait_until(lambda: device.commands[-1].left == -250)
            child.send_signal(sig)
            assert child.wait(10) == 128 + sig  # SystemExit: finally blocks and atexit ran
        finally:
            child.kill()
            child.wait()
        if kind == "firmware":
            assert wait_until(lambda: device.motor == 0.0)
            assert not device.status & protocol.Status.WATCHDOG  # a stop, not a watchdog
        else:
            assert wait_until(lambda: device.commands[-1].stop and device.commands[-1].left == 0)


def test_stop_signals_hand_over_to_the_previous_handler_and_are_restored() -> None:
    seen: list[int] = []

    def previous(signum: int, frame: Any) -> None:
        seen.append(signum)

    before = signal.signal(signal.SIGTERM, previous)
    try:
        with EmulatedBackend("rotary", lockstep=True) as backend:
            assert signal.getsignal(signal.SIGTERM) is not previous  # ours, while a device is open
            backend.start()
            backend.step(1.0)
            os.kill(os.getpid(), signal.SIGTERM)
            assert wait_until(lambda: seen == [signal.SIGTERM])
            assert not backend.armed  # stopped first, then the previous handler ran
            assert wait_until(lambda: backend.emulator.motor == 0.0)
        assert signal.getsignal(signal.SIGTERM) is previous  # restored on close
    finally:
        signal.signal(signal.SIGTERM, before)


def test_an_ignored_hangup_stays_ignored_and_threads_install_nothing() -> None:
    before = signal.signal(signal.SIGHUP, signal.SIG_IGN)  # as under nohup
    try:
        with EmulatedBackend("rotary", lockstep=True):
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
        handlers = signal.getsignal(signal.SIGTERM)
        errors: list[BaseException] = []

        def open_in_a_thread() -> None:
            try:
                with EmulatedBackend("rotary", lockstep=True) as backend:
                    backend.start()
            except BaseException as exc:  # reported below
                errors.append(exc)

        def run_in_a_thread() -> None:
            thread = threading.Thread(target=open_in_a_thread)
            thread.start()
            thread.join()

        stop_signals._warned = False  # warned once per process: maybe by an earlier test
        with pytest.warns(RuntimeWarning, match="stop_devices_on_signals"):
            run_in_a_thread()
        assert not errors
        assert signal.getsignal(signal.SIGTERM) is handlers
    finally:
        signal.signal(signal.SIGHUP, before)


THREAD_DRIVER = """
import sys, threading, time
from frictiongym.hardware import stop_devices_on_signals
from frictiongym.hardware.altino_stock import AltinoStockBackend

stop_devices_on_signals()  # in the main thread, before the worker opens the device


def drive():
    backend = AltinoStockBackend(sys.argv[1], rate_hz=50.0)
    backend.start()
    backend.step(-250.0)
    print("driving", flush=True)
    while True:
        backend.step(-250.0)


threading.Thread(target=drive, daemon=True).start()
while True:
    time.sleep(0.05)
"""


def test_a_device_opened_in_a_worker_thread_stops_on_sigterm() -> None:
    """A stock Altino opened outside the main thread kept driving after SIGTERM (no handler
    could be installed there); the main thread can now install one for good beforehand."""
    with FakeStockAltino() as car:
        child = subprocess.Popen(
            [sys.executable, "-c", THREAD_DRIVER, car.port],
            stdout=subprocess.PIPE,
            text=True,
            cwd=Path(frictiongym.__file__).parents[1],
        )
        try:
            assert child.stdout is not None
            assert child.stdout.readline() == "driving\n"
            assert wait_until(lambda: car.commands[-1].left == -250)
            child.send_signal(signal.SIGTERM)
            assert child.wait(10) == 128 + signal.SIGTERM
        finally:
            child.kill()
            child.wait()
        assert wait_until(lambda: car.commands[-1].stop and car.commands[-1].left == 0)


def test_stop_devices_on_signals_keeps_its_handlers_and_refuses_other_threads() -> None:
    before = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
    try:
        stop_devices_on_signals()
        with EmulatedBackend("rotary", lockstep=True):
            pass
        assert all(signal.getsignal(sig) is not before[sig] for sig in STOP_SIGNALS)
        errors: list[BaseException] = []
        thread = threading.Thread(target=lambda: _capture(stop_devices_on_signals, errors))
        thread.start()
        thread.join()
        assert isinstance(errors[0], RuntimeError)
    finally:
        stop_signals._kept = False
        stop_signals.release_stop_signals()
        for sig, handler in before.items():
            signal.signal(sig, handler)


def _capture(function: Any, errors: list[BaseException]) -> None:
    try:
        function()
    except BaseException as exc:  # reported by the caller
        errors.append(exc)


# -- item 7: one host per port -----------------------------------------------------------------


@pytest.fixture
def served() -> Iterator[tuple[Emulator, SerialBackend]]:
    with Emulator("rotary", lockstep=True, watchdog_ms=0) as emulator:
        backend = SerialBackend(emulator.serve_pty())
        backend.start()
        backend.step(1.0)
        yield emulator, backend
        backend.close()


def test_a_second_open_of_a_port_is_refused_and_names_who_holds_it(served: Any) -> None:
    emulator, first = served
    second = SerialBackend(first.port)
    with pytest.raises(DeviceBusyError, match=rf"in use by another program \(pid {os.getpid()}"):
        second.open()
    assert first.step(1.5).applied == 1.5  # the first keeps working
    assert emulator.motor == 1.5


def test_a_second_open_of_a_stock_altino_is_refused_too() -> None:
    with FakeStockAltino(rate_hz=STOCK_RATE) as fake:
        with AltinoStockBackend(fake.port, rate_hz=STOCK_RATE) as first:
            first.start()
            with pytest.raises(DeviceBusyError, match="in use by another program"):
                AltinoStockBackend(fake.port, rate_hz=STOCK_RATE).open()
            first.step(-100.0)
            assert wait_until(lambda: fake.commands[-1].left == -100)


def _intruder(port: str, message: protocol.Message) -> None:
    """Another program that opens the port without a lock and writes ``message``."""
    fd = os.open(port, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(fd, protocol.encode(message))
        time.sleep(0.05)
    finally:
        os.close(fd)


@pytest.mark.parametrize(
    ("message", "sign"),
    [
        (protocol.HelloRequest(), "answered a Hello request this host never sent"),
        (
            protocol.Command(seq=40000, command=500, flags=protocol.Flag.ENABLE),
            "holds command 40000",
        ),
    ],
)
def test_a_second_host_is_named_not_blamed_on_the_power_supply(
    served: Any, message: protocol.Message, sign: str
) -> None:
    emulator, backend = served
    _intruder(backend.port, message)
    with pytest.raises(DeviceFaultError, match=f"another program is talking.*{sign}"):  # noqa: PT012
        for _ in range(5):
            backend.step(1.0)
    assert wait_until(lambda: emulator.motor == 0.0)


def test_a_late_answer_to_our_own_handshake_is_not_a_second_host(served: Any) -> None:
    """A booting board may answer two of the handshake's repeated requests."""
    emulator, backend = served
    backend._hellos_due, backend._late_hellos_until = 1, time.monotonic() + 0.5
    _intruder(backend.port, protocol.HelloRequest())  # its answer stands for our second one
    for _ in range(5):
        backend.step(1.0)
    assert backend._hellos_due == 0
    assert emulator.motor == 1.0


def test_a_restarted_device_is_still_called_restarted() -> None:
    backend = SerialBackend("/dev/null")
    backend._echoed = True
    backend._last = protocol.State(
        protocol.Status(0), seq=5000, tick_us=10_000_000, seq_applied=7, applied=0, sensor=0
    )
    rebooted = protocol.State(
        protocol.Status.DISABLED, seq=3, tick_us=6000, seq_applied=0, applied=0, sensor=0
    )
    error = backend._restarted_or_second_host(rebooted)
    assert error is not None
    assert "restarted mid-run" in str(error)
    running = protocol.State(
        protocol.Status(0), seq=5001, tick_us=10_002_000, seq_applied=9, applied=0, sensor=0
    )
    assert "another program" in str(backend._restarted_or_second_host(running))


def test_a_second_client_of_a_tcp_emulator_is_told_at_once() -> None:
    """Before, it waited for the 3 s handshake and got a timeout that blamed the firmware."""
    with Emulator("rotary", lockstep=True, watchdog_ms=0) as emulator:
        url = emulator.serve_tcp()
        with SerialBackend(url) as first:
            first.start()
            started = time.monotonic()
            with pytest.raises(DeviceDisconnectedError, match="serves one host at a time"):
                SerialBackend(url).open()
            assert time.monotonic() - started < 1.0
            assert first.step(0.5).applied == 0.5  # the first host keeps its device


# -- item 11: URIs that surfaced pyserial's internals or were misread ---------------------------


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("socket://127.0.0.1", "socket://127.0.0.1 names no port; e.g. socket://127.0.0.1:5000"),
        ("socket://host:abc", "the port must be a number in 0..65535"),
        ("socket://:5000", "names no host"),
        ("serial:///dev/x?baud=9600&baud=115200", "option baud is given twice"),
        ("emulator://rotary?seed=1&seed=2", "option seed is given twice"),
        ("SIM", "the simulator is 'sim'"),
        ("Sim://", "the simulator is 'sim'"),
        ("socket://127.0.0.1:5000?max_age=abc", "max_age must be a positive number, got 'abc'"),
        ("socket://127.0.0.1:5000?max_age=", "max_age must be a positive number, got ''"),
        ("socket://127.0.0.1:5000?bogus=1", "unknown option.* bogus in socket://127.0.0.1:5000"),
    ],
)
def test_uris_say_what_is_wrong(spec: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        resolve_backend(spec, "rotary")


def test_uris_of_the_simulator_and_of_sockets_still_work() -> None:
    assert resolve_backend("sim", "rotary") is None
    backend = resolve_backend("socket://127.0.0.1:5000", "rotary")
    assert isinstance(backend, SerialBackend)
    # The backend's own options on a network link (they went to pyserial, which refused them
    # with its internals); pyserial's own stay in its URL.
    backend = resolve_backend("socket://127.0.0.1:5000?max_age=0.5&logging=debug", "rotary")
    assert (backend.port, backend.max_sample_age) == ("socket://127.0.0.1:5000?logging=debug", 0.5)
    assert gym.make(SERVO, backend="sim").unwrapped.on_device is False
    with pytest.raises(ValueError, match="the simulator is 'sim'"):
        gym.make(SERVO, backend="SIM")


def test_a_refused_connection_and_a_second_reader_are_named() -> None:
    import serial

    backend = resolve_backend("socket://127.0.0.1:1", "rotary")  # nothing listens on port 1
    with pytest.raises(DeviceNotFoundError, match=r"could not connect to .* the emulator"):
        backend.open()

    class Shared:  # what pyserial says when another program took the bytes first
        in_waiting = 0

        def read(self, size: int) -> bytes:
            raise serial.SerialException(
                "device reports readiness to read but returned no data (device disconnected "
                "or multiple access on port?)"
            )

    reader = SerialBackend("/dev/ttyX")
    reader._serial = Shared()
    with pytest.raises(DeviceDisconnectedError, match="another program is probably reading"):
        reader._read_available()


def test_a_slow_host_is_not_a_stale_link() -> None:
    """Time the host spends between steps or stalled (a slow controller, a garbage collection)
    does not count as the device's delay: only a late answer does."""
    env = gym.make(SERVO, backend=LOCKSTEP, log=False)
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.array([0.5]))
        time.sleep(0.15)  # longer than the 0.1 s bound, less than the lock-step watchdog
    assert env.unwrapped.sim.last_sample.age < 0.1
    env.close()
