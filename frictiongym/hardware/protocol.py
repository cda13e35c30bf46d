"""The frictiongym device protocol: pure encoding and decoding, no I/O.

A frame on the wire is ``COBS(payload + CRC16) + 0x00``: the payload is one message below
(little-endian, first byte its type), the CRC is CRC-16/CCITT-FALSE (polynomial 0x1021, initial
value 0xFFFF, no reflection, no final xor; ``binascii.crc_hqx(payload, 0xFFFF)``) of the payload,
appended little-endian, and COBS (Cheshire & Baker, 1999) removes every zero byte so that 0x00
delimits frames. A decoder resynchronises at the next 0x00 after any corruption. The C
implementation in ``firmware/common/`` is checked against this module on shared test vectors.

Messages (sizes without CRC; ``docs/protocol.md`` has the full table and the device behaviour):

=========================  =====  ==================================================================
message                    bytes  fields
=========================  =====  ==================================================================
``Command`` 0x01 host→dev     8    flags u8, seq u16, command i16 (counts), aux i16
``HelloRequest`` 0x02         2    protocol version u8
``Place`` 0x03 (emulator)     5    position f32 (rad, or cm from the wall); real firmware ignores it
``Hello`` 0x80 dev→host      18    version, kind, capabilities u8; rate Hz u16, counts/rev u16,
                                   command counts per unit u16, command limit i16 (counts),
                                   watchdog ms u16, firmware build u32
``State`` 0x81 dev→host      18    status u8, seq u16, tick µs u32, seq_applied u16, applied i16,
                                   sensor i32 (encoder counts or IR readout), aux i16
=========================  =====  ==================================================================

The device streams one ``State`` per tick of its own clock; ``seq_applied`` and ``applied`` echo
the host command it held over the period that ended at this tick.
"""

from __future__ import annotations

import binascii
import dataclasses
import enum
import struct
from dataclasses import dataclass
from typing import ClassVar, Union

from frictiongym.hardware.errors import ProtocolError

#: Version carried by ``HelloRequest`` and ``Hello``; the host refuses a device of another.
PROTOCOL_VERSION = 1
#: Longest payload any message has, plus its CRC: frames longer than this are garbage.
MAX_PAYLOAD = 32
#: Longest encoded frame (COBS adds one byte per 254, plus one).
MAX_FRAME = MAX_PAYLOAD + 2 + MAX_PAYLOAD // 254 + 1


class FrameError(ProtocolError):
    """A frame that fails COBS, its CRC or its layout (decoders count and drop these)."""


class MessageType(enum.IntEnum):
    """First byte of every payload."""

    COMMAND = 0x01
    HELLO_REQUEST = 0x02
    PLACE = 0x03
    HELLO = 0x80
    STATE = 0x81


class DeviceKind(enum.IntEnum):
    """What is behind the link."""

    ROTARY = 1  #: QUBE-Servo 2 (through an SPI bridge): encoder counts, command in mV
    ALTINO = 2  #: Altino car: front IR readout, command in motor units
    #: A device from its description file (docs/devices.md): both ends hold the same file, and
    #: the wire carries its encoder counts, command scale and limit, not its name
    AXIS = 3


class Flag(enum.IntFlag):
    """Bits of ``Command.flags``."""

    ENABLE = 0x01  #: drive the motor (else it is held at zero and the amplifier disabled)
    ZERO_POSITION = 0x02  #: zero the encoder count at this tick (servo)
    ESTOP = 0x04  #: zero the motor, disable, latch ``Status.DISABLED`` until ``REARM``
    REARM = 0x08  #: clear the latched watchdog, limit and e-stop bits


class Status(enum.IntFlag):
    """Bits of ``State.status``."""

    AMP_FAULT = 0x01
    STALL = 0x02
    STALL_ERROR = 0x04
    WATCHDOG = 0x08  #: no valid command within the watchdog time; latched until ``REARM``
    COMMAND_LATE = 0x10  #: no new command arrived for this period; the last one was held
    CRC_ERROR = 0x20  #: a bad frame was received since the last state
    #: the distance guard tripped (it brakes, then refuses forward commands); latched until
    #: ``REARM``
    LIMIT = 0x40
    #: the motor is off whatever the command: not armed (boot, e-stop, watchdog, fault) or not
    #: enabled
    DISABLED = 0x80


#: Status bits after which a run cannot go on (``LIMIT`` only ends the episode: the device
#: stopped itself short of the wall).
FAULT_BITS = Status.AMP_FAULT | Status.STALL_ERROR | Status.WATCHDOG


class Capability(enum.IntFlag):
    """Bits of ``Hello.capabilities``."""

    WATCHDOG = 0x01  #: zeroes the motor when commands stop
    PLACE = 0x02  #: honours ``Place`` (the emulator)
    #: brakes before the wall (the predictive guard of hardware/guard.py; the Altino)
    DISTANCE_LIMIT = 0x04


@dataclass(frozen=True)
class _Fields:
    """A message whose fields, in declaration order, are its payload's after the type byte."""

    def fields(self) -> tuple[int | float, ...]:
        """Payload fields after the type byte, in order."""
        return tuple(getattr(self, f.name) for f in dataclasses.fields(self))


@dataclass(frozen=True)
class Command(_Fields):
    """Host to device: hold ``command`` counts (``Hello.command_scale`` counts per unit)."""

    seq: int
    command: int
    flags: Flag = Flag.ENABLE
    aux: int = 0
    FORMAT: ClassVar[str] = "<BBHhh"
    TYPE: ClassVar[MessageType] = MessageType.COMMAND

    def fields(self) -> tuple[int, ...]:
        """Payload fields after the type byte, in order."""
        return (int(self.flags), self.seq, self.command, self.aux)


@dataclass(frozen=True)
class HelloRequest(_Fields):
    """Host to device: ask for a ``Hello``."""

    version: int = PROTOCOL_VERSION
    FORMAT: ClassVar[str] = "<BB"
    TYPE: ClassVar[MessageType] = MessageType.HELLO_REQUEST


@dataclass(frozen=True)
class Place(_Fields):
    """Host to emulator: put the plant at rest at ``position`` (a real device ignores it)."""

    position: float
    FORMAT: ClassVar[str] = "<Bf"
    TYPE: ClassVar[MessageType] = MessageType.PLACE


@dataclass(frozen=True)
class Hello(_Fields):
    """Device to host: who it is and how it runs."""

    version: int
    kind: DeviceKind
    capabilities: Capability
    rate_hz: int
    counts_per_rev: int  #: encoder counts per revolution (0 without an encoder)
    command_scale: int  #: command counts per physical unit (1000 per V; 1 per motor unit)
    command_limit: int  #: largest |command| the device applies, counts (fits an int16)
    watchdog_ms: int  #: 0: no watchdog
    firmware: int  #: build number
    FORMAT: ClassVar[str] = "<BBBBHHHhHI"
    TYPE: ClassVar[MessageType] = MessageType.HELLO


@dataclass(frozen=True)
class State(_Fields):
    """Device to host, once per tick: the sensor and the command held over the last period."""

    status: Status
    seq: int  #: the device's frame counter (gaps are dropped frames)
    tick_us: int  #: device clock at the sample, µs (wraps at 2**32)
    seq_applied: int  #: ``seq`` of the host command held over the period ending here
    applied: int  #: that command, counts (after the device's own clipping)
    sensor: int  #: encoder counts (servo) or IR readout 0..800 (Altino)
    aux: int = 0  #: motor current in mA (servo), or 0
    FORMAT: ClassVar[str] = "<BBHIHhih"
    TYPE: ClassVar[MessageType] = MessageType.STATE


Message = Union[Command, HelloRequest, Place, Hello, State]  # noqa: UP007  (runtime alias)
_CLASSES: dict[int, type[Command | HelloRequest | Place | Hello | State]] = {
    cls.TYPE: cls for cls in (Command, HelloRequest, Place, Hello, State)
}


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (check value 0x29B1 for ``b"123456789"``)."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data``: the result has no zero byte and is one byte (per 254) longer."""
    out = bytearray([0])
    code_at, code = 0, 1
    for byte in data:
        if byte:
            out.append(byte)
            code += 1
        if not byte or code == 0xFF:
            out[code_at] = code
            code_at, code = len(out), 1
            out.append(0)
    out[code_at] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Invert :func:`cobs_encode`; raise :class:`FrameError` on a malformed block."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        end = i + code
        if code == 0 or end > n:
            raise FrameError("COBS: a block code is zero or runs past the end of the frame")
        block = data[i + 1 : end]
        if 0 in block:
            raise FrameError("COBS: zero byte inside a frame")
        out += block
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


def pack(message: Message) -> bytes:
    """Return the payload of ``message`` (type byte first, no CRC)."""
    try:
        return struct.pack(message.FORMAT, int(message.TYPE), *message.fields())
    except (struct.error, OverflowError) as exc:  # OverflowError: a float beyond binary32
        raise ValueError(f"{message!r} does not fit its wire format: {exc}") from None


def unpack(payload: bytes) -> Message:
    """Parse a payload (without CRC); raise :class:`FrameError` on an unknown or short one."""
    if not payload:
        raise FrameError("empty payload")
    cls = _CLASSES.get(payload[0])
    if cls is None:
        raise FrameError(f"unknown message type 0x{payload[0]:02x}")
    if len(payload) != struct.calcsize(cls.FORMAT):
        raise FrameError(
            f"{cls.__name__} payload of {len(payload)} bytes, expected "
            f"{struct.calcsize(cls.FORMAT)}"
        )
    values = struct.unpack(cls.FORMAT, payload)[1:]
    if cls is Command:
        flags, seq, command, aux = values
        return Command(seq=seq, command=command, flags=Flag(flags), aux=aux)
    if cls is Hello:
        version, kind, caps, *rest = values
        try:
            device = DeviceKind(kind)
        except ValueError:
            raise FrameError(f"Hello names an unknown device kind {kind}") from None
        return Hello(version, device, Capability(caps), *rest)
    if cls is State:
        status, *rest = values
        return State(Status(status), *rest)
    return cls(*values)


def encode(message: Message) -> bytes:
    """Return the bytes on the wire for ``message``: ``COBS(payload + CRC) + 0x00``."""
    payload = pack(message)
    return cobs_encode(payload + crc16(payload).to_bytes(2, "little")) + b"\x00"


def decode(frame: bytes) -> Message:
    """Parse one frame as :func:`encode` writes it, without its trailing 0x00."""
    if len(frame) > MAX_FRAME:
        raise FrameError(f"frame of {len(frame)} bytes, longer than any message")
    data = cobs_decode(frame)
    if len(data) < 3:
        raise FrameError(f"frame of {len(data)} bytes is too short for a payload and a CRC")
    payload, crc = data[:-2], int.from_bytes(data[-2:], "little")
    if crc16(payload) != crc:
        raise FrameError("CRC mismatch")
    return unpack(payload)


class FrameDecoder:
    """Split a byte stream into messages; bad frames are counted and dropped, never raised.

    Feed it whatever ``read`` returned; it keeps a partial frame until its 0x00 arrives.
    """

    def __init__(self) -> None:
        self._partial = bytearray()
        self._overflow = False
        self.frames = 0  #: good frames decoded
        self.errors = 0  #: frames dropped for bad COBS, CRC, layout or length

    def feed(self, data: bytes) -> list[Message]:
        """Decode every frame completed by ``data``, in order."""
        messages: list[Message] = []
        *complete, rest = bytes(data).split(b"\x00")
        for chunk in complete:
            self._partial += chunk
            frame, overflow = bytes(self._partial), self._overflow
            self._partial.clear()
            self._overflow = False
            if not frame and not overflow:
                continue  # back-to-back delimiters (a sender resynchronising)
            if overflow:
                self.errors += 1
                continue
            try:
                messages.append(decode(frame))
            except FrameError:
                self.errors += 1
            else:
                self.frames += 1
        self._partial += rest
        if len(self._partial) > MAX_FRAME:  # garbage without delimiters: drop, stay bounded
            self._partial.clear()
            self._overflow = True
        return messages
