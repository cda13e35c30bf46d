"""A fake ``quanser.hardware`` for the HIL backend's tests: it records calls, simulates a QUBE.

:func:`install` puts the module into ``sys.modules`` (through pytest's ``monkeypatch``, so it is
removed after the test) and returns the :class:`FakeBoard` behind it. Its ``HIL`` records every
call in ``board.calls`` and answers like the SDK: ``task_read_encoder`` returns the encoder
count of a ``Simulation(ROTARY, 1)`` stepped one period under the last voltage written
(0 V while the amplifier is disabled), once per read after the first.
"""

from __future__ import annotations

import enum
import math
import sys
import types
from collections.abc import Callable
from typing import Any

import pytest
from _altino_stock_device import StepSim

from frictiongym.devices import ROTARY


class HILError(Exception):
    """The SDK's error: a negative code and a message."""

    def __init__(self, error_code: int = -1, message: str = "HIL error") -> None:
        super().__init__(message)
        self.error_code = error_code
        self.message = message

    def get_error_message(self) -> str:
        return self.message


class Clock(enum.IntEnum):
    HARDWARE_CLOCK_0 = 0


class BufferOverflowMode(enum.IntEnum):
    ERROR_ON_OVERFLOW = 0
    OVERWRITE_ON_OVERFLOW = 1


class DigitalState(enum.IntEnum):
    LOW = 0
    HIGH = 1


class FakeBoard:
    """State and options of the fake board, shared by every ``HIL`` object."""

    def __init__(self, *, watchdog: bool = True, digital: bool = True) -> None:
        self.watchdog = watchdog  #: the watchdog calls are supported
        self.digital = digital  #: the fault inputs are readable
        self.calls: list[tuple[str, tuple[Any, ...]]] = []
        self.fail: dict[str, HILError] = {}  #: method name -> error its next call raises
        self.hooks: dict[str, Callable[[], None]] = {}  #: method name -> run before it answers
        self.faults = [0, 0, 0]  #: digital inputs 0..2: amplifier fault, stall, stall error
        self.voltage = 0.0  #: last analog output 0
        self.enabled = False  #: digital output 0
        self.is_open = False
        self.offset = 0  #: encoder counts added to the simulated angle's
        self.overflows = 0
        self.reloads = 0
        self.expired = False  #: the watchdog has expired (reloads return False)
        self.plant: StepSim | None = None
        self._started = False

    def written(self, name: str) -> list[Any]:
        """First value written by each call of ``name`` (``write_analog``, ``write_digital``)."""
        return [args[2][0] for method, args in self.calls if method == name]

    def names(self) -> list[str]:
        return [method for method, _ in self.calls]

    def counts(self) -> int:
        if self.plant is None:
            return self.offset
        return round(self.plant.measured * 2048 / (2.0 * math.pi)) + self.offset


def _make_hil(board: FakeBoard) -> type:
    class HIL:
        INFINITE = -1

        @staticmethod
        def get_version() -> Any:
            return types.SimpleNamespace(major=2024, minor=1, release=0, build=7)

        def __getattribute__(self, name: str) -> Any:
            attribute = object.__getattribute__(self, name)
            if name.startswith("_") or not callable(attribute):
                return attribute

            def recorded(*args: Any) -> Any:
                board.calls.append((name, tuple(list(a) if _is_array(a) else a for a in args)))
                if name in board.hooks:
                    board.hooks.pop(name)()
                if name in board.fail:
                    raise board.fail.pop(name)
                return attribute(*args)

            return recorded

        def open(self, card_type: str, identifier: str) -> None:
            board.is_open = True

        def close(self) -> None:
            board.is_open = False

        def write_analog(self, channels: Any, n: int, values: Any) -> None:
            board.voltage = float(values[0])

        def write_digital(self, channels: Any, n: int, values: Any) -> None:
            board.enabled = bool(values[0])

        def read_digital(self, channels: Any, n: int, values: Any) -> None:
            if not board.digital:
                raise HILError(-1077, "Not supported")
            for i in range(n):
                values[i] = board.faults[channels[i]]

        def set_encoder_counts(self, channels: Any, n: int, counts: Any) -> None:
            board.offset += int(counts[0]) - board.counts()

        def task_create_encoder_reader(self, samples: int, channels: Any, n: int) -> str:
            return "task"

        def task_set_buffer_overflow_mode(self, task: str, mode: int) -> None:
            pass

        def task_start(self, task: str, clock: int, frequency: float, samples: int) -> None:
            offset = board.counts()
            board.plant = StepSim(ROTARY, 0.0, 1.0 / frequency)
            board.offset = offset
            board._started = False

        def task_read_encoder(self, task: str, samples: int, counts: Any) -> int:
            if board.plant is None:
                raise HILError(-1, "task not started")
            if board._started:
                board.plant.step(board.voltage if board.enabled else 0.0)
            board._started = True
            counts[0] = board.counts()
            return 1

        def task_get_buffer_overflows(self, task: str) -> int:
            return board.overflows

        def task_stop(self, task: str) -> None:
            pass

        def task_delete(self, task: str) -> None:
            board.plant = None

        def _watchdog(self) -> None:
            if not board.watchdog:
                raise HILError(-1077, "Not supported")

        def watchdog_set_analog_expiration_state(self, channels: Any, n: int, values: Any) -> None:
            self._watchdog()

        def watchdog_set_digital_expiration_state(self, channels: Any, n: int, values: Any) -> None:
            self._watchdog()

        def watchdog_start(self, timeout: float) -> None:
            self._watchdog()

        def watchdog_reload(self) -> bool:
            board.reloads += 1
            return not board.expired

        def watchdog_clear(self) -> None:
            self._watchdog()

        def watchdog_stop(self) -> None:
            self._watchdog()

    return HIL


def _is_array(value: Any) -> bool:
    return hasattr(value, "__len__") and not isinstance(value, str | bytes)


def install(monkeypatch: pytest.MonkeyPatch, **options: Any) -> FakeBoard:
    """Install a fake ``quanser.hardware`` for this test; return its board."""
    board = FakeBoard(**options)
    hardware = types.ModuleType("quanser.hardware")
    hardware.HIL = _make_hil(board)  # type: ignore[attr-defined]
    for obj in (HILError, Clock, BufferOverflowMode, DigitalState):
        setattr(hardware, obj.__name__, obj)
    package = types.ModuleType("quanser")
    package.hardware = hardware  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "quanser", package)
    monkeypatch.setitem(sys.modules, "quanser.hardware", hardware)
    return board
