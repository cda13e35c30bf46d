"""The Altino's stock serial frames (the vendor's ``Altino.h``): pure encoding and decoding.

28-byte command frames ``0x02, 28, checksum, ..., 0x03`` and 31- or 56-byte sensor replies
``0x02, length, checksum, ..., 0x03``, with 8-bit additive checksums, 16-bit big-endian fields
and sign-magnitude wheel values (the vendor's ``Altino.h``). Every command frame carries every
field: the vendor's ``Go()`` and ``Sensor(1)`` send the same bytes, so a sensor request also
sets the motors and a Go is also a request. :mod:`frictiongym.hardware.altino_stock` drives a
car with them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from frictiongym.hardware.errors import ProtocolError

#: Start and end bytes of every frame.
STX, ETX = 0x02, 0x03
COMMAND_LENGTH = 28
#: Reply length of each sensor request: 1 = IR/torque/temperature/CDS, 2 = accel/mag/steering/
#: battery, 10 = everything (Altino.h ``Sensor()``).
REPLY_LENGTHS = {1: 31, 2: 31, 10: 56}
#: Largest wheel command (Altino.h ``Go()`` clamps to ±1000).
GO_LIMIT = 1000
_STOP_MODE = 255
_SIGN = 0x8000

#: Per-frame time on the car: the vendor's Arduino library waits 10 ms after each frame.
CAR_FRAME_S = 0.010
#: Wire time of one tick at 115200 baud 8N1 (10 bits a byte): a 28-byte command and a 31-byte
#: reply, 5.1 ms.
WIRE_S = (COMMAND_LENGTH + REPLY_LENGTHS[1]) * 10 / 115200
#: Fastest rate the stock link can carry: one frame and its reply per tick, plus the car's
#: 10 ms, 66 Hz. Bluetooth SPP adds tens of ms of latency: 10-20 Hz is realistic, 50 Hz at best.
STOCK_MAX_RATE_HZ = 1.0 / (WIRE_S + CAR_FRAME_S)
#: Stop frames sent by :meth:`AltinoStockBackend.stop`, 10 ms apart: the stock link
#: acknowledges nothing, so one lost frame must not leave the car driving (assumed).
STOP_REPEATS = 3

# Reply fields: name -> (first byte, count, kind); kinds u16/i16 big-endian, u8 (Altino.h).
_Field = tuple[int, int, str]
_LAYOUT: dict[int, dict[str, _Field]] = {
    1: {
        "ir": (7, 6, "u16"),
        "torque": (19, 2, "u16"),
        "temperature": (23, 1, "u16"),
        "cds": (25, 1, "u16"),
    },
    2: {
        "accel": (7, 3, "i16"),
        "mag": (13, 3, "i16"),
        "steering": (19, 1, "u16"),
        "steering_torque": (21, 1, "u16"),
        "battery": (23, 1, "u16"),
        "remote": (25, 1, "u8"),
        "motor_temperature": (26, 1, "u8"),
    },
    10: {
        "ir": (7, 6, "u16"),
        "torque": (19, 2, "u16"),
        "steering_torque": (23, 1, "u16"),
        "accel": (25, 3, "i16"),
        "mag": (31, 3, "i16"),
        "gyro": (37, 3, "i16"),
        "cds": (43, 1, "u16"),
        "steering": (45, 1, "u16"),
        "battery": (47, 1, "u16"),
        "temperature": (49, 1, "u16"),
        "remote": (51, 1, "u8"),
        "motor_temperature": (52, 1, "u8"),
    },
}


@dataclass(frozen=True)
class StockCommand:
    """The drive fields of a command frame (what :func:`parse_go_frame` returns)."""

    left: int  #: left wheel, -1000..1000
    right: int  #: right wheel, -1000..1000
    request: int  #: sensor group requested (0: none)
    stop: bool  #: both mode bytes are 255 (stop)


@dataclass(frozen=True)
class StockSensors:
    """One sensor reply; fields its group does not carry stay empty (``()``) or 0.

    The 16-bit accelerometer, magnetometer and gyro fields are read as two's complement.
    """

    group: int
    ir: tuple[int, ...] = ()  #: IR1..IR6 readouts (0..800 seen in practice); index 1 = front
    torque: tuple[int, ...] = ()  #: wheel torque (current), right then left
    temperature: int = 0
    cds: int = 0  #: light sensor
    accel: tuple[int, ...] = ()
    mag: tuple[int, ...] = ()
    gyro: tuple[int, ...] = ()
    steering: int = 0  #: steering potentiometer
    steering_torque: int = 0
    battery: int = 0
    remote: int = 0
    motor_temperature: int = 0


def command_checksum(frame: bytes | bytearray) -> int:
    """Checksum of a command frame: ``(byte 1 + sum of bytes 3..27) mod 256``."""
    return (frame[1] + sum(frame[3:COMMAND_LENGTH])) % 256


def reply_checksum(frame: bytes | bytearray) -> int:
    """Checksum of a sensor reply: the sum of every byte except byte 2, mod 256."""
    return (sum(frame) - frame[2]) % 256


def _wheel(name: str, value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or abs(value) > GO_LIMIT:
        raise ValueError(f"{name} must be an integer in -{GO_LIMIT}..{GO_LIMIT}, got {value!r}")
    return value if value >= 0 else _SIGN + (-value)


def go_frame(left: int, right: int, *, request: int = 1) -> bytes:
    """Encode ``Go(left, right)`` in 28 bytes, as the vendor's library sends it after ``Open()``.

    ``request`` is the sensor group the frame asks for (the library keeps that of its last
    ``Sensor()`` call; ``Open()`` sets 1). Steering, display, LEDs and sound are zero, as in
    a program that never sets them. A wheel value that is not an integer in -1000..1000 raises
    ``ValueError`` (the vendor's library clamps instead; we refuse to guess).
    """
    if request not in (0, *REPLY_LENGTHS):
        raise ValueError(f"request must be 0 or one of {sorted(REPLY_LENGTHS)}, got {request!r}")
    frame = bytearray(COMMAND_LENGTH)
    frame[0], frame[1], frame[3], frame[4] = STX, COMMAND_LENGTH, 1, request
    for mode_at, value in ((6, right), (9, left)):
        frame[mode_at] = _STOP_MODE if value == 0 else 0
    frame[7:9] = _wheel("right", right).to_bytes(2, "big")
    frame[10:12] = _wheel("left", left).to_bytes(2, "big")
    if request in (1, 10):
        frame[21] |= 0x01
    frame[COMMAND_LENGTH - 1] = ETX
    frame[2] = command_checksum(frame)
    return bytes(frame)


def sensor_request_frame(group: int, *, left: int = 0, right: int = 0) -> bytes:
    """Ask for sensor ``group`` (1, 2 or 10) while driving the wheels at ``left``/``right``.

    The frame carries the drive fields too (every stock frame does): a request with the
    default zeros also stops the car. ``sensor_request_frame(1, left=u, right=u)`` and
    ``go_frame(u, u)`` are the same bytes.
    """
    if group not in REPLY_LENGTHS:
        raise ValueError(f"sensor group must be one of {sorted(REPLY_LENGTHS)}, got {group!r}")
    return go_frame(left, right, request=group)


def parse_go_frame(frame: bytes) -> StockCommand:
    """Decode a 28-byte command frame; :class:`ProtocolError` if it is malformed."""
    if len(frame) != COMMAND_LENGTH or frame[0] != STX or frame[1] != COMMAND_LENGTH:
        raise ProtocolError(f"not a 28-byte Altino command frame: {bytes(frame[:4]).hex()}...")
    if frame[-1] != ETX or frame[2] != command_checksum(frame):
        raise ProtocolError("Altino command frame fails its end byte or checksum")

    def wheel(at: int) -> int:
        raw = int.from_bytes(frame[at : at + 2], "big")
        return -(raw - _SIGN) if raw & _SIGN else raw

    stop = frame[6] == _STOP_MODE and frame[9] == _STOP_MODE
    return StockCommand(left=wheel(10), right=wheel(7), request=frame[4], stop=stop)


def _value(frame: bytes, at: int, kind: str) -> int:
    if kind == "u8":
        return frame[at]
    return int.from_bytes(frame[at : at + 2], "big", signed=kind == "i16")


def parse_sensor_reply(frame: bytes) -> StockSensors:
    """Decode a 31- or 56-byte sensor reply; :class:`ProtocolError` if malformed or corrupt."""
    length = len(frame)
    if length < 5 or frame[0] != STX or frame[1] != length or length not in (31, 56):
        raise ProtocolError(
            f"not an Altino sensor reply ({length} bytes): {bytes(frame[:5]).hex()}"
        )
    if frame[-1] != ETX:
        raise ProtocolError("Altino sensor reply does not end with 0x03")
    if frame[2] != reply_checksum(frame):
        raise ProtocolError(
            f"Altino sensor reply checksum 0x{frame[2]:02x}, computed 0x{reply_checksum(frame):02x}"
        )
    group = frame[4]
    if group not in _LAYOUT or REPLY_LENGTHS[group] != length:
        raise ProtocolError(f"Altino sensor reply of {length} bytes names group {group}")
    fields: dict[str, Any] = {}
    for name, (at, count, kind) in _LAYOUT[group].items():
        step = 1 if kind == "u8" else 2
        values = tuple(_value(frame, at + step * i, kind) for i in range(count))
        fields[name] = values if count > 1 else values[0]
    return StockSensors(group=group, **fields)


def sensor_reply(sensors: StockSensors) -> bytes:
    """Encode ``sensors`` as the car would reply (the inverse of :func:`parse_sensor_reply`)."""
    length = REPLY_LENGTHS.get(sensors.group)
    if length is None:
        raise ValueError(f"sensor group must be one of {sorted(REPLY_LENGTHS)}")
    frame = bytearray(length)
    frame[0], frame[1], frame[4], frame[-1] = STX, length, sensors.group, ETX
    for name, (at, count, kind) in _LAYOUT[sensors.group].items():
        value = getattr(sensors, name)
        values = value if isinstance(value, tuple) else (value,)
        values = values + (0,) * (count - len(values))
        for i, v in enumerate(values[:count]):
            if kind == "u8":
                frame[at + i] = v
            else:
                frame[at + 2 * i : at + 2 * i + 2] = int(v).to_bytes(2, "big", signed=kind == "i16")
    frame[2] = reply_checksum(frame)
    return bytes(frame)


class BadReply(Exception):
    """A reply-shaped frame that fails its end byte or checksum."""


class ImplausibleReply(BadReply):
    """A reply that passes its checksum but whose readout the car cannot have produced.

    The 8-bit additive checksum lets about 0.5 % of two-bit corruptions through (a bit set in
    one byte and cleared in another at the same position sum alike); half of them make the wall
    look farther (IR 342 -> 86: 2.5 cm read as 7.4 cm). A readout that jumps farther than the
    car can move between two replies is taken for one of them.
    """


def take_reply(buffer: bytearray, length: int) -> bytes | None:
    """Pop the first reply of ``length`` bytes from ``buffer``, dropping garbage before it.

    Returns None while the reply is incomplete; raises :class:`BadReply` (after dropping
    the bad frame's start byte, so the search resynchronises) when it fails its checks.
    """
    while buffer:
        start = buffer.find(STX)
        if start < 0:
            buffer.clear()
            return None
        del buffer[:start]
        if len(buffer) >= 2 and buffer[1] != length:
            del buffer[0]
            continue
        if len(buffer) < length:
            return None
        frame = bytes(buffer[:length])
        if frame[-1] != ETX or frame[2] != reply_checksum(frame):
            del buffer[0]
            raise BadReply
        del buffer[:length]
        return frame
    return None
