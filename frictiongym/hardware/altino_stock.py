"""The Altino car on its stock firmware: the vendor's serial frames, paced by the host.

A user can start with an Altino as it ships, over its Bluetooth SPP (or cable) serial port,
without flashing anything. Every stock command frame (:mod:`frictiongym.hardware.altino_frames`)
carries every field, so a sensor request also sets the motors and a Go is also a request:
:class:`AltinoStockBackend` therefore sends **one frame per tick**, ``Go(u, u)`` with the request
byte of its sensor group, and reads the one reply: only frames the vendor's library itself
sends, and no doubt which reply answers which request on a link without sequence numbers.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any

from frictiongym._validation import real_number
from frictiongym.hardware.altino_frames import (
    CAR_FRAME_S,
    GO_LIMIT,
    REPLY_LENGTHS,
    STOCK_MAX_RATE_HZ,
    STOP_REPEATS,
    BadReply,
    ImplausibleReply,
    StockSensors,
    go_frame,
    parse_sensor_reply,
    take_reply,
)
from frictiongym.hardware.base import Backend, DeviceInfo, Sample
from frictiongym.hardware.errors import (
    DeviceDisconnectedError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    HardwareError,
    ProtocolError,
)
from frictiongym.hardware.guard import (
    LIMIT_CM,
    REACTION_PERIODS,
    CarBounds,
    DistanceGuard,
    readout_jump_possible,
)
from frictiongym.hardware.ports import is_lock_failure, port_busy_error
from frictiongym.hardware.ports import pyserial as _import_serial
from frictiongym.hardware.protocol import Status
from frictiongym.hardware.uri import positive, uri_options
from frictiongym.plants.sensors import IR_MAX_READOUT, IR_NUMERATOR, IR_OFFSET

try:  # a hung-up tty makes tcflush raise termios.error, which is not an OSError
    import termios

    _LINK_ERRORS: tuple[type[BaseException], ...] = (OSError, termios.error)
except ImportError:  # pragma: no cover  (Windows)
    _LINK_ERRORS = (OSError,)

#: The guard's reaction on the stock link: one period more than the firmware's, as a reply
#: arrives while the next command starts (a command acts a tick late).
STOCK_REACTION_PERIODS = REACTION_PERIODS + 1
#: Longest a stop keeps watching a tripped guard's car that may still approach, s: the
#: heaviest plausible car at the guard's top speed brakes to rest within
#: 77.7 / ((1000 + 150.4) / 5.5) = 0.37 s; one that coasts in from beyond the IR range at the
#: fastest the guard let it drive there (about 60 cm/s with no friction) needs seconds more.
BRAKE_AT_STOP_S = 5.0
#: Longest single blocking read, s: reads loop until the reply or the timeout (assumed: short
#: enough that a timeout is never overshot by much, long enough not to spin).
_POLL_S = 0.01


class AltinoStockBackend(Backend):
    """An Altino on its stock firmware, over its serial or Bluetooth SPP port.

    Each step waits for the next tick of a **host** clock (the car neither streams nor stamps
    its samples), sends one ``Go(u, u)`` frame that is also the sensor request (module
    docstring), and returns the front IR readout of the reply. Ticks are absolute deadlines
    (``next += period``, ``time.perf_counter``); a step called after its tick is sent at once,
    and whole periods missed are skipped and counted (:attr:`missed_ticks`,
    :attr:`Sample.skipped`). ``Sample.tick_us`` is the host clock at the send.

    Timing: the reply is read as the frame's command starts, so a sample shows the command of
    the previous step held over the period (``Sample.applied``), and a command acts one tick
    after the sample it was computed from: the stock link adds one period of dead time to the
    car's own (50 ms at 20 Hz). Rates: at most 66 Hz (:data:`STOCK_MAX_RATE_HZ`, refused
    above: the wire's and the car's time per frame); over Bluetooth SPP 10-20 Hz is realistic.

    Safety the stock link cannot give, and what this class does instead:

    * **no device watchdog** (``DeviceInfo.watchdog_s`` is None): a host that dies leaves the car
      driving at its last command; stop it by hand. :meth:`stop` (close, episode end, errors,
      Ctrl-C, interpreter exit) sends ``Go(0, 0)`` in stop mode :data:`STOP_REPEATS` times,
      10 ms apart, as nothing acknowledges it;
    * **no device distance limit**: the host runs the firmware's distance guard
      (:class:`~frictiongym.hardware.guard.DistanceGuard`, with one more period of reaction for
      this link's latency): when the car, braking now, would stop within ``limit_cm`` of the
      wall, it brakes at full reverse while the car approaches and then refuses forward
      commands, with ``Status.LIMIT`` in every sample until :meth:`start` re-arms it. A reply
      that trips it is followed at once by the brake, not a tick later, and a stop (the end
      of the episode, an error, close) keeps the guard at work while the car may approach,
      up to :data:`BRAKE_AT_STOP_S`, before its stop frames;
    * no sequence numbers and an 8-bit checksum: a bad reply is counted
      (:attr:`bad_replies`) and the request sent again once, and so is a reply whose IR
      readout jumps farther than the car can move since the last one (its top speed over a
      period, plus one count: :attr:`implausible_replies`; a corruption the checksum let
      through, refused before the guard or the controller sees it); a second bad one raises
      :class:`ProtocolError`. No reply within ``timeout`` raises :class:`DeviceTimeoutError`, a
      vanished port :class:`DeviceDisconnectedError`; all stop the car first.

    Parameters
    ----------
    port : str
        A device path (``/dev/rfcomm0``, ``/dev/ttyUSB0``) or any pyserial URL (``socket://``,
        ``loop://``, ``spy://``).
    baud : int, default 115200
        The car's serial rate (Altino.h opens its port at 115200 8N1).
    rate_hz : float, default 20.0
        Control rate (the env's default period, 50 ms: docs/altino-model.md).
    ir_index : int, default 1
        IR sensor read as ``Sample.measured``: 1 is the front-centre one (the vendor's Arduino
        examples).
    timeout : float, default 0.5
        Longest wait for a reply, s (assumed: ten periods at 20 Hz, well above Bluetooth
        latency).
    sensor_group : int, default 1
        Request 1 (31-byte reply with the IR sensors) or 10 (56 bytes, everything).
    limit_cm : float, default 1.5
        Closest approach the guard allows, cm (the firmware's: ``guard.LIMIT_CM``).
    max_age : float, optional
        Longest wait from a send to its reply a step accepts, s (:attr:`Sample.age`); default
        max(5 periods, 0.1 s).
    car_bounds : CarBounds, optional
        What the guard assumes of the car (default: any mass 1.1-5.5 and the paper's least
        friction, :class:`~frictiongym.hardware.guard.CarBounds`); a car on a surface with
        less friction needs its own.
    """

    def __init__(
        self,
        port: str,
        *,
        baud: int = 115200,
        rate_hz: float = 20.0,
        ir_index: int = 1,
        timeout: float = 0.5,
        sensor_group: int = 1,
        limit_cm: float = LIMIT_CM,
        max_age: float | None = None,
        car_bounds: CarBounds | None = None,
    ) -> None:
        if max_age is not None:
            real_number("max_age", max_age, "> 0", unit=" s")
        self.max_sample_age = max_age
        if not isinstance(port, str) or not port:
            raise ValueError(f"port must be a device path or pyserial URL, got {port!r}")
        if isinstance(baud, bool) or not isinstance(baud, int) or baud <= 0:
            raise ValueError(f"baud must be a positive integer, got {baud!r}")
        if not (isinstance(rate_hz, int | float) and 0.0 < rate_hz <= STOCK_MAX_RATE_HZ):
            raise ValueError(
                f"rate_hz must be in (0, {STOCK_MAX_RATE_HZ:.0f}] Hz, got {rate_hz!r}: a tick of "
                "the stock link takes 5.1 ms on the wire plus 10 ms on the car; 10-20 Hz is "
                "realistic over Bluetooth"
            )
        if ir_index not in range(6):
            raise ValueError(
                f"ir_index must be 0..5 (IR1..IR6; 1 is front-centre), got {ir_index!r}"
            )
        if sensor_group not in (1, 10):
            raise ValueError(
                f"sensor_group must be 1 (IR group) or 10 (everything), got {sensor_group!r}"
            )
        real_number("timeout", timeout, "> 0", unit=" s")
        nearest, farthest = IR_NUMERATOR / (IR_MAX_READOUT + IR_OFFSET), IR_NUMERATOR / IR_OFFSET
        if not (isinstance(limit_cm, int | float) and nearest < limit_cm < farthest):
            raise ValueError(
                f"limit_cm must lie within the IR sensor's range ({nearest:.2f}, {farthest:.2f}) "
                f"cm, got {limit_cm!r}"
            )
        self.port = port
        self.baud = baud
        self.rate_hz = float(rate_hz)
        self.period = 1.0 / self.rate_hz
        self.ir_index = ir_index
        self.timeout = float(timeout)
        self.sensor_group = sensor_group
        self.limit_cm = float(limit_cm)
        self.missed_ticks = 0  #: whole periods skipped because a step came late
        self.bad_replies = 0  #: replies that failed their checksum or end byte, or implausible
        #: Replies whose IR readout jumped farther than the car can move (counted in both).
        self.implausible_replies = 0
        self._last_reading: tuple[float, float] | None = None  # (readout, send time) accepted
        self._speed_cap = 0.0  # bound of the car's speed either way at that reading, cm/s
        if not isinstance(car_bounds, CarBounds | None):
            raise TypeError(f"car_bounds must be a CarBounds(...), got {car_bounds!r}")
        self.car_bounds = car_bounds  # None: the guard's default for GO_LIMIT
        self.guard = self._new_guard()
        self._serial: Any = None
        self._serial_module: Any = None
        self._held = 0
        self._readout = 0.0
        self._answered_after = 0.0  # s the latest reply took at least (Sample.age)
        self._seq = 0
        self._next = 0.0
        self._origin = 0.0

    @classmethod
    def from_uri(cls, path: str, query: Mapping[str, str]) -> AltinoStockBackend:
        """Build from ``altino-stock://PATH?baud=115200&rate=20`` (``path`` is the port).

        Options: ``baud``, ``rate`` (Hz), ``ir_index``, ``timeout`` (s), ``sensor_group``,
        ``limit_cm``, ``max_age`` (s).
        """
        uri = f"altino-stock://{path}"
        if not path:
            raise ValueError(f"{uri} names no port; e.g. altino-stock:///dev/rfcomm0?rate=20")
        parsers: dict[str, Callable[[str], Any]] = {
            "baud": int,
            "rate": positive("rate"),
            "ir_index": int,
            "timeout": positive("timeout"),
            "sensor_group": int,
            "limit_cm": positive("limit_cm"),
            "max_age": positive("max_age"),
        }
        options = uri_options(query, parsers, uri)
        if "rate" in options:
            options["rate_hz"] = options.pop("rate")
        return cls(path, **options)

    def _link(self, call: Callable[..., Any], *args: Any) -> Any:
        """Run one pyserial call, mapping its failures to our errors."""
        serial = self._serial_module
        try:
            return call(*args)
        except serial.SerialTimeoutException as exc:
            raise DeviceTimeoutError(
                f"writing to the Altino on {self.port} timed out ({exc}): the link is stalled; "
                "check the Bluetooth connection"
            ) from exc
        except (serial.SerialException, *_LINK_ERRORS) as exc:
            raise DeviceDisconnectedError(
                f"the link to the Altino on {self.port} went away ({exc}); check the car's power "
                "and battery, Bluetooth range or cable, then open it again"
            ) from exc

    def _new_guard(self) -> DistanceGuard:
        return DistanceGuard(
            self.period, float(GO_LIMIT), self.limit_cm, STOCK_REACTION_PERIODS, self.car_bounds
        )

    def _frame(self, command: int) -> bytes:
        return go_frame(command, command, request=self.sensor_group)

    def _read_reply(self, deadline: float) -> StockSensors:
        length = REPLY_LENGTHS[self.sensor_group]
        buffer = bytearray()
        previous_read = latest_read = deadline - self.timeout  # the send
        while True:
            frame = take_reply(buffer, length)
            if frame is not None:
                sensors = parse_sensor_reply(frame)
                if sensors.group == self.sensor_group:  # else: the reply to another request
                    # It had not come when the read before started: the car's least delay
                    # (a host stalled meanwhile does not count).
                    self._answered_after = previous_read - (deadline - self.timeout)
                    return sensors
                continue
            if time.perf_counter() >= deadline:
                raise DeviceTimeoutError(
                    f"the Altino on {self.port} did not answer a sensor request within "
                    f"{self.timeout} s; check that the car is on and runs its stock firmware, "
                    f"the Bluetooth link is up and the baud rate is {self.baud}"
                )
            previous_read, latest_read = latest_read, time.perf_counter()
            buffer += self._link(self._serial.read, max(1, length - len(buffer)))

    def _transact(self, command: int) -> tuple[float, StockSensors]:
        """Send ``Go(command)`` with the sensor request; return the send time and the reply."""
        frame = self._frame(command)
        for _ in range(2):
            self._link(self._serial.reset_input_buffer)  # stale replies (the vendor's PurgeComm)
            self._link(self._serial.write, frame)
            sent = time.perf_counter()
            try:
                sensors = self._read_reply(sent + self.timeout)
                self._check_readout(sensors, sent, command)
            except ImplausibleReply as exc:
                self.bad_replies += 1
                self.implausible_replies += 1
                why = str(exc)
                continue
            except BadReply:
                self.bad_replies += 1
                why = "failed their checksum"
                continue
            return sent, sensors
        raise ProtocolError(
            f"two replies in a row from {self.port} {why}: check the baud rate ({self.baud}), "
            "that the port is the Altino's, on its stock firmware, and the link's quality"
        )

    def _check_readout(self, sensors: StockSensors, sent: float, command: float) -> None:
        """Refuse a readout the car cannot reach from the last one (:class:`ImplausibleReply`).

        Bound: the farthest the car can move (either way) since that reply, from a bound of its
        speed and the commands it held (the last one and ``command``, which may act before the
        reading), over the time since, at least a period; plus one count of quantization and
        the bounds' noise at each reading.
        """
        readout = float(sensors.ir[self.ir_index])
        car = self.guard.car
        if self._last_reading is None:
            self._last_reading = (readout, sent)
            return
        previous, when = self._last_reading
        elapsed = max(sent - when, self.period)
        pushed = max(abs(self._held), abs(command))
        speed = car.advance(self._speed_cap, pushed, elapsed)
        travel = max(self._speed_cap, speed) * elapsed  # the bound only rises, or only falls
        if not readout_jump_possible(previous, readout, travel, car.noise_counts):
            raise ImplausibleReply(
                f"gave IR readouts that jump from {previous:g} to {readout:g}, farther than "
                f"the car can move between them ({travel:.2f} cm holding at most "
                f"{pushed:g}): a corruption the 8-bit checksum let through"
            )
        self._last_reading, self._speed_cap = (readout, sent), speed

    def _tick_us(self, at: float) -> int:
        return int((at - self._origin) * 1e6) % 2**32

    def _open(self) -> DeviceInfo:
        serial = self._serial_module = _import_serial()
        try:
            self._serial = serial.serial_for_url(
                self.port,
                baudrate=self.baud,
                timeout=min(self.timeout, _POLL_S),
                write_timeout=self.timeout,
                exclusive=True,
            )
        except (serial.SerialException, ValueError, *_LINK_ERRORS) as exc:
            if is_lock_failure(exc):
                raise port_busy_error(self.port) from None
            raise DeviceNotFoundError(
                f"cannot open the Altino's port {self.port!r} ({exc}); check the path (Bluetooth "
                "SPP: /dev/rfcommN after `rfcomm bind`; cable: /dev/ttyUSBN), that the car is on "
                "and paired, and that you may open it (group dialout)"
            ) from exc
        self._origin = time.perf_counter()
        try:  # a stop frame that is also a request: is this a stock Altino?
            self._transact(0)
        except BaseException:
            self._close()
            raise
        return DeviceInfo(
            kind="altino",
            rate_hz=self.rate_hz,
            command_limit=float(GO_LIMIT),
            counts_per_rev=0,
            watchdog_s=None,
            can_place=False,
            distance_limit=True,
            firmware="stock (vendor protocol)",
            link=f"altino-stock {self.port} @ {self.baud} baud",
        )

    def _start(self, zero_position: bool) -> Sample:
        sent, sensors = self._transact(0)
        self._held, self._seq = 0, 0
        self.guard = self._new_guard()  # re-armed
        self._readout = float(sensors.ir[self.ir_index])
        self._next = sent + self.period
        status = Status.LIMIT if self.guard.update(self._readout) else Status(0)
        return Sample(
            measured=self._readout,
            applied=0.0,
            tick_us=self._tick_us(sent),
            host_ns=time.perf_counter_ns(),
            status=int(status),
            age=self._answered_after,
        )

    def _wait_tick(self) -> int:
        """Sleep until the next tick; return the whole periods missed if it has passed."""
        deadline = self._next
        now = time.perf_counter()
        skipped = 0
        if now < deadline:
            time.sleep(deadline - now)
        else:
            skipped = int((now - deadline) / self.period)
            deadline += skipped * self.period
        self._next = deadline + self.period
        self.missed_ticks += skipped
        return skipped

    def _exchange(self, command: float) -> Sample:
        value = round(self.guard.command(command))
        skipped = self._wait_tick()
        seq_applied = self._seq
        self._seq += 1 + skipped
        sent, sensors = self._transact(value)
        held, self._held = self._held, value
        self._readout = float(sensors.ir[self.ir_index])
        was_tripped = self.guard.tripped
        if self.guard.update(self._readout, held) and not was_tripped:
            brake = round(self.guard.command(value))  # at once, not a tick later
            if brake != value:
                self._transact(brake)
                self._held = brake
        return Sample(
            measured=self._readout,
            applied=float(held),
            tick_us=self._tick_us(sent),
            host_ns=time.perf_counter_ns(),
            seq=self._seq,
            seq_applied=seq_applied,
            age=self._answered_after,
            status=int(Status.LIMIT if self.guard.tripped else Status(0)),
            late=skipped > 0,
            skipped=skipped,
        )

    def _brake_to_rest(self) -> None:
        """Keep a tripped guard at work until the car cannot approach, as the firmware does.

        The stock car has no guard of its own: stop frames right after a trip would cancel the
        brake and let the car coast on (an env ends its episode on the trip, and stops). So
        while the car may still approach (its readings, or out of range the speed bound) the
        guard keeps braking it in range and watching it out of range, for at most
        :data:`BRAKE_AT_STOP_S`.
        """
        deadline = time.perf_counter() + BRAKE_AT_STOP_S
        held = self._held
        while self.guard.tripped and self.guard.may_approach():
            if time.perf_counter() >= deadline:
                return
            value = round(self.guard.command(0.0))  # full reverse in range, 0 out of it
            self._wait_tick()
            _, sensors = self._transact(value)
            self.guard.update(float(sensors.ir[self.ir_index]), held)
            self._held = held = value

    def _stop(self) -> None:
        if self._serial is None:
            return
        try:
            self._brake_to_rest()
        except HardwareError:
            pass  # the stop frames follow; a link that failed fails them too
        self._held = 0
        frame = self._frame(0)
        for i in range(STOP_REPEATS):  # each one tried even if another fails
            if i:
                time.sleep(CAR_FRAME_S)
            try:
                self._link(self._serial.write, frame)
            except HardwareError:
                if i == STOP_REPEATS - 1:
                    raise
        self._link(self._serial.flush)

    def _close(self) -> None:
        port, self._serial = self._serial, None
        if port is not None:
            try:
                port.close()
            except (self._serial_module.SerialException, *_LINK_ERRORS):
                pass  # the port is gone already
