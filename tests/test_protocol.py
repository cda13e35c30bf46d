"""frictiongym.hardware.protocol: CRC, COBS, messages, the stream decoder, and fuzzing.

The fuzz tests check ``FrameDecoder`` against an independent reference written here (split on
0x00, a second COBS decoder, ``binascii.crc_hqx``): random bytes and damaged streams never make
``feed`` raise, and it yields exactly the frames whose CRC holds.
"""

from __future__ import annotations

import binascii
import importlib.util
import json
import math
import struct
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from frictiongym.hardware import protocol
from frictiongym.hardware.errors import HardwareError, ProtocolError

ROOT = Path(__file__).resolve().parents[1]
VECTOR_FILE = ROOT / "tests" / "data" / "protocol_vectors.json"
VECTORS = json.loads(VECTOR_FILE.read_text())

I16 = st.integers(-(2**15), 2**15 - 1)
U16 = st.integers(0, 2**16 - 1)
commands = st.builds(protocol.Command, U16, I16, st.builds(protocol.Flag, st.integers(0, 255)), I16)
hello_requests = st.builds(protocol.HelloRequest, st.integers(0, 255))
places = st.builds(protocol.Place, st.floats(width=32, allow_nan=False))
hellos = st.builds(
    protocol.Hello,
    st.integers(0, 255),
    st.sampled_from(protocol.DeviceKind),
    st.builds(protocol.Capability, st.integers(0, 255)),
    U16,
    U16,
    U16,
    I16,
    U16,
    st.integers(0, 2**32 - 1),
)
states = st.builds(
    protocol.State,
    st.builds(protocol.Status, st.integers(0, 255)),
    U16,
    st.integers(0, 2**32 - 1),
    U16,
    I16,
    st.integers(-(2**31), 2**31 - 1),
    I16,
)
messages = st.one_of(commands, hello_requests, places, hellos, states)

# COBS inputs: arbitrary bytes, runs of zeros, and whole 254/255-byte blocks.
cobs_inputs = st.one_of(
    st.binary(max_size=700),
    st.lists(st.sampled_from([0, 0, 0, 1, 255]), max_size=600).map(bytes),
    st.lists(
        st.sampled_from([bytes(range(1, 255)), bytes(range(1, 256)), b"\x00", b"\x07" * 253]),
        max_size=4,
    ).map(b"".join),
)


# --- CRC ---------------------------------------------------------------------------------------


def _crc_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE from its definition: poly 0x1021, init 0xFFFF, MSB first."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021 if crc & 0x8000 else crc << 1) & 0xFFFF
    return crc


def test_crc_check_value() -> None:
    assert protocol.crc16(b"123456789") == 0x29B1  # the CRC catalogue's check for CCITT-FALSE


@given(st.binary(max_size=300))
def test_crc_matches_its_definition(data: bytes) -> None:
    assert protocol.crc16(data) == _crc_bitwise(data)


# --- COBS --------------------------------------------------------------------------------------


@given(cobs_inputs)
def test_cobs_round_trip(data: bytes) -> None:
    encoded = protocol.cobs_encode(data)
    assert 0 not in encoded
    assert len(encoded) <= len(data) + len(data) // 254 + 1
    assert protocol.cobs_decode(encoded) == data


@pytest.mark.parametrize(
    ("data", "encoded"),
    [
        (b"", b"\x01"),
        (b"\x00", b"\x01\x01"),
        (b"\x00\x00", b"\x01\x01\x01"),
        (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
        (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
        (bytes(range(1, 255)), b"\xff" + bytes(range(1, 255)) + b"\x01"),
        (bytes(range(1, 256)), b"\xff" + bytes(range(1, 255)) + b"\x02\xff"),
    ],
)
def test_cobs_known_encodings(data: bytes, encoded: bytes) -> None:
    assert protocol.cobs_encode(data) == encoded
    assert protocol.cobs_decode(encoded) == data


def test_cobs_decodes_a_final_full_block_without_its_empty_successor() -> None:
    # Encoders that omit the trailing 0x01 after a final 254-byte block interoperate.
    assert protocol.cobs_decode(b"\xff" + bytes(range(1, 255))) == bytes(range(1, 255))


@pytest.mark.parametrize("frame", [b"\x00", b"\x05\x01\x02", b"\x03\x01\x00", b"\x02\x01\x00\x01"])
def test_cobs_rejects_malformed_blocks(frame: bytes) -> None:
    with pytest.raises(protocol.FrameError, match="COBS"):
        protocol.cobs_decode(frame)


# --- messages ----------------------------------------------------------------------------------


@given(messages)
def test_every_message_round_trips(message: protocol.Message) -> None:
    wire = protocol.encode(message)
    assert wire.endswith(b"\x00")
    assert 0 not in wire[:-1]
    assert len(wire) - 1 <= protocol.MAX_FRAME
    assert protocol.decode(wire[:-1]) == message
    assert protocol.unpack(protocol.pack(message)) == message


def test_place_nan_decodes_as_nan() -> None:
    decoded = protocol.decode(protocol.encode(protocol.Place(math.nan))[:-1])
    assert isinstance(decoded, protocol.Place)
    assert math.isnan(decoded.position)


def test_payload_sizes_match_the_documented_table() -> None:
    sizes = {
        protocol.Command: 8,
        protocol.HelloRequest: 2,
        protocol.Place: 5,
        protocol.Hello: 18,
        protocol.State: 18,
    }
    for cls, size in sizes.items():
        assert struct.calcsize(cls.FORMAT) == size  # type: ignore[attr-defined]
        assert size + 2 <= protocol.MAX_PAYLOAD


@pytest.mark.parametrize(
    "message",
    [
        protocol.Command(seq=65536, command=0),
        protocol.Command(seq=-1, command=0),
        protocol.Command(seq=0, command=40000),
        protocol.Command(seq=0, command=0, flags=protocol.Flag(256)),
        protocol.Place(1e39),
        protocol.State(protocol.Status(0), 0, 2**32, 0, 0, 0),
        protocol.State(protocol.Status(0), 0, 0, 0, 0, 2**31),
    ],
)
def test_pack_refuses_what_does_not_fit(message: protocol.Message) -> None:
    with pytest.raises(ValueError, match="does not fit"):
        protocol.pack(message)


@pytest.mark.parametrize(
    ("payload", "match"),
    [
        (b"", "empty"),
        (b"\x42\x00", "unknown message type"),
        (b"\x01\x01\x00", "expected 8"),
        (protocol.pack(protocol.State(protocol.Status(0), 0, 0, 0, 0, 0)) + b"\x00", "expected 18"),
        (b"\x80\x01\x07" + bytes(15), "unknown device kind"),
    ],
)
def test_unpack_rejects_bad_payloads(payload: bytes, match: str) -> None:
    with pytest.raises(protocol.FrameError, match=match):
        protocol.unpack(payload)


def test_frame_errors_are_hardware_errors() -> None:
    assert issubclass(protocol.FrameError, ProtocolError)
    assert issubclass(protocol.FrameError, HardwareError)


# --- the shared vectors ------------------------------------------------------------------------


def _load_script() -> Any:
    spec = importlib.util.spec_from_file_location(
        "protocol_vectors", ROOT / "scripts" / "protocol_vectors.py"
    )
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_vector_file_is_what_the_script_writes_now() -> None:
    assert VECTOR_FILE.read_text(encoding="utf-8") == _load_script().render(), (
        "tests/data/protocol_vectors.json is out of date: run python scripts/protocol_vectors.py"
    )


@pytest.mark.parametrize("vector", VECTORS["messages"], ids=lambda v: v["name"])
def test_vectors_decode_in_python(vector: dict[str, Any]) -> None:
    message = protocol.decode(bytes.fromhex(vector["wire"])[:-1])
    assert protocol.pack(message).hex() == vector["payload"]
    assert protocol.crc16(bytes.fromhex(vector["payload"])) == vector["crc"]


@pytest.mark.parametrize("vector", VECTORS["corrupt"], ids=lambda v: v["name"])
def test_corrupted_vectors_are_rejected(vector: dict[str, Any]) -> None:
    with pytest.raises(protocol.FrameError):
        protocol.decode(bytes.fromhex(vector["frame"]))


# --- FrameDecoder ------------------------------------------------------------------------------


def _feed_in_chunks(
    decoder: protocol.FrameDecoder, stream: bytes, cuts: list[int]
) -> list[protocol.Message]:
    out: list[protocol.Message] = []
    start = 0
    for cut in [*sorted(cuts), len(stream)]:
        out += decoder.feed(stream[start:cut])
        start = max(start, cut)
    return out


@given(st.lists(messages, max_size=10), st.lists(st.integers(0, 300), max_size=20))
def test_decoder_splits_streams_fed_in_any_chunks(
    batch: list[protocol.Message], cuts: list[int]
) -> None:
    stream = b"".join(protocol.encode(m) for m in batch)
    decoder = protocol.FrameDecoder()
    got = _feed_in_chunks(decoder, stream, [c for c in cuts if c <= len(stream)])
    assert [protocol.pack(m) for m in got] == [protocol.pack(m) for m in batch]
    assert (decoder.frames, decoder.errors) == (len(batch), 0)


def test_decoder_resynchronises_after_garbage() -> None:
    a, b = (
        protocol.Command(seq=1, command=100),
        protocol.State(protocol.Status(0), 1, 2000, 1, 100, 7),
    )
    decoder = protocol.FrameDecoder()
    assert decoder.feed(b"\x13\x37\xff") == []  # mid-frame start: no delimiter yet
    assert decoder.feed(b"\x42" + protocol.encode(a)) == []  # the garbage glues onto a's frame
    assert decoder.errors == 1
    assert decoder.feed(protocol.encode(a) + b"\x05\x06\x00" + protocol.encode(b)) == [a, b]
    assert (decoder.frames, decoder.errors) == (2, 2)


def test_decoder_skips_empty_frames_without_counting() -> None:
    decoder = protocol.FrameDecoder()
    assert decoder.feed(b"\x00\x00" + protocol.encode(protocol.HelloRequest()) + b"\x00") == [
        protocol.HelloRequest()
    ]
    assert (decoder.frames, decoder.errors) == (1, 0)


def test_decoder_stays_bounded_on_endless_garbage() -> None:
    decoder = protocol.FrameDecoder()
    junk = bytes(range(1, 256)) * 20
    for _ in range(200):  # 1 MB without a delimiter
        assert decoder.feed(junk) == []
        assert len(decoder._partial) <= protocol.MAX_FRAME
    command = protocol.Command(seq=9, command=-9)
    assert decoder.feed(b"\x00" + protocol.encode(command)) == [command]
    assert (decoder.frames, decoder.errors) == (1, 1)


# --- fuzzing -----------------------------------------------------------------------------------


def _reference_cobs_decode(frame: bytes) -> bytes | None:
    """COBS decoding written independently of protocol.py (None: malformed)."""
    out, i = bytearray(), 0
    while i < len(frame):
        code = frame[i]
        block = frame[i + 1 : i + code]
        if code == 0 or len(block) != code - 1 or 0 in block:
            return None
        out += block
        i += code
        if code < 0xFF and i < len(frame):
            out.append(0)
    return bytes(out)


def _reference_decode(stream: bytes) -> tuple[list[bytes], int, int]:
    """Payloads of the good frames of ``stream``, the count of good and of bad frames."""
    *segments, _partial = stream.split(b"\x00")
    payloads, bad = [], 0
    for segment in filter(None, segments):
        data = _reference_cobs_decode(segment) if len(segment) <= protocol.MAX_FRAME else None
        if data is None or len(data) < 3:
            bad += 1
            continue
        payload, crc = data[:-2], int.from_bytes(data[-2:], "little")
        if binascii.crc_hqx(payload, 0xFFFF) != crc:
            bad += 1
            continue
        try:
            protocol.unpack(payload)
        except protocol.FrameError:
            bad += 1
            continue
        payloads.append(payload)
    return payloads, len(payloads), bad


def _check_decoder_on(stream: bytes, cuts: list[int]) -> None:
    decoder = protocol.FrameDecoder()
    got = _feed_in_chunks(decoder, stream, [c for c in cuts if c <= len(stream)])
    payloads, good, bad = _reference_decode(stream)
    assert [protocol.pack(m) for m in got] == [protocol.pack(protocol.unpack(x)) for x in payloads]
    assert (decoder.frames, decoder.errors) == (good, bad)
    for message in got:  # every message came from a frame with a valid CRC in the input
        if not (isinstance(message, protocol.Place) and math.isnan(message.position)):
            assert protocol.encode(message) in b"\x00" + stream


@given(st.binary(max_size=3000), st.lists(st.integers(0, 3000), max_size=30))
def test_fuzz_random_bytes(stream: bytes, cuts: list[int]) -> None:
    _check_decoder_on(stream, cuts)


@given(
    st.lists(messages, max_size=12),
    st.lists(
        st.tuples(
            st.sampled_from(["flip", "drop", "insert"]), st.integers(0, 10**6), st.integers(0, 255)
        ),
        max_size=8,
    ),
    st.lists(st.integers(0, 400), max_size=10),
)
def test_fuzz_damaged_streams(
    batch: list[protocol.Message], damage: list[tuple[str, int, int]], cuts: list[int]
) -> None:
    stream = bytearray(b"".join(protocol.encode(m) for m in batch))
    for action, where, value in damage:
        if not stream:
            break
        at = where % len(stream)
        if action == "flip":
            stream[at] ^= 1 << (value % 8)
        elif action == "drop":
            del stream[at]
        else:
            stream.insert(at, value)
    _check_decoder_on(bytes(stream), cuts)
