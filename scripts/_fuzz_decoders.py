"""Frame decoders under fuzzing: the device protocol in Python (``protocol.py``) and C
(``fg_protocol.c``, compared on every stream), and the stock Altino's replies
(``altino_frames.py``). Part of ``fuzz_hardware.py``.
"""

from __future__ import annotations

import random
import struct

from _fuzz_common import CHarness, Part, Progress, case_rng, progress

from frictiongym.hardware import altino_frames as af
from frictiongym.hardware import protocol
from frictiongym.hardware.errors import ProtocolError

#: Streams per harness process: one process per batch keeps a crash to one batch.
BATCH = 2000


# --- frames -----------------------------------------------------------------------------------


def random_message(rng: random.Random) -> protocol.Message:
    """A valid message of any type, with fields over their whole range."""
    u16, i16 = rng.randrange(1 << 16), rng.randrange(-(1 << 15), 1 << 15)
    kind = rng.randrange(5)
    if kind == 0:
        return protocol.Command(
            u16, i16, protocol.Flag(rng.randrange(256)), rng.randrange(-(1 << 15), 1 << 15)
        )
    if kind == 1:
        return protocol.HelloRequest(rng.randrange(256))
    if kind == 2:
        bits = rng.randrange(1 << 32)
        return protocol.Place(struct.unpack("<f", struct.pack("<I", bits))[0])
    if kind == 3:
        return protocol.Hello(
            rng.randrange(256),
            rng.choice(list(protocol.DeviceKind)),
            protocol.Capability(rng.randrange(256)),
            rng.randrange(256),
            u16,
            rng.randrange(1 << 16),
            i16,
            rng.randrange(1 << 16),
            rng.randrange(1 << 32),
        )
    return protocol.State(
        protocol.Status(rng.randrange(256)),
        u16,
        rng.randrange(1 << 32),
        rng.randrange(1 << 16),
        i16,
        rng.randrange(-(1 << 31), 1 << 31),
        rng.randrange(-(1 << 15), 1 << 15),
    )


def _framed(payload: bytes, crc_xor: int = 0) -> bytes:
    crc = protocol.crc16(payload) ^ crc_xor
    return protocol.cobs_encode(payload + crc.to_bytes(2, "little"))


def _garbage(rng: random.Random, low: int, high: int, zeros: bool) -> bytes:
    first = 0 if zeros else 1
    return bytes(rng.randrange(first, 256) for _ in range(rng.randint(low, high)))


def damaged_frame(rng: random.Random) -> tuple[str, bytes, bytes]:
    """One frame (without its delimiter), valid or damaged in one of many ways.

    Returns the kind of damage, the frame, and the intact frame it was made from.
    """
    frame = protocol.encode(random_message(rng))[:-1]
    how = rng.choice(MUTATIONS)
    data = bytearray(frame)
    if how == "bit flips":
        for _ in range(rng.randint(1, 3)):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
    elif how == "truncated":
        del data[rng.randrange(len(data)) :]
    elif how == "extended":
        data += _garbage(rng, 1, 8, zeros=False)
    elif how == "byte replaced":
        data[rng.randrange(len(data))] = rng.randrange(1, 256)
    elif how == "garbage":
        data = bytearray(_garbage(rng, 0, 3 * protocol.MAX_FRAME, zeros=rng.random() < 0.5))
    elif how == "bad CRC":
        data = bytearray(_framed(protocol.pack(random_message(rng)), rng.randrange(1, 1 << 16)))
    elif how == "bad layout":  # a good CRC over a payload of the wrong type or length
        payload = bytearray(protocol.pack(random_message(rng)))
        if rng.random() < 0.5:
            payload = payload[: rng.randrange(len(payload))] or bytearray([payload[0]])
        else:
            payload[0] = rng.choice([0, 4, 0x7F, 0x82, 0xFF, rng.randrange(256)])
        data = bytearray(_framed(bytes(payload)))
    elif how == "COBS edge":
        data = bytearray(_cobs_edge(rng))
    return how, bytes(data), frame


def _cobs_edge(rng: random.Random) -> bytes:
    """Frames at the edges of COBS and of the decoders' buffers."""
    choice = rng.randrange(6)
    if choice == 0:  # a block code that runs past the end
        frame = bytearray(protocol.encode(random_message(rng))[:-1])
        frame[0] = min(255, len(frame) + rng.randint(1, 20))
        return bytes(frame)
    if choice == 1:  # code 0xFF and 254-byte blocks: longer than any frame
        return bytes([0xFF]) + _garbage(rng, 254, 254, zeros=False)
    if choice == 2:  # exactly the longest frame, and one byte more
        return _garbage(rng, protocol.MAX_FRAME, protocol.MAX_FRAME + 1, zeros=False)
    if choice == 3:  # a good CRC over the longest payload a frame may carry, and one more
        return _framed(_garbage(rng, protocol.MAX_PAYLOAD, protocol.MAX_PAYLOAD + 1, zeros=True))
    if choice == 4:  # every block of length one (all zeros)
        return bytes([1] * rng.randint(1, 40))
    return b""  # an empty frame: back-to-back delimiters


#: Mutations of the intact frame itself (the others make a new one, valid or not).
DAMAGES = ("bit flips", "truncated", "extended", "byte replaced")
MUTATIONS = (
    "none",
    "bit flips",
    "truncated",
    "extended",
    "byte replaced",
    "garbage",
    "bad CRC",
    "bad layout",
    "COBS edge",
)


def random_stream(rng: random.Random) -> tuple[bytes, list[tuple[str, bytes, bytes]]]:
    """Up to 8 frames, valid or damaged, with delimiters sometimes dropped or doubled.

    Returns the stream and each frame as :func:`damaged_frame` made it.
    """
    parts, made = [], []
    for _ in range(rng.randint(1, 8)):
        how, frame, intact = damaged_frame(rng)
        made.append((how, frame, intact))
        delimiter = rng.choices([b"\x00", b"", b"\x00\x00"], [0.9, 0.05, 0.05])[0]
        parts.append(frame + delimiter)
    return b"".join(parts), made


def _c_values(message: protocol.Message) -> tuple[int, ...]:
    """The numbers the C harness prints for ``message`` (a Place by its binary32 bits)."""
    if isinstance(message, protocol.Place):
        return (int(message.TYPE), int.from_bytes(protocol.pack(message)[1:5], "little"))
    return (int(message.TYPE), *(int(v) for v in message.fields()))


class PiecewiseDecoder(protocol.FrameDecoder):
    """A FrameDecoder fed a stream in random pieces, keeping what it decoded."""

    def __init__(self, rng: random.Random, stream: bytes) -> None:
        super().__init__()
        self.messages: list[protocol.Message] = []
        for at in _cuts(rng, len(stream)):
            self.messages += self.feed(stream[at[0] : at[1]])


def _cuts(rng: random.Random, length: int) -> list[tuple[int, int]]:
    """Random consecutive pieces (1-64 bytes) covering ``range(length)``."""
    cuts, at = [], 0
    while at < length:
        size = rng.randint(1, 64)
        cuts.append((at, min(length, at + size)))
        at += size
    return cuts


def check_python_stream(part: Part, case: str, stream: bytes, rng: random.Random) -> list[str]:
    """Decode ``stream`` whole and in random pieces; return the C harness's expected lines."""
    try:
        whole = protocol.FrameDecoder()
        messages = whole.feed(stream)
        pieces = PiecewiseDecoder(rng, stream)
    except Exception as exc:
        part.fail(f"{case}: FrameDecoder raised {type(exc).__name__}: {exc}")
        return []
    encoded = [protocol.encode(m) for m in messages]  # bytes: a NaN Place is not equal to itself
    if [protocol.encode(m) for m in pieces.messages] != encoded or (
        pieces.frames,
        pieces.errors,
    ) != (
        whole.frames,
        whole.errors,
    ):
        part.fail(f"{case}: the decoder's result depends on how the stream is split")
    chunks = set(stream.split(b"\x00"))
    for message, frame in zip(messages, encoded, strict=True):
        if frame[:-1] not in chunks:
            part.fail(f"{case}: accepted {message!r}, which no frame of the stream encodes")
    for chunk in chunks:
        _check_python_frame(part, case, chunk)
    expected = [" ".join(map(str, ("msg", *_c_values(m)))) for m in messages]
    return [*expected, f"count {whole.frames} {whole.errors}"]


def _check_python_frame(part: Part, case: str, frame: bytes) -> None:
    try:
        message = protocol.decode(frame)
    except protocol.FrameError:
        return
    except Exception as exc:
        part.fail(f"{case}: decode raised {type(exc).__name__}: {exc} on {frame.hex()}")
        return
    if protocol.encode(message)[:-1] != frame:
        part.fail(f"{case}: decode accepted {frame.hex()}, which is not how {message!r} encodes")


def fuzz_frames(cases: range, seed: int, harness: CHarness | None, say: Progress) -> Part:
    """Random and damaged frame streams through protocol.py and fg_protocol.c."""
    part = Part.named("frames")
    frames = damaged = collided = 0
    requests: list[str] = []
    expected: list[list[str]] = []
    for case in cases:
        rng = case_rng(seed, "frames", case)
        stream, made = random_stream(rng)
        frames += len(made)
        damaged += sum(frame != intact for _, frame, intact in made)
        lines = check_python_stream(part, f"frames case {case}", stream, rng)
        collided += sum(
            how in DAMAGES and frame != intact and _decodes(frame) for how, frame, intact in made
        )
        if harness is not None:
            requests.append(f"stream {stream.hex() or '-'}")
            expected.append(lines)
            if len(requests) == BATCH or case == cases[-1]:
                _compare_with_c(part, harness, requests, expected, case + 1 - len(requests))
                requests, expected = [], []
        progress(say, part, cases, case, "streams")
    part.cases = len(cases)
    c_side = "C (ASan+UBSan)" if harness and harness.sanitized else "C" if harness else "no C"
    part.notes.append(
        f"frames: {frames} frames ({damaged} damaged) in {len(cases)} streams; {c_side}; frames "
        f"damaged by bit flips, truncation, extension or a replaced byte that still formed a "
        f"valid frame (a CRC-16 collision, which the decoders must accept): {collided}"
    )
    return part


def _decodes(frame: bytes) -> bool:
    """Whether ``frame`` is a valid frame (a damaged one: a CRC-16 collision, well-formed)."""
    try:
        protocol.decode(frame)
    except protocol.FrameError:
        return False
    return True


def _compare_with_c(
    part: Part, harness: CHarness, requests: list[str], expected: list[list[str]], first: int
) -> None:
    answers, stderr = harness.run(requests)
    if answers is None:
        part.fail(
            f"frames cases {first}..{first + len(requests) - 1}: the C harness died: "
            f"{stderr.strip()[:300]}"
        )
        return
    if stderr.strip():
        part.fail(f"frames cases {first}..: the C harness reported: {stderr.strip()[:300]}")
    for i, (got, want) in enumerate(zip(answers, expected, strict=True)):
        if got != want:
            part.fail(f"frames case {first + i}: C decoded {got[:3]}..., Python {want[:3]}...")


# --- the stock Altino's replies -----------------------------------------------------------------


def _random_sensors(rng: random.Random) -> af.StockSensors:
    group = rng.choice(sorted(af.REPLY_LENGTHS))
    ir = tuple(rng.randrange(801) for _ in range(6))
    if group == 2:
        return af.StockSensors(
            group=2, accel=(rng.randrange(-999, 999),) * 3, battery=rng.randrange(1 << 16)
        )
    return af.StockSensors(group=group, ir=ir, torque=(rng.randrange(1 << 16),) * 2)


def _damage(rng: random.Random, frame: bytes) -> tuple[str, bytes]:
    data = bytearray(frame)
    how = rng.choice(("none", "1 bit", "2 bits", "3 bits", "truncated", "garbage", "checksum"))
    if how.endswith(("bit", "bits")):
        spots = rng.sample(range(len(data) * 8), int(how[0]))
        for spot in spots:
            data[spot // 8] ^= 1 << (spot % 8)
    elif how == "truncated":
        del data[rng.randrange(len(data)) :]
    elif how == "garbage":
        data = bytearray(_garbage(rng, 0, 80, zeros=True))
    elif how == "checksum":
        data[2] = (data[2] + rng.randrange(1, 256)) % 256
    return how, bytes(data)


def _well_formed(frame: bytes, group: bool = True) -> bool:
    """What an accepted reply must be, computed apart from the decoder.

    ``group=False``: not its group byte (``take_reply`` leaves that to the parser).
    """
    total = sum(frame) - frame[2]
    return (
        len(frame) in (31, 56)
        and frame[0] == af.STX
        and frame[1] == len(frame)
        and frame[-1] == af.ETX
        and frame[2] == total % 256
        and (not group or af.REPLY_LENGTHS.get(frame[4]) == len(frame))
    )


def fuzz_altino(cases: range, seed: int, say: Progress) -> Part:
    """Damaged stock Altino replies through parse_sensor_reply and take_reply."""
    part = Part.named("altino replies")
    passed = {k: [0, 0] for k in ("1 bit", "2 bits", "3 bits")}
    for case in cases:
        rng = case_rng(seed, "altino", case)
        sensors = _random_sensors(rng)
        intact = af.sensor_reply(sensors)
        how, frame = _damage(rng, intact)
        try:
            parsed = af.parse_sensor_reply(frame)
        except ProtocolError:
            parsed = None
        except Exception as exc:
            part.fail(f"altino case {case}: parse raised {type(exc).__name__}: {exc}")
            continue
        if parsed is not None and not _well_formed(frame):
            part.fail(f"altino case {case}: accepted a malformed reply {frame.hex()}")
        if how in passed and frame != intact:
            passed[how][0] += 1
            passed[how][1] += parsed is not None
        _check_take_reply(part, case, rng, frame, intact)
        progress(say, part, cases, case, "replies")
    part.cases = len(cases)
    rates = ", ".join(f"{k}: {n} of {t}" for k, (t, n) in passed.items())
    part.notes.append(
        "altino: damaged replies the 8-bit additive checksum let through (a limit of the "
        f"vendor's protocol; the stock backend also refuses implausible readout jumps): {rates}"
    )
    return part


def _check_take_reply(
    part: Part, case: int, rng: random.Random, frame: bytes, intact: bytes
) -> None:
    """Garbage, the frame, garbage, an intact reply: the reader must end on the intact one."""
    stream = _garbage(rng, 0, 40, zeros=True) + frame + _garbage(rng, 0, 40, zeros=True) + intact
    buffer, got, at = bytearray(), [], 0
    for _ in range(10 * len(stream) + 10):  # every call consumes or waits: bounded
        if at < len(stream) and (not buffer or rng.random() < 0.5):
            size = rng.randint(1, 64)
            buffer += stream[at : at + size]
            at += size
        try:
            reply = af.take_reply(buffer, len(intact))
        except af.BadReply:
            continue
        except Exception as exc:
            part.fail(f"altino case {case}: take_reply raised {type(exc).__name__}: {exc}")
            return
        if reply is not None:
            got.append(reply)
            if not _well_formed(reply, group=False):
                part.fail(f"altino case {case}: take_reply returned a malformed {reply.hex()}")
        elif at >= len(stream):
            break
    if not got or got[-1] != intact:
        part.fail(f"altino case {case}: the reader lost the intact reply after the damage")
