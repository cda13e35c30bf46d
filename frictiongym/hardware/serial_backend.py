"""A device running our firmware (or the emulator), over pyserial: ``serial://`` and ``socket://``.

The device's clock paces the loop: it sends one ``State`` per tick, and :meth:`step` writes the
command and blocks until the ``State`` that echoes it (``seq_applied``), so host jitter adds
latency but never changes the sampling period. A command that misses its tick is held one
period late and reported (``Sample.late``); a device that stays silent while the host listens
for ``timeout`` raises :class:`~frictiongym.hardware.errors.DeviceTimeoutError` (time the host
itself was stalled, by a garbage collection or the scheduler, is not the device's silence).

A port is opened exclusively where the platform allows it (a ``flock`` on POSIX), so a second
frictiongym on the same port is refused, naming the process that holds it; a second host that
does not lock (another program) is recognised by what it does to the stream: a ``Hello``
nobody here asked for, or the device holding commands this host never sent.
"""

from __future__ import annotations

import time
from typing import Any

from frictiongym import devices
from frictiongym._validation import real_number
from frictiongym.hardware import protocol
from frictiongym.hardware.base import Backend, DeviceInfo, Sample, kind_of_code
from frictiongym.hardware.echo import EchoTimes
from frictiongym.hardware.errors import (
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    HardwareError,
    ProtocolError,
    WatchdogTripError,
)
from frictiongym.hardware.ports import is_lock_failure, port_busy_error, pyserial
from frictiongym.hardware.uri import check_socket_url, integer, positive, uri_options

#: Default line rate: the QUBE bridge's (exact on 16 MHz AVRs, room for 500 Hz frames both
#: ways). Ignored by USB CDC boards, ptys and sockets.
DEFAULT_BAUD = 1_000_000
#: Time for the device to answer the handshake: an Arduino resets when its port opens and
#: spends 1-2 s in its bootloader.
HANDSHAKE_TIMEOUT = 3.0
#: A command with no echo after this many periods counts as late (it missed its tick).
LATE_AFTER_PERIODS = 2.5
#: How long after the handshake a Hello may still answer one of its repeated requests, s.
LATE_HELLO = 0.5
#: Longest single wait for input, s: a wait that returns later than this was stalled on the
#: host, and counts as this long towards the timeout.
READ_WAIT = 0.05

_FAULTS = {
    protocol.Status.WATCHDOG: "its watchdog tripped (no command reached it in time: the host loop "
    "stalled or the link lost frames)",
    protocol.Status.AMP_FAULT: "the amplifier reports a fault (check the supply and the motor "
    "cable)",
    protocol.Status.STALL_ERROR: "the motor stalled under voltage for too long (free the load, "
    "then re-arm)",
}


class SerialBackend(Backend):
    """A device speaking :mod:`frictiongym.hardware.protocol` over a serial port or socket.

    Parameters
    ----------
    port : str
        A device path (``/dev/ttyACM0``, ``COM3``) or a pyserial URL (``socket://host:port``).
    baud : int, default 1_000_000
        Line rate (ignored by USB CDC boards, ptys and sockets).
    timeout : float, optional
        Longest silence of the device while the host listens for a state frame, s (default:
        five device periods, at least 0.1 s).
    handshake_timeout : float, default 3.0
        Longest wait for the device's ``Hello`` after opening.
    max_age : float, optional
        Oldest sample a step accepts, s (:attr:`Sample.age`: how long the device took at least
        to answer a recent command); default max(5 device periods, 0.1 s).
    """

    def __init__(
        self,
        port: str,
        *,
        baud: int = DEFAULT_BAUD,
        timeout: float | None = None,
        handshake_timeout: float = HANDSHAKE_TIMEOUT,
        max_age: float | None = None,
    ) -> None:
        for name, value in (
            ("timeout", timeout),
            ("handshake_timeout", handshake_timeout),
            ("max_age", max_age),
        ):
            if value is not None:
                real_number(name, value, "> 0", unit=" s")
        if not (isinstance(baud, int) and baud > 0):
            raise ValueError(f"baud must be a positive integer, got {baud!r}")
        if port.lower().startswith("socket:"):
            check_socket_url(port)
        self.port = port
        self.max_sample_age = max_age
        self.baud = baud
        self.timeout = timeout
        self.handshake_timeout = handshake_timeout
        self.hello: protocol.Hello | None = None
        self._encoder_step = 0.0  #: position units per encoder count (the device description's)
        self.decoder = protocol.FrameDecoder()
        self._serial: Any = None
        self._seq = 0
        self._last: protocol.State | None = None
        self._echoes = EchoTimes()
        self._echoed = False  # a state of this episode echoed one of our commands
        self._hellos_due = 0  # our HelloRequests not answered yet
        self._late_hellos_until = 0.0  # monotonic time until which a Hello may answer one

    @classmethod
    def from_uri(cls, path: str, query: dict[str, str]) -> SerialBackend:
        """Build from ``serial://PATH?baud=N&timeout=S&max_age=S`` (or a pyserial URL)."""
        parsers = {
            "baud": integer("baud"),
            "timeout": positive("timeout"),
            "max_age": positive("max_age"),
        }
        uri = path if "://" in path else f"serial://{path}"  # a pyserial URL names itself
        return cls(path, **uri_options(query, parsers, uri))

    # -- link -------------------------------------------------------------------------------------

    def _open(self) -> DeviceInfo:
        serial = pyserial()
        try:
            self._serial = serial.serial_for_url(
                self.port,
                baudrate=self.baud,
                timeout=READ_WAIT,
                write_timeout=0.5,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            if is_lock_failure(exc):
                raise port_busy_error(self.port) from None
            if "://" in self.port:  # a network URL: no device path to check
                raise DeviceNotFoundError(
                    f"could not connect to {self.port!r}: {exc}. Check that the device's "
                    "server or the emulator (`frictiongym emulate --tcp PORT`) runs at that "
                    "address, and that the URL is the one it printed"
                ) from None
            raise DeviceNotFoundError(
                f"could not open {self.port!r}: {exc}. Check the path (ls /dev/ttyACM* "
                "/dev/ttyUSB*), that the device is plugged in and that you may use it (the "
                "dialout group); for the emulator, the URL it printed on its first line"
            ) from None
        try:
            if hasattr(self._serial, "set_low_latency_mode"):
                self._serial.set_low_latency_mode(True)  # not on ptys and sockets: fine
        except (OSError, ValueError, AttributeError):
            pass
        try:
            hello = self._handshake()
        except BaseException:
            self._serial.close()
            raise
        self.hello = hello
        try:
            kind = kind_of_code(hello.kind, self.described_kind)
        except HardwareError:
            self._serial.close()
            raise
        if hello.counts_per_rev:  # the same float as the simulated encoder's step
            self._encoder_step = devices.get(kind).position_per_rev / hello.counts_per_rev
        period = 1.0 / hello.rate_hz
        if self.timeout is None:
            self.timeout = max(0.1, 5.0 * period)
        self._serial.timeout = min(self.timeout, READ_WAIT)
        return DeviceInfo(
            kind=kind,
            rate_hz=float(hello.rate_hz),
            command_limit=hello.command_limit / hello.command_scale,
            counts_per_rev=hello.counts_per_rev,
            watchdog_s=hello.watchdog_ms / 1000.0 if hello.watchdog_ms else None,
            can_place=bool(hello.capabilities & protocol.Capability.PLACE),
            distance_limit=bool(hello.capabilities & protocol.Capability.DISTANCE_LIMIT),
            firmware=f"build {hello.firmware}",
            link=f"frictiongym protocol {hello.version} on {self.port}",
        )

    def _handshake(self) -> protocol.Hello:
        """Ask for a ``Hello`` until one comes (a booting Arduino misses the first requests)."""
        self._serial.reset_input_buffer()
        deadline = time.monotonic() + self.handshake_timeout
        next_request = 0.0
        while time.monotonic() < deadline:
            try:
                if time.monotonic() >= next_request:
                    self._write(protocol.HelloRequest())
                    self._hellos_due += 1
                    next_request = time.monotonic() + 0.25
                arrived = self._read_available()
            except DeviceDisconnectedError:
                raise DeviceDisconnectedError(
                    f"{self.port!r} closed the link before answering: a device on TCP (the "
                    "emulator's --tcp) serves one host at a time and another one is connected, "
                    "or it stopped; close the other host, or start another emulator"
                ) from None
            for message in self.decoder.feed(arrived):
                if isinstance(message, protocol.Hello):
                    self._hellos_due -= 1
                    self._late_hellos_until = time.monotonic() + LATE_HELLO
                    return self._check_hello(message)
        raise DeviceTimeoutError(
            f"no answer from {self.port!r} within {self.handshake_timeout} s. Check that the "
            "device runs the frictiongym firmware (firmware/README.md) at this baud rate "
            f"({self.baud}), or that the emulator is running"
        )

    def _check_hello(self, hello: protocol.Hello) -> protocol.Hello:
        if hello.version != protocol.PROTOCOL_VERSION:
            raise ProtocolError(
                f"the device at {self.port!r} speaks protocol version {hello.version}, this "
                f"frictiongym speaks {protocol.PROTOCOL_VERSION}: update the firmware or "
                "frictiongym"
            )
        if hello.rate_hz <= 0 or hello.command_scale <= 0 or hello.command_limit <= 0:
            raise ProtocolError(f"the device's Hello makes no sense: {hello}")
        return hello

    def _read_available(self, wait: bool = True) -> bytes:
        """Read what arrived, waiting at most the port's timeout for a first byte if ``wait``."""
        serial = pyserial()
        try:
            waiting = self._serial.in_waiting
            if not (wait or waiting):
                return b""
            data: bytes = self._serial.read(max(1, waiting))
        except (serial.SerialException, OSError) as exc:
            if "multiple access" in str(exc):  # pyserial's hint: readable, yet nothing to read
                raise DeviceDisconnectedError(
                    f"the link to {self.port!r} gave no data when it said it had some ({exc}): "
                    "another program is probably reading this port too (find it with `fuser "
                    f"{self.port}`) and must be closed; or the device disconnected"
                ) from None
            raise DeviceDisconnectedError(
                f"the link to {self.port!r} went away ({exc}); check the cable and the device's "
                "power, or whether the emulator stopped"
            ) from None
        return data

    def _write(self, message: protocol.Message) -> None:
        serial = pyserial()
        try:
            self._serial.write(protocol.encode(message))
        except serial.SerialTimeoutException:
            raise DeviceTimeoutError(
                f"writing to {self.port!r} timed out: the device stopped reading (check that it "
                "is powered and not stuck)"
            ) from None
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnectedError(
                f"could not write to {self.port!r} ({exc}); check the cable and the device"
            ) from None

    # -- states -----------------------------------------------------------------------------------

    def _states(self, wait: bool) -> list[protocol.State]:
        """Decode the states that arrived (waiting up to the port timeout if ``wait``)."""
        self._echoes.reading(time.perf_counter_ns())
        data = self._read_available(wait)
        states = []
        for message in self.decoder.feed(data):
            if isinstance(message, protocol.State):
                states.append(message)
            elif isinstance(message, protocol.Hello):
                if self._hellos_due > 0 and time.monotonic() < self._late_hellos_until:
                    # the late answer to a second request of our handshake
                    self._hellos_due -= 1
                    continue
                # A device sends a Hello only when asked: another program asked.
                raise self._second_host("it answered a Hello request this host never sent")
        return states

    def _second_host(self, sign: str) -> DeviceFaultError:
        return DeviceFaultError(
            f"another program is talking to the device at {self.port!r} ({sign}); two hosts on "
            "one device both drive its motor. Close the other program (fuser -v "
            f"{self.port} names it), then start a new episode"
        )

    def _restarted_or_second_host(self, state: protocol.State) -> DeviceFaultError | None:
        """Why ``state`` echoes a command this host never sent (None: it may, before ours)."""
        if not self._echoed:
            return None  # states sent before our first command arrived: from before the start
        last = self._last
        if state.status & protocol.Status.DISABLED and (
            last is None or ((state.seq - last.seq) & 0xFFFF) > 0x8000 or state.tick_us < 1_000_000
        ):  # off, and its clock or frame counter started over: a reboot
            return DeviceFaultError(
                f"the device at {self.port!r} restarted mid-run (its clock started over and it "
                "is disarmed); check its power supply and cable, then start a new episode"
            )
        return self._second_host(
            f"it holds command {state.seq_applied}, which this host never sent"
        )

    def _await(self, seq: int) -> Sample:
        """Block until the state that echoes command ``seq`` (or report the command late).

        The timeout counts only time spent listening: each wait for input counts at most
        its own limit (:data:`READ_WAIT`), so a host stalled inside a wait (a garbage
        collection, the scheduler) finds the frames that arrived meanwhile instead of
        blaming the device.
        """
        assert self.hello is not None  # opened by start() and step()
        period = 1.0 / self.hello.rate_hz
        sent = time.monotonic()
        newest: protocol.State | None = None
        listened = 0.0
        while True:
            started = time.monotonic()
            for state in self._states(wait=True):
                newest = state
                if self._echoes.ours(state.seq_applied):
                    self._echoes.echoed(state.seq_applied)
                    self._echoed = True
                else:
                    error = self._restarted_or_second_host(state)
                    if error is not None:
                        raise error
                if state.seq_applied == seq:
                    return self._sample(state, late=False)
            now = time.monotonic()
            listened += min(now - started, self._serial.timeout)
            if newest is not None and now - sent > LATE_AFTER_PERIODS * period:
                return self._sample(newest, late=True)
            if listened > (self.timeout or 0.0):
                raise DeviceTimeoutError(
                    f"no state frame from {self.port!r} for {listened:.3f} s (the device ticks "
                    f"every {period * 1000:.1f} ms): the device stopped or the link is down"
                )

    def _sample(self, state: protocol.State, late: bool) -> Sample:
        hello = self.hello
        assert hello is not None
        if state.status & protocol.FAULT_BITS:
            reasons = "; ".join(text for bit, text in _FAULTS.items() if state.status & bit)
            message = f"the device at {self.port!r} stopped its motor: {reasons}"
            if state.status & protocol.FAULT_BITS == protocol.Status.WATCHDOG:
                raise WatchdogTripError(message)
            raise DeviceFaultError(message)
        skipped = 0
        if self._last is not None:
            skipped = max(0, ((state.seq - self._last.seq) & 0xFFFF) - 1)
        self._last = state
        if hello.counts_per_rev:  # the same float product as the simulated encoder
            measured = state.sensor * self._encoder_step
        else:
            measured = float(state.sensor)
        return Sample(
            measured=measured,
            applied=state.applied / hello.command_scale,
            tick_us=state.tick_us,
            host_ns=time.perf_counter_ns(),
            seq=state.seq,
            seq_applied=state.seq_applied,
            status=int(state.status),
            late=late,
            skipped=skipped,
            age=self._echoes.age(),
        )

    def _send(self, command: float, flags: protocol.Flag) -> int:
        hello = self.hello
        assert hello is not None
        counts = round(command * hello.command_scale)  # within the limit: step() saturated it
        self._seq = (self._seq + 1) & 0xFFFF
        self._echoes.sent(self._seq, time.perf_counter_ns())
        self._write(protocol.Command(seq=self._seq, command=counts, flags=flags))
        return self._seq

    # -- Backend ----------------------------------------------------------------------------------

    def _start(self, zero_position: bool) -> Sample:
        flags = protocol.Flag.ENABLE | protocol.Flag.REARM
        if zero_position and self.info is not None and self.info.counts_per_rev:
            flags |= protocol.Flag.ZERO_POSITION
        self._states(wait=False)  # drop states of before the start
        self._last = None
        self._echoed = False
        self._echoes.forget_pending()  # the stops that ended the last episode
        return self._await(self._send(0.0, flags))

    def _exchange(self, command: float) -> Sample:
        return self._await(self._send(command, protocol.Flag.ENABLE))

    def _place(self, position: float) -> None:
        self._write(protocol.Place(float(position)))

    def _stop(self) -> None:
        if self._serial is None or not self._serial.is_open:
            return
        for _ in range(2):  # a second copy in case the first is corrupted on the line
            self._send(0.0, protocol.Flag.ESTOP)
        try:
            self._serial.flush()
        except Exception:  # the link may be gone; the device's watchdog covers that
            pass

    def _close(self) -> None:
        if self._serial is not None:
            self._serial.close()
            self._serial = None
            self.hello = None
            self._echoes.clear()
            self._hellos_due = 0
