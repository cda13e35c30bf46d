"""The QUBE-Servo 2 over Quanser's own HIL SDK (``quanser.hardware``): the board paces the loop.

Quanser's Python API is not on PyPI; it is imported when the backend opens, and a clear
:class:`SDKNotAvailableError` says where to get it. The calls follow Quanser's own examples: the
motor voltage on analog output 0, the amplifier enable on digital output 0, the disk's encoder
on encoder input 0, the amplifier-fault, stall-detected and stall-error flags on digital inputs
0-2, and a hardware-clocked encoder-reader task whose read blocks until the board's next
sample: the device clock, not Python, times the loop.
"""

from __future__ import annotations

import array
import importlib
import math
import time
from collections.abc import Callable, Mapping
from typing import Any

from frictiongym._validation import real_number
from frictiongym.devices import ROTARY
from frictiongym.hardware.base import Backend, DeviceInfo, Sample
from frictiongym.hardware.errors import (
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    HardwareError,
    SDKNotAvailableError,
    WatchdogTripError,
)
from frictiongym.hardware.protocol import Status
from frictiongym.hardware.uri import positive, uri_options

SDK_MISSING = (
    "Quanser's Python HIL API (quanser.hardware) is not installed, and it is not on PyPI. "
    "Install the Quanser SDK (on Linux: the HIL SDK from github.com/quanser/"
    "hil_sdk_linux_x86_64), then Quanser's Python packages as its install instructions say, "
    "and check with: python -c 'import quanser.hardware'. Without the SDK, drive the QUBE "
    "through the serial bridge firmware (firmware/qube_bridge): "
    "backend='serial:///dev/ttyACM0?baud=1000000'."
)

#: Channels of the QUBE-Servo 2 USB (Quanser's qube_servo2_usb page).
MOTOR_AO, ENABLE_DO, DISK_ENCODER = 0, 0, 0
FAULT_DI = (0, 1, 2)  #: amplifier fault, stall detected, stall error (1 = active)
_FAULT_BITS = (Status.AMP_FAULT, Status.STALL, Status.STALL_ERROR)
#: The HIL analog output's range, V (Quanser's qube_servo2_usb page: ±15 V).
AO_RANGE_V = 15.0
#: Watchdog time when ``watchdog_s`` is None and the board has one (assumed: 50 periods at
#: 500 Hz, longer than a Python garbage-collector pause, short enough that a dead host's last
#: command acts for a tenth of a second at most).
AUTO_WATCHDOG_S = 0.1
#: Samples the encoder task buffers; older ones are overwritten and counted as skipped, so a
#: late read returns the newest sample (gym_brt's reader: one sample, overwrite on overflow).
TASK_BUFFER = 1
#: How often the fault inputs are read, s (assumed: a stall error takes about 3 s to latch,
#: Quanser's pal docstring; each read is one more USB round trip).
FAULT_POLL_S = 0.02


def _import_sdk() -> Any:
    """Import ``quanser.hardware``, or raise :class:`SDKNotAvailableError` saying how to get it."""
    try:
        return importlib.import_module("quanser.hardware")
    except ImportError as exc:
        raise SDKNotAvailableError(SDK_MISSING) from exc


class QuanserHILBackend(Backend):
    """A QUBE-Servo 2 driven through Quanser's HIL SDK; its hardware clock paces the loop.

    Each step reloads the board's watchdog (when there is one), writes the voltage to analog
    output 0 and blocks in ``task_read_encoder`` until the board's next sample, so a sample
    shows the command held over the period before it, as in the simulator. Samples the host
    was too late for are overwritten (one-sample buffer) and counted in
    :attr:`Sample.skipped`; ``Sample.tick_us`` counts the board's periods.

    Safety: commands beyond ``voltage_limit`` are saturated (the base class refuses NaN);
    :meth:`stop` (close, episode end, errors, Ctrl-C, interpreter exit) writes 0 V, stops and
    deletes the task, writes 0 V again and disables the amplifier, each step tried even if one
    fails. The HIL watchdog, where the board supports it, sets 0 V and disables the amplifier
    when the host stops reloading it (``DeviceInfo.watchdog_s``); its expiry raises
    :class:`WatchdogTripError` (a :class:`DeviceFaultError`), the amplifier-fault and
    stall-error inputs (read every 20 ms) a :class:`DeviceFaultError`; stall detected only
    sets ``Status.STALL``. :meth:`start` disables and re-enables the amplifier, which clears a
    latched stall error (Quanser's reset procedure).

    The SDK's blocking read has no timeout argument: a board that stops sampling raises its
    own ``HILError``, mapped to :class:`DeviceDisconnectedError` (or
    :class:`DeviceTimeoutError` when the SDK says it timed out).

    Parameters
    ----------
    board : str, default "qube_servo2_usb"
        HIL board type.
    identifier : str, default "0"
        Board identifier (``"0"``: the first; Quanser Interactive Labs' virtual QUBE is
        ``"0@tcpip://localhost:18920?nagle='off'"``).
    rate_hz : float, default 500.0
        Sample rate of the board's clock (QUARC's QUBE-Servo 2 models use 2 ms; Quanser's pal
        defaults to 500 Hz).
    voltage_limit : float, default 10.0
        Largest |voltage|, V, within the output's ±15 V (±10 V is Quanser's recommended
        envelope for the QUBE-Servo 3 amplifier).
    watchdog_s : float, optional
        HIL watchdog time, s: None (default) uses :data:`AUTO_WATCHDOG_S` if the board has a
        watchdog and runs without one otherwise; a positive time requires one (error if
        unsupported); 0 turns it off.
    """

    def __init__(
        self,
        board: str = "qube_servo2_usb",
        identifier: str = "0",
        *,
        rate_hz: float = 500.0,
        voltage_limit: float = 10.0,
        watchdog_s: float | None = None,
    ) -> None:
        if not (isinstance(board, str) and board and isinstance(identifier, str)):
            raise ValueError(f"board and identifier must be strings, got {board!r}, {identifier!r}")
        if not (isinstance(rate_hz, int | float) and 0.0 < rate_hz <= 10_000.0):
            raise ValueError(f"rate_hz must be in (0, 10000] Hz, got {rate_hz!r}")
        if not (isinstance(voltage_limit, int | float) and 0.0 < voltage_limit <= AO_RANGE_V):
            raise ValueError(
                f"voltage_limit must be in (0, {AO_RANGE_V}] V (the HIL output's range), "
                f"got {voltage_limit!r}"
            )
        if watchdog_s is not None:
            real_number("watchdog_s", watchdog_s, ">= 0", unit=" s", hint=" (0: off, None: auto)")
        self.board = board
        self.identifier = identifier
        self.rate_hz = float(rate_hz)
        self.voltage_limit = float(voltage_limit)
        self.watchdog_s = watchdog_s
        self._hw: Any = None
        self._card: Any = None
        self._task: Any = None
        self._watchdog: float | None = None  # the watchdog time in use
        self._watching = False  # the watchdog runs
        self._faults_readable = False
        self._poll_every = max(1, round(FAULT_POLL_S * self.rate_hz))
        self._tick = 0
        self._since_poll = 0
        self._overflows = 0
        self._status = Status(0)
        self._counts = array.array("i", [0])
        self._volts = array.array("d", [0.0])
        self._state = array.array("b", [0])
        self._flags = array.array("b", [0] * len(FAULT_DI))
        self._ao, self._do = array.array("i", [MOTOR_AO]), array.array("i", [ENABLE_DO])
        self._encoder, self._di = array.array("i", [DISK_ENCODER]), array.array("i", FAULT_DI)

    @classmethod
    def from_uri(cls, path: str, query: Mapping[str, str]) -> QuanserHILBackend:
        """Build from ``quanser-hil://BOARD/IDENTIFIER?rate=500`` (``path``: ``BOARD/ID``).

        Options: ``rate`` (Hz), ``voltage_limit`` (V), ``watchdog`` (s; 0 turns it off).
        """
        uri = f"quanser-hil://{path}"
        board, _, identifier = path.strip("/").partition("/")
        if not board:
            raise ValueError(f"{uri} names no board; e.g. quanser-hil://qube_servo2_usb/0")

        def watchdog(text: str) -> float:
            value = float(text)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"watchdog must be 0 (off) or a time in s, got {text!r}")
            return value

        parsers: dict[str, Callable[[str], Any]] = {
            "rate": positive("rate"),
            "voltage_limit": positive("voltage_limit"),
            "watchdog": watchdog,
        }
        options = uri_options(query, parsers, uri)
        renames = {"rate": "rate_hz", "watchdog": "watchdog_s"}
        kwargs = {renames.get(key, key): value for key, value in options.items()}
        return cls(board, identifier or "0", **kwargs)

    @property
    def _where(self) -> str:
        return f"HIL board {self.board!r} {self.identifier!r}"

    def _error(self, exc: BaseException, doing: str) -> HardwareError:
        """Our error for the SDK's ``HILError`` ``exc`` raised while ``doing``."""
        getter = getattr(exc, "get_error_message", None)
        message = getter() if callable(getter) else str(exc)
        code = getattr(exc, "error_code", None)
        text = f"{doing} on {self._where} failed: {message}" + (
            f" (HIL error {code})" if code else ""
        )
        lowered = str(message).lower()
        if "timeout" in lowered or "timed out" in lowered:
            return DeviceTimeoutError(f"{text}; check the USB cable and the QUBE's power")
        if doing == "opening":
            return DeviceNotFoundError(
                f"{text}; check that the QUBE is powered and plugged in by USB, that Quanser's "
                "driver is installed, and that no other program (QUARC, another Python "
                "process) has the board open"
            )
        if "watchdog" in lowered:
            return WatchdogTripError(f"{text}; the watchdog zeroed the motor: call start() again")
        return DeviceDisconnectedError(
            f"{text}; the board stopped answering: check the USB cable and the QUBE's power, "
            "then open it again"
        )

    def _call(self, doing: str, method: str, *args: Any) -> Any:
        """Call the card's ``method``, mapping ``HILError`` to our errors."""
        try:
            return getattr(self._card, method)(*args)
        except self._hw.HILError as exc:
            raise self._error(exc, doing) from exc

    def _supported(self, method: str, *args: Any) -> bool:
        """Try an optional SDK call; False if the SDK or the board does not have it."""
        try:
            getattr(self._card, method)(*args)
        except (AttributeError, self._hw.HILError):
            return False
        return True

    def _write(self, volts: float) -> None:
        self._volts[0] = volts
        self._call("writing the motor voltage", "write_analog", self._ao, 1, self._volts)

    def _enable(self, on: bool) -> None:
        self._state[0] = 1 if on else 0
        self._call("setting the amplifier enable", "write_digital", self._do, 1, self._state)

    def _open(self) -> DeviceInfo:
        self._hw = _import_sdk()
        try:
            self._card = self._hw.HIL()
            self._card.open(self.board, self.identifier)
        except self._hw.HILError as exc:
            self._card = None
            raise self._error(exc, "opening") from exc
        try:
            self._write(0.0)
            self._enable(False)
            self._faults_readable = self._supported(
                "read_digital", self._di, len(FAULT_DI), self._flags
            )
            self._watchdog = self._configure_watchdog()
        except BaseException:
            self._close()
            raise
        return DeviceInfo(
            kind="rotary",
            rate_hz=self.rate_hz,
            command_limit=self.voltage_limit,
            counts_per_rev=ROTARY.counts_per_rev,
            watchdog_s=self._watchdog,
            firmware=self._sdk_version(),
            link=f"quanser-hil {self.board} {self.identifier}",
        )

    def _sdk_version(self) -> str:
        try:
            v = self._hw.HIL.get_version()
            return f"quanser.hardware {v.major}.{v.minor}.{v.release} (build {v.build})"
        except Exception:  # the version is for logs only
            return "quanser.hardware"

    def _configure_watchdog(self) -> float | None:
        """Set the watchdog's expiration states (0 V, amplifier off); its time, or None."""
        if self.watchdog_s == 0:
            return None
        low = getattr(getattr(self._hw, "DigitalState", None), "LOW", 0)
        supported = self._supported(
            "watchdog_set_analog_expiration_state",
            self._ao,
            1,
            array.array("d", [0.0]),
        ) and self._supported(
            "watchdog_set_digital_expiration_state",
            self._do,
            1,
            array.array("i", [int(low)]),
        )
        if supported:
            return AUTO_WATCHDOG_S if self.watchdog_s is None else float(self.watchdog_s)
        if self.watchdog_s is not None:
            raise HardwareError(
                f"{self._where} has no HIL watchdog (its expiration states cannot be set); "
                "pass watchdog_s=None or 0 to run without one"
            )
        return None

    def _start(self, zero_position: bool) -> Sample:
        self._stop_task()
        if self._watching:
            self._supported("watchdog_stop")
            self._watching = False
        self._write(0.0)
        self._enable(False)  # a disable/enable cycle clears a latched stall error
        if self._watchdog is not None:
            self._supported("watchdog_clear")
        if zero_position:
            zero = array.array("i", [0])
            self._call("zeroing the encoder", "set_encoder_counts", self._encoder, 1, zero)
        self._enable(True)
        self._task = self._call(
            "creating the encoder task", "task_create_encoder_reader", TASK_BUFFER, self._encoder, 1
        )
        mode = getattr(getattr(self._hw, "BufferOverflowMode", None), "OVERWRITE_ON_OVERFLOW", None)
        if mode is not None:
            self._supported("task_set_buffer_overflow_mode", self._task, mode)
        self._call(
            "starting the encoder task",
            "task_start",
            self._task,
            self._hw.Clock.HARDWARE_CLOCK_0,
            self.rate_hz,
            self._hw.HIL.INFINITE,
        )
        if self._watchdog is not None:
            self._call("starting the watchdog", "watchdog_start", self._watchdog)
            self._watching = True
        self._tick, self._overflows, self._status = -1, 0, Status(0)
        self._since_poll = self._poll_every  # read the fault inputs at the first sample
        return self._sample(0.0)

    def _sample(self, applied: float) -> Sample:
        """Block until the board's next sample; return it."""
        read = self._call("reading the encoder", "task_read_encoder", self._task, 1, self._counts)
        if read is not None and read < 1:
            raise DeviceDisconnectedError(
                f"the encoder task of {self._where} returned no sample: the task stopped; "
                "check the USB cable, then start() again"
            )
        host_ns = time.perf_counter_ns()
        try:
            overflows = int(self._card.task_get_buffer_overflows(self._task))
        except (AttributeError, TypeError, self._hw.HILError):
            overflows = self._overflows
        skipped, self._overflows = max(0, overflows - self._overflows), overflows
        self._tick += 1 + skipped
        self._since_poll += 1 + skipped
        if self._faults_readable and self._since_poll >= self._poll_every:
            self._status, self._since_poll = self._faults(), 0
        return Sample(
            measured=self._counts[0] * ROTARY.encoder_step,
            applied=applied,
            tick_us=round(self._tick * 1e6 / self.rate_hz) % 2**32,
            host_ns=host_ns,
            seq=self._tick,
            seq_applied=max(self._tick - 1, 0),
            status=int(self._status),
            late=skipped > 0,
            skipped=skipped,
        )

    def _faults(self) -> Status:
        """Read the amplifier-fault and stall inputs; raise on a fault that stops the motor."""
        self._call("reading the fault inputs", "read_digital", self._di, len(FAULT_DI), self._flags)
        status = Status(0)
        for flag, bit in zip(self._flags, _FAULT_BITS, strict=True):
            if flag:
                status |= bit
        if status & (Status.AMP_FAULT | Status.STALL_ERROR):
            names = ", ".join(str(bit.name) for bit in _FAULT_BITS if status & bit)
            raise DeviceFaultError(
                f"{self._where} reports {names}: the amplifier shut the motor down. Check "
                "that the disk turns freely and the voltage is not held above 5 V at a stall; "
                "start() again clears it"
            )
        return status

    def _exchange(self, command: float) -> Sample:
        if self._watching and not self._call("reloading the watchdog", "watchdog_reload"):
            raise WatchdogTripError(
                f"the HIL watchdog of {self._where} expired ({self._watchdog} s without a "
                "reload): it zeroed the motor and disabled the amplifier; the loop was too "
                "slow; start() again"
            )
        self._write(command)
        return self._sample(command)

    def _stop_task(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            for method in ("task_stop", "task_delete"):
                try:
                    getattr(self._card, method)(task)
                except Exception:  # the other steps of a stop must still run
                    pass

    def _stop(self) -> None:
        if self._card is None:
            return
        steps: list[Callable[[], object]] = [
            lambda: self._write(0.0),
            self._stop_task,
            lambda: self._write(0.0),
            lambda: self._enable(False),
        ]
        if self._watching:
            steps.append(lambda: self._card.watchdog_stop())
        self._watching = False
        for step in steps:  # each one tried even if another fails
            try:
                step()
            except Exception:  # best effort: the base class's stop() never raises
                pass

    def _close(self) -> None:
        card, self._card = self._card, None
        if card is not None:
            try:
                card.close()
            except self._hw.HILError as exc:
                raise self._error(exc, "closing") from exc
