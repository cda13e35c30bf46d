"""QuanserHILBackend against a fake ``quanser.hardware`` that simulates a QUBE-Servo 2."""

from __future__ import annotations

import math
import sys

import gymnasium as gym
import pytest
from _altino_stock_device import StepSim
from _fake_quanser import FakeBoard, HILError, install

from frictiongym.devices import ROTARY
from frictiongym.hardware import resolve_backend
from frictiongym.hardware.errors import (
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    HardwareError,
    SDKNotAvailableError,
)
from frictiongym.hardware.protocol import Status
from frictiongym.hardware.quanser_hil import AUTO_WATCHDOG_S, QuanserHILBackend

RATE = 500.0
STEP = 2.0 * math.pi / 2048


@pytest.fixture
def board(monkeypatch: pytest.MonkeyPatch) -> FakeBoard:
    return install(monkeypatch)


def assert_shut_down(board: FakeBoard) -> None:
    """0 V was written after the last nonzero voltage, the amplifier disabled after its enable."""
    analog = [(i, args[2][0]) for i, (n, args) in enumerate(board.calls) if n == "write_analog"]
    digital = [(i, args[2][0]) for i, (n, args) in enumerate(board.calls) if n == "write_digital"]
    last_drive = max((i for i, volts in analog if volts != 0.0), default=-1)
    assert any(volts == 0.0 and i > last_drive for i, volts in analog)
    last_enable = max((i for i, on in digital if on), default=-1)
    assert any(not on and i > last_enable for i, on in digital)
    assert "task_stop" in board.names()
    assert "task_delete" in board.names()
    assert board.voltage == 0.0
    assert not board.enabled


def run(backend: QuanserHILBackend, steps: int, command: float = 1.0) -> None:
    for _ in range(steps):
        backend.step(command)


def test_missing_sdk_says_where_to_get_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "quanser.hardware", None)  # an import of it fails
    backend = QuanserHILBackend()  # configuration only: nothing imported yet
    with pytest.raises(SDKNotAvailableError, match="not on PyPI") as caught:
        backend.open()
    message = str(caught.value)
    assert "hil_sdk_linux_x86_64" in message
    assert "serial://" in message
    assert "firmware/qube_bridge" in message
    assert isinstance(caught.value, ImportError)


def test_open_leaves_the_motor_off(board: FakeBoard) -> None:
    with QuanserHILBackend(rate_hz=RATE) as backend:
        info = backend.info
        assert info is not None
        assert (info.kind, info.counts_per_rev, info.command_limit) == ("rotary", 2048, 10.0)
        assert info.watchdog_s == AUTO_WATCHDOG_S
        assert "2024.1.0" in info.firmware
        assert board.voltage == 0.0
        assert not board.enabled
    assert not board.is_open


def test_pid_run_matches_the_simulator(board: FakeBoard) -> None:
    kp, ki, kd, target = 8.0, 2.0, 0.3, 1.0
    sim = StepSim(ROTARY, 0.0, 1.0 / RATE)
    with QuanserHILBackend(rate_hz=RATE) as backend:
        sample = backend.start()
        integral, previous = 0.0, sample.measured
        for _ in range(500):
            assert sample.measured == pytest.approx(sim.measured, abs=1e-6)
            error = target - sample.measured
            integral += error / RATE
            u = kp * error + ki * integral - kd * (sample.measured - previous) * RATE
            previous = sample.measured
            sample = backend.step(u)
            sim.step(min(max(u, -10.0), 10.0))
            assert sample.applied == pytest.approx(min(max(u, -10.0), 10.0))
        assert abs(sample.measured - target) < 0.05
        assert sample.seq == 500
        assert sample.tick_us == 1_000_000
    assert board.reloads == 500
    assert_shut_down(board)


def test_saturation_and_nan(board: FakeBoard) -> None:
    with QuanserHILBackend(rate_hz=RATE, voltage_limit=6.0) as backend:
        backend.start()
        assert backend.step(50.0).applied == 6.0
        assert backend.step(-1e9).applied == -6.0
        with pytest.raises(ValueError, match="not a finite number"):
            backend.step(math.nan)
        assert_shut_down(board)
        with pytest.raises(HardwareError, match=r"start\(\) it again"):
            backend.step(1.0)
    volts = board.written("write_analog")
    assert all(math.isfinite(v) and abs(v) <= 6.0 for v in volts)
    assert 6.0 in volts
    assert -6.0 in volts


def test_exception_inside_a_step_shuts_down(board: FakeBoard) -> None:
    backend = QuanserHILBackend(rate_hz=RATE)
    backend.start()
    backend.step(3.0)
    board.fail["task_read_encoder"] = HILError(-27, "The communications link was lost")
    with pytest.raises(DeviceDisconnectedError, match="communications link was lost"):
        backend.step(3.0)
    assert_shut_down(board)
    backend.close()
    assert not board.is_open


def test_keyboard_interrupt_inside_a_step_shuts_down(board: FakeBoard) -> None:
    def interrupt() -> None:
        raise KeyboardInterrupt

    backend = QuanserHILBackend(rate_hz=RATE)
    backend.start()
    backend.step(4.0)
    board.hooks["task_read_encoder"] = interrupt
    with pytest.raises(KeyboardInterrupt):
        backend.step(4.0)
    assert_shut_down(board)
    backend.close()


def test_close_shuts_down_in_order(board: FakeBoard) -> None:
    backend = QuanserHILBackend(rate_hz=RATE)
    backend.start()
    backend.step(2.0)
    start = len(board.calls)
    backend.close()
    names = board.names()[start:]
    assert names[0] == "write_analog"  # 0 V first
    assert names.index("task_stop") < names.index("task_delete") < names.index("write_digital")
    assert names[-1] == "close"
    assert_shut_down(board)


def test_a_failing_shutdown_step_does_not_skip_the_others(board: FakeBoard) -> None:
    backend = QuanserHILBackend(rate_hz=RATE)
    backend.start()
    backend.step(2.0)
    board.fail["task_stop"] = HILError(-1, "task_stop failed")
    backend.close()
    assert_shut_down(board)


@pytest.mark.parametrize(
    ("method", "message", "error"),
    [
        ("open", "Board not found", DeviceNotFoundError),
        ("task_read_encoder", "The operation timed out", DeviceTimeoutError),
        ("write_analog", "Device removed", DeviceDisconnectedError),
    ],
)
def test_hil_errors_map_to_ours(
    board: FakeBoard, method: str, message: str, error: type[HardwareError]
) -> None:
    backend = QuanserHILBackend(rate_hz=RATE)
    if method != "open":
        backend.start()
    board.fail[method] = HILError(-33, message)
    with pytest.raises(error, match=message) as caught:
        backend.step(1.0)
    assert "HIL error -33" in str(caught.value)
    if method == "open":
        assert "no other program" in str(caught.value)
        assert not backend.is_open
    backend.close()


def test_watchdog_when_enabled(board: FakeBoard) -> None:
    with QuanserHILBackend(rate_hz=RATE, watchdog_s=0.05) as backend:
        assert backend.info is not None
        assert backend.info.watchdog_s == 0.05
        backend.start()
        for _ in range(3):
            backend.step(1.0)
    names = board.names()
    assert "watchdog_set_analog_expiration_state" in names
    assert "watchdog_set_digital_expiration_state" in names
    assert ("watchdog_start", (0.05,)) in board.calls
    assert board.reloads == 3
    assert names.index("watchdog_start") < names.index("watchdog_reload")
    assert "watchdog_stop" in names


def test_watchdog_expiry_is_a_fault(board: FakeBoard) -> None:
    backend = QuanserHILBackend(rate_hz=RATE)
    backend.start()
    board.expired = True
    with pytest.raises(DeviceFaultError, match=r"watchdog .* expired"):
        backend.step(1.0)
    assert_shut_down(board)
    backend.close()


def test_watchdog_off_or_unsupported(monkeypatch: pytest.MonkeyPatch) -> None:
    board = install(monkeypatch)
    with QuanserHILBackend(watchdog_s=0) as backend:
        backend.start()
        backend.step(1.0)
        assert backend.info is not None
        assert backend.info.watchdog_s is None
    assert "watchdog_start" not in board.names()
    board = install(monkeypatch, watchdog=False)
    with QuanserHILBackend() as backend:
        assert backend.info is not None
        assert backend.info.watchdog_s is None
        backend.start()
        backend.step(1.0)
    with pytest.raises(HardwareError, match="has no HIL watchdog"):
        QuanserHILBackend(watchdog_s=0.05).open()
    assert not board.is_open


def test_fault_inputs(board: FakeBoard) -> None:
    backend = QuanserHILBackend(rate_hz=RATE)
    with backend:
        backend.start()
        board.faults[1] = 1  # stall detected: a warning
        statuses = [backend.step(1.0).status for _ in range(12)]
        assert statuses[-1] & Status.STALL
        board.faults[2] = 1  # stall error: the amplifier shut down
        with pytest.raises(DeviceFaultError, match="STALL_ERROR"):
            run(backend, backend._poll_every)  # the inputs are read every 20 ms
        assert_shut_down(board)


def test_fault_inputs_unreadable(monkeypatch: pytest.MonkeyPatch) -> None:
    board = install(monkeypatch, digital=False)
    board.faults[0] = 1  # unreadable, so never seen
    with QuanserHILBackend(rate_hz=RATE) as backend:
        backend.start()
        assert all(backend.step(0.5).status == 0 for _ in range(20))


def test_overflows_are_skipped_samples(board: FakeBoard) -> None:
    with QuanserHILBackend(rate_hz=RATE) as backend:
        backend.start()
        first = backend.step(0.0)
        board.overflows = 3
        late = backend.step(0.0)
        assert (late.skipped, late.late, late.seq - first.seq) == (3, True, 4)
        assert late.tick_us == round(late.seq * 1e6 / RATE)


def test_zero_position_and_restart(board: FakeBoard) -> None:
    with QuanserHILBackend(rate_hz=RATE) as backend:
        backend.start()
        for _ in range(100):
            sample = backend.step(3.0)
        assert sample.measured > 10 * STEP
        backend.stop()
        assert backend.start(zero_position=True).measured == 0.0


def test_from_uri() -> None:
    backend = QuanserHILBackend.from_uri(
        "qube_servo2_usb/1", {"rate": "1000", "voltage_limit": "5", "watchdog": "0"}
    )
    assert (backend.board, backend.identifier, backend.rate_hz) == ("qube_servo2_usb", "1", 1000.0)
    assert (backend.voltage_limit, backend.watchdog_s) == (5.0, 0.0)
    assert QuanserHILBackend.from_uri("/qube_servo2_usb", {}).identifier == "0"
    with pytest.raises(ValueError, match="accepted: rate, voltage_limit, watchdog"):
        QuanserHILBackend.from_uri("qube_servo2_usb/0", {"baud": "9600"})
    with pytest.raises(ValueError, match="names no board"):
        QuanserHILBackend.from_uri("", {})
    with pytest.raises(ValueError, match="output's range"):
        QuanserHILBackend(voltage_limit=24.0)


def test_uri_and_env(board: FakeBoard) -> None:
    backend = resolve_backend("quanser-hil://qube_servo2_usb/0?rate=500", "rotary")
    assert isinstance(backend, QuanserHILBackend)
    env = gym.make("frictiongym/RotaryServo-v1", backend=backend, reference=1.0)
    obs, _ = env.reset()
    for _ in range(200):
        obs, _, terminated, _, info = env.step([5.0 * (1.0 - obs[0]) - 0.2 * obs[1]])
        assert not terminated
    assert abs(obs[0] - 1.0) < 0.2
    assert info["command"] == board.voltage
    env.close()
    assert_shut_down(board)
    assert not board.is_open
