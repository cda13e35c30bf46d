"""The wire side of ``fuzz_hardware.py``: frame decoders (Python and C), stock Altino replies,
and the device watchdog (the C firmware and its Python twin).

Imported by ``fuzz_hardware.py`` as ``_fuzz_wire`` (the scripts' folder is first on
``sys.path`` when it runs); not part of the package. Every case is drawn from
``random.Random(f"{seed}:{part}:{case}")``, so one failing case can be replayed alone.
"""

from __future__ import annotations

import os
import random
import shutil
import struct
import subprocess
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from frictiongym.hardware import altino_frames as af
from frictiongym.hardware import protocol as p
from frictiongym.hardware.errors import ProtocolError
from frictiongym.hardware.firmware import Firmware

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware"
CFLAGS = ["-Wall", "-Wextra", "-Werror", "-std=c99", "-pedantic", "-g", "-O1"]
SANITIZERS = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
#: Streams per harness process: one process per batch keeps a crash to one batch.
BATCH = 2000
#: Longest a harness batch may take before it counts as hung, s.
BATCH_TIMEOUT = 600.0
Progress = Callable[[str], None]


#: What each part tries, and what every case of it must satisfy (the summary's columns).
WHAT: dict[str, tuple[str, str]] = {
    "frames": (
        "streams of 1-8 frames of every message type: intact, bit flips, truncated, extended, "
        "a byte replaced, garbage, bad CRC, good CRC over a bad layout, COBS edges; "
        "delimiters dropped or doubled; fed whole and in random pieces",
        "no exception but FrameError; every accepted frame is exactly a valid encoding; the "
        "result does not depend on the pieces; C (sanitized) == Python on every stream",
    ),
    "altino replies": (
        "stock Altino sensor replies (groups 1, 2, 10): intact, 1-3 bit flips, truncated, "
        "garbage, bad checksum, parsed alone and taken from a stream in random pieces",
        "no exception but ProtocolError/BadReply; every reply parsed is well-formed (start, "
        "length, end, checksum, group), every one taken from a stream too (but for its group, "
        "which the parser checks); the reader always finds the intact reply after",
    ),
    "watchdog": (
        "the servo and Altino firmware (fg_device.c and firmware.py) armed, sent commands "
        "at random times closer than its watchdog (the default, 5-50 ms or 100-400 ms; the "
        "Altino's driving away from the wall), then silence; clocks near the 32-bit µs wrap",
        "the motor holds while commands come and is 0 from the first tick at or past the "
        "watchdog time after the last command; C and Python agree tick by tick",
    ),
    "actions": (
        "device envs (servo and Altino) on the lock-step emulator over a pty, stepped with "
        "NaN, inf, huge floats and ints, strings, dates, None, complex, objects, bools, "
        "object arrays, wrong shapes, fractions, int64 extremes, between ordinary actions",
        "a refused action raises ValueError and zeroes the motor; the device never receives a "
        "command beyond its limit; non-numbers, non-finite and wrong shapes are refused; the "
        "run log holds every step that returned",
    ),
    "stock altino": (
        "the stock Altino backend driving a fake car on a pty at 50 Hz, each ordinary "
        "command followed by a hostile one (as for the actions)",
        "a refused command raises ValueError and the car receives the stop frames at once; "
        "no wheel value beyond 1000 and no malformed frame ever reaches the car",
    ),
    "faults": (
        "the servo env on the real-time emulator (500 Hz) stepped 20-200 times, then: the "
        "device unplugged, the device frozen (no more frames), or the host silent; a link "
        "delaying every frame by 0.12-0.3 s (the device's watchdog at 1 s); a link damaging "
        "1-10 % of the frames and dropping bytes, over 500 steps",
        "unplug/freeze raise DeviceDisconnectedError/DeviceTimeoutError, the delayed link a "
        "HardwareError within 25 steps with the motor zeroed, each with the log holding "
        "every step returned; after host silence the device's watchdog zeroes the motor "
        "within its time plus a period and the next step raises WatchdogTripError; over the "
        "damaging link every sample returned is the device's own state at its tick",
    ),
    "model files": (
        "copies of models/residual/rotary.zip carrying pickles (an added data entry, SB3's "
        "own entries, policy_kwargs, policy.pth or pytorch_variables.pth as a plain or a "
        "torch pickle), JSON values replaced, bits flipped, truncated; 1-3 at once",
        "nothing runs (no marker file, no pickle.find_class/os.system/subprocess audit "
        "event); the only error is ValueError (UnsafeModelError among them)",
    ),
    "params files": (
        "the two identified friction.json files with a value replaced (NaN, inf, 1e308, "
        "negative, strings, null, lists, 10^400, nesting up to 100 000 deep), a key dropped "
        "or doubled, bytes replaced, truncated, invalid UTF-8, another top-level value",
        "the only error is ParamsFileError; every file that loads has finite parameters "
        "inside their physical ranges",
    ),
}


@dataclass
class Part:
    """What one part of the fuzzing tried and what held."""

    name: str
    tried: str  #: what the cases were
    held: str  #: what every case had to satisfy
    cases: int = 0
    failures: list[str] = field(default_factory=list)
    #: Findings that are not failures (counts of known limits), printed under the table.
    notes: list[str] = field(default_factory=list)

    @classmethod
    def named(cls, name: str) -> Part:
        """The part ``name``, described by :data:`WHAT`."""
        return cls(name, *WHAT[name])

    def fail(self, message: str) -> None:
        """Record a failure (the first 20 are kept verbatim, the rest only counted)."""
        self.failures.append(message)


def progress(say: Progress, part: Part, cases: range, case: int, unit: str) -> None:
    """Say how far ``part`` got, ten times over its ``cases`` (``case`` just done)."""
    done = case + 1 - cases.start
    if done % max(1, len(cases) // 10) == 0:
        say(f"{part.name}: {done}/{len(cases)} {unit}, {len(part.failures)} failures")


def case_rng(seed: int, part: str, case: int) -> random.Random:
    """The generator of one case: a case can be replayed from its seed, part and number."""
    return random.Random(f"{seed}:{part}:{case}")


# --- the C harness ----------------------------------------------------------------------------


class HarnessBuildError(RuntimeError):
    """The C harness did not compile (the message holds the compiler's errors)."""


class CHarness:
    """firmware/test/host_harness.c built with the system compiler, run in batches.

    Built with AddressSanitizer and UBSan when the compiler links them (any report aborts the
    process, which then counts as a failure of its batch).
    """

    def __init__(self, workdir: Path, firmware: Path = FIRMWARE) -> None:
        compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
        if compiler is None:
            raise HarnessBuildError("no C compiler (cc or gcc) on PATH: install gcc or pass --no-c")
        sources = [*sorted((firmware / "common").glob("*.c")), firmware / "test" / "host_harness.c"]
        self.exe = workdir / "host_harness"
        self.sanitized = self._compile(compiler, [*CFLAGS, *SANITIZERS], sources)
        if not self.sanitized:
            self._compile(compiler, CFLAGS, sources, check=True)

    def _compile(
        self, compiler: str, flags: list[str], sources: list[Path], check: bool = False
    ) -> bool:
        done = subprocess.run(
            [compiler, *flags, *map(str, sources), "-o", str(self.exe)],
            capture_output=True,
            text=True,
            check=False,
        )
        if check and done.returncode != 0:
            raise HarnessBuildError(
                f"{compiler} failed on the C harness (or pass --no-c):\n{done.stderr}"
            )
        return done.returncode == 0

    def run(self, requests: list[str]) -> tuple[list[list[str]] | None, str]:
        """Answer ``requests``; return the answers (None if the process died) and its stderr."""
        text = "\n".join(requests) + "\nquit\n"
        done = subprocess.run(
            [str(self.exe)], input=text, capture_output=True, text=True, timeout=BATCH_TIMEOUT
        )
        answers = done.stdout.split("\n.\n")
        if done.returncode != 0 or len(answers) != len(requests) + 1:
            return None, done.stderr or f"exit status {done.returncode}"
        return [a.split("\n") if a else [] for a in answers[:-1]], done.stderr


# --- frames -----------------------------------------------------------------------------------


def random_message(rng: random.Random) -> p.Message:
    """A valid message of any type, with fields over their whole range."""
    u16, i16 = rng.randrange(1 << 16), rng.randrange(-(1 << 15), 1 << 15)
    kind = rng.randrange(5)
    if kind == 0:
        return p.Command(u16, i16, p.Flag(rng.randrange(256)), rng.randrange(-(1 << 15), 1 << 15))
    if kind == 1:
        return p.HelloRequest(rng.randrange(256))
    if kind == 2:
        bits = rng.randrange(1 << 32)
        return p.Place(struct.unpack("<f", struct.pack("<I", bits))[0])
    if kind == 3:
        return p.Hello(
            rng.randrange(256), rng.choice(list(p.DeviceKind)), p.Capability(rng.randrange(256)),
            rng.randrange(256), u16, rng.randrange(1 << 16), i16, rng.randrange(1 << 16),
            rng.randrange(1 << 32),
        )  # fmt: skip
    return p.State(
        p.Status(rng.randrange(256)), u16, rng.randrange(1 << 32), rng.randrange(1 << 16), i16,
        rng.randrange(-(1 << 31), 1 << 31), rng.randrange(-(1 << 15), 1 << 15),
    )  # fmt: skip


def _framed(payload: bytes, crc_xor: int = 0) -> bytes:
    crc = p.crc16(payload) ^ crc_xor
    return p.cobs_encode(payload + crc.to_bytes(2, "little"))


def _garbage(rng: random.Random, low: int, high: int, zeros: bool) -> bytes:
    first = 0 if zeros else 1
    return bytes(rng.randrange(first, 256) for _ in range(rng.randint(low, high)))


def damaged_frame(rng: random.Random) -> tuple[str, bytes, bytes]:
    """One frame (without its delimiter), valid or damaged in one of many ways.

    Returns the kind of damage, the frame, and the intact frame it was made from.
    """
    frame = p.encode(random_message(rng))[:-1]
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
        data = bytearray(_garbage(rng, 0, 3 * p.MAX_FRAME, zeros=rng.random() < 0.5))
    elif how == "bad CRC":
        data = bytearray(_framed(p.pack(random_message(rng)), rng.randrange(1, 1 << 16)))
    elif how == "bad layout":  # a good CRC over a payload of the wrong type or length
        payload = bytearray(p.pack(random_message(rng)))
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
        frame = bytearray(p.encode(random_message(rng))[:-1])
        frame[0] = min(255, len(frame) + rng.randint(1, 20))
        return bytes(frame)
    if choice == 1:  # code 0xFF and 254-byte blocks: longer than any frame
        return bytes([0xFF]) + _garbage(rng, 254, 254, zeros=False)
    if choice == 2:  # exactly the longest frame, and one byte more
        return _garbage(rng, p.MAX_FRAME, p.MAX_FRAME + 1, zeros=False)
    if choice == 3:  # a good CRC over the longest payload a frame may carry, and one more
        return _framed(_garbage(rng, p.MAX_PAYLOAD, p.MAX_PAYLOAD + 1, zeros=True))
    if choice == 4:  # every block of length one (all zeros)
        return bytes([1] * rng.randint(1, 40))
    return b""  # an empty frame: back-to-back delimiters


#: Mutations of the intact frame itself (the others make a new one, valid or not).
DAMAGES = ("bit flips", "truncated", "extended", "byte replaced")
MUTATIONS = ("none", "bit flips", "truncated", "extended", "byte replaced", "garbage", "bad CRC",
             "bad layout", "COBS edge")  # fmt: skip


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


def _c_values(message: p.Message) -> tuple[int, ...]:
    """The numbers the C harness prints for ``message`` (a Place by its binary32 bits)."""
    if isinstance(message, p.Place):
        return (int(message.TYPE), int.from_bytes(p.pack(message)[1:5], "little"))
    return (int(message.TYPE), *(int(v) for v in message.fields()))


class PiecewiseDecoder(p.FrameDecoder):
    """A FrameDecoder fed a stream in random pieces, keeping what it decoded."""

    def __init__(self, rng: random.Random, stream: bytes) -> None:
        super().__init__()
        self.messages: list[p.Message] = []
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
        whole = p.FrameDecoder()
        messages = whole.feed(stream)
        pieces = PiecewiseDecoder(rng, stream)
    except Exception as exc:
        part.fail(f"{case}: FrameDecoder raised {type(exc).__name__}: {exc}")
        return []
    encoded = [p.encode(m) for m in messages]  # bytes: a NaN Place is not equal to itself
    if [p.encode(m) for m in pieces.messages] != encoded or (pieces.frames, pieces.errors) != (
        whole.frames, whole.errors,
    ):  # fmt: skip
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
        message = p.decode(frame)
    except p.FrameError:
        return
    except Exception as exc:
        part.fail(f"{case}: decode raised {type(exc).__name__}: {exc} on {frame.hex()}")
        return
    if p.encode(message)[:-1] != frame:
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
        p.decode(frame)
    except p.FrameError:
        return False
    return True


def _compare_with_c(
    part: Part, harness: CHarness, requests: list[str], expected: list[list[str]], first: int
) -> None:
    answers, stderr = harness.run(requests)
    if answers is None:
        part.fail(f"frames cases {first}..{first + len(requests) - 1}: the C harness died: "
                  f"{stderr.strip()[:300]}")  # fmt: skip
        return
    if stderr.strip():
        part.fail(f"frames cases {first}..: the C harness reported: {stderr.strip()[:300]}")
    for i, (got, want) in enumerate(zip(answers, expected, strict=True)):
        if got != want:
            part.fail(f"frames case {first + i}: C decoded {got[:3]}..., Python {want[:3]}...")


def build_harness(
    firmware: Path | None,
) -> tuple[CHarness | None, tempfile.TemporaryDirectory[str] | None]:
    """Build the C harness of ``firmware`` (None: no C); the caller keeps the folder."""
    if firmware is None:
        return None, None
    folder = tempfile.TemporaryDirectory(prefix="fuzz-harness-")
    return CHarness(Path(folder.name), firmware), folder


# --- the stock Altino's replies -----------------------------------------------------------------


def _random_sensors(rng: random.Random) -> af.StockSensors:
    group = rng.choice(sorted(af.REPLY_LENGTHS))
    ir = tuple(rng.randrange(801) for _ in range(6))
    if group == 2:
        return af.StockSensors(group=2, accel=(rng.randrange(-999, 999),) * 3,
                               battery=rng.randrange(1 << 16))  # fmt: skip
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
        len(frame) in (31, 56) and frame[0] == af.STX and frame[1] == len(frame)
        and frame[-1] == af.ETX and frame[2] == total % 256
        and (not group or af.REPLY_LENGTHS.get(frame[4]) == len(frame))
    )  # fmt: skip


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


# --- the device watchdog: C firmware and Python twin ------------------------------------------

#: Per device: its period (µs), default watchdog (ms), largest command (counts) and the signs
#: of the commands held (the Altino's drive away from the wall: its distance guard never acts).
WATCHDOG_DEVICES = {"rotary": (2000, 100, 10_000, (-1, 1)), "altino": (50_000, 150, 1000, (-1,))}


def _watchdog_events(rng: random.Random, device: str) -> tuple[int, list[tuple[str, int]], int]:
    """A watchdog setting and a timeline: commands at odd µs, then silence; ticks every period.

    Command times are odd and tick times even, so no tick falls exactly on a deadline (the
    C firmware counts µs, its Python twin seconds in floating point).
    """
    period, default_ms, *_ = WATCHDOG_DEVICES[device]
    watchdog_ms = rng.choice([0, rng.randint(5, 50), rng.randint(100, 400)])
    start = rng.choice([rng.randrange(1 << 20), (1 << 32) - rng.randrange(1, 400_000)])
    start -= start % period
    limit = (watchdog_ms or default_ms) * 1000
    events, t = [], start + 1
    for _ in range(rng.randint(1, 12)):  # commands closer together than the watchdog time
        t += rng.randrange(1, min(limit, 4 * period) // 2) * 2
        events.append(("cmd", t))
    silent_from = t
    end = silent_from + 2 * limit + 4 * period
    ticks = range(start + period, end, period)
    events += [("tick", k) for k in ticks]
    events.sort(key=lambda e: (e[1], e[0] == "tick"))
    return watchdog_ms, events, silent_from


def fuzz_watchdog(cases: range, seed: int, harness: CHarness | None, say: Progress) -> Part:
    """The firmware watchdog against random command timelines, in C and in the Python twin."""
    part = Part.named("watchdog")
    delays: dict[str, list[float]] = {}
    requests, timelines = [], []
    for case in cases:
        rng = case_rng(seed, "watchdog", case)
        device = rng.choice(sorted(WATCHDOG_DEVICES))
        watchdog_ms, events, silent_from = _watchdog_events(rng, device)
        _, default_ms, largest, signs = WATCHDOG_DEVICES[device]
        command = rng.choice(signs) * rng.randint(100, largest)
        python = _python_motor(device, watchdog_ms, events, command)
        lines = [f"dev_init {device} {watchdog_ms}"]
        seq = 0
        for kind, t in events:
            if kind == "cmd":
                seq += 1
                flags = p.Flag.ENABLE | (p.Flag.REARM if seq == 1 else 0)
                frame = p.encode(p.Command(seq, command, flags))
                lines.append(f"dev_rx {t & 0xFFFFFFFF} {frame.hex()}")
            else:
                lines.append(f"dev_tick {t & 0xFFFFFFFF} 0 0 0")
        requests.append(lines)
        timelines.append((case, watchdog_ms, events, silent_from, python))
        deadline = silent_from + (watchdog_ms or default_ms) * 1000
        _check_watchdog(part, case, deadline, events, python, delays.setdefault(device, []))
        progress(say, part, cases, case, "timelines")
    if harness is not None:
        _compare_watchdog_with_c(part, harness, requests, timelines)
    part.cases = len(cases)
    for device, late in sorted(delays.items()):
        period = WATCHDOG_DEVICES[device][0] / 1000
        part.notes.append(
            f"watchdog: {device}: {len(late)} timelines, motor 0 within {min(late):.1f}-"
            f"{max(late):.1f} ms past the watchdog time (its period: {period:g} ms)"
        )
    return part


def _python_motor(
    device: str, watchdog_ms: int, events: list[tuple[str, int]], command: int
) -> list[int]:
    firmware = Firmware(device, watchdog_ms=watchdog_ms or None)
    motors, seq, origin = [], 0, events[0][1]
    for kind, t in events:
        now = (t - origin) / 1e6  # seconds from the first event: no float wrap
        if kind == "cmd":
            seq += 1
            flags = p.Flag.ENABLE | (p.Flag.REARM if seq == 1 else 0)
            firmware.receive(p.Command(seq, command, flags), now)
        else:
            firmware.tick(now)
            motors.append(firmware.motor_counts)
    return motors


def _check_watchdog(
    part: Part,
    case: int,
    deadline: int,
    events: list[tuple[str, int]],
    motors: list[int],
    delays: list[float],
) -> None:
    ticks = [t for kind, t in events if kind == "tick"]
    first_cmd = next(t for kind, t in events if kind == "cmd")
    for t, motor in zip(ticks, motors, strict=True):
        if first_cmd < t < deadline and motor == 0:
            part.fail(f"watchdog case {case}: motor 0 at {t - first_cmd} µs, before the deadline")
            return
        if t >= deadline and motor != 0:
            part.fail(f"watchdog case {case}: motor {motor} at {t - deadline} µs past the deadline")
            return
    first_zero = next(t for t in ticks if t >= deadline)
    delays.append((first_zero - deadline) / 1000)


def _compare_watchdog_with_c(
    part: Part, harness: CHarness, requests: list[list[str]], timelines: list[tuple]
) -> None:
    flat = [line for lines in requests for line in lines]
    answers, stderr = harness.run(flat)
    if answers is None:
        part.fail(f"watchdog: the C harness died: {stderr.strip()[:300]}")
        return
    at = 0
    for lines, (case, *_, python) in zip(requests, timelines, strict=True):
        mine = answers[at : at + len(lines)]
        at += len(lines)
        c_motors = [int(a[1].split()[1]) for line, a in zip(lines, mine, strict=True)
                    if line.startswith("dev_tick")]  # fmt: skip
        if c_motors != python:
            pairs = enumerate(zip(c_motors, python, strict=False))
            first = next((i for i, (a, b) in pairs if a != b), min(map(len, (c_motors, python))))
            if first == min(len(c_motors), len(python)):
                part.fail(f"watchdog case {case}: C ran {len(c_motors)} ticks, Python "
                          f"{len(python)}")  # fmt: skip
                continue
            part.fail(f"watchdog case {case}: C motor {c_motors[first]}, Python "
                      f"{python[first]} at tick {first}")  # fmt: skip
