"""The C protocol and device state machine of firmware/common/, on the host, against Python.

firmware/test/host_harness.c is compiled once per session with gcc (warnings are errors, and
AddressSanitizer/UBSan when the compiler has them) and driven line by line over a pipe; every
check compares the C answer with tests/data/protocol_vectors.json (written by protocol.py) or
with protocol.py itself. Skipped with a reason when gcc is missing; the AVR build is skipped
when avr-gcc is missing.
"""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from frictiongym.hardware import guard, protocol
from frictiongym.hardware.firmware import FIRMWARE_BUILD
from frictiongym.plants.sensors import IR_NUMERATOR, IR_OFFSET

ROOT = Path(__file__).resolve().parents[1]
FIRMWARE = ROOT / "firmware"
COMMON = sorted((FIRMWARE / "common").glob("*.c"))
VECTORS = json.loads((ROOT / "tests" / "data" / "protocol_vectors.json").read_text())
CFLAGS = ["-Wall", "-Wextra", "-Werror", "-std=c99", "-pedantic"]
#: C error codes of fg_protocol.h by the reason names of the vector file.
REASONS = {"cobs": -1, "short": -2, "crc": -3, "type": -4, "length": -5, "kind": -6, "long": -7}
TIMEOUT = 10.0  # s for one harness answer; a hang fails the test instead of blocking it


class Harness:
    """The compiled host harness as a line-oriented server (see host_harness.c)."""

    def __init__(self, exe: Path) -> None:
        self.proc = subprocess.Popen(
            [str(exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )
        self._buffer = b""

    def ask(self, request: str) -> list[str]:
        """Send one request line; return the answer's lines (without the final ".")."""
        assert self.proc.stdin is not None
        assert self.proc.stdout is not None
        self.proc.stdin.write(request.encode() + b"\n")
        self.proc.stdin.flush()
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + TIMEOUT
        while b"\n.\n" not in b"\n" + self._buffer:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not select.select([fd], [], [], remaining)[0]:
                raise TimeoutError(f"the C harness did not answer {request[:60]!r}")
            chunk = os.read(fd, 65536)
            if not chunk:
                err = self.proc.stderr.read().decode() if self.proc.stderr else ""
                raise RuntimeError(f"the C harness died on {request[:60]!r}: {err}")
            self._buffer += chunk
        text = (b"\n" + self._buffer).split(b"\n.\n", 1)
        self._buffer = text[1]
        return text[0].decode().split("\n")[1:]

    def close(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.write(b"quit\n")
            self.proc.stdin.close()
            self.proc.wait(timeout=TIMEOUT)


def _sanitizers(gcc: str, workdir: Path) -> list[str]:
    """ASan/UBSan flags if this gcc can link them (skipped silently otherwise)."""
    probe = workdir / "probe.c"
    probe.write_text("int main(void) { return 0; }\n")
    flags = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
    done = subprocess.run(
        [gcc, *flags, str(probe), "-o", str(workdir / "probe")], capture_output=True, check=False
    )
    return flags if done.returncode == 0 else []


@pytest.fixture(scope="session")
def harness(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Harness]:
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc is not installed: the C protocol cannot be built (apt-get install gcc)")
    workdir = tmp_path_factory.mktemp("firmware")
    exe = workdir / "host_harness"
    sources = [*COMMON, FIRMWARE / "test" / "host_harness.c"]
    flags = [*CFLAGS, "-g", "-O1", *_sanitizers(gcc, workdir)]
    done = subprocess.run(
        [gcc, *flags, *map(str, sources), "-o", str(exe)], capture_output=True, text=True
    )
    assert done.returncode == 0, f"gcc failed:\n{done.stderr}"
    server = Harness(exe)
    yield server
    server.close()


def _hex(data: bytes) -> str:
    return data.hex() or "-"


def _parse_messages(lines: list[str]) -> list[tuple[int, list[int]]]:
    out = []
    for line in lines:
        if line.startswith("msg "):
            numbers = [int(x) for x in line.split()[1:]]
            out.append((numbers[0], numbers[1:]))
    return out


def _python_values(message: protocol.Message) -> tuple[int, list[int]]:
    if isinstance(message, protocol.Place):
        bits = int.from_bytes(protocol.pack(message)[1:5], "little")
        return int(message.TYPE), [bits]
    return int(message.TYPE), [int(v) for v in message.fields()]


# --- vectors -----------------------------------------------------------------------------------


@pytest.mark.parametrize("vector", VECTORS["crc"], ids=lambda v: v["name"])
def test_crc_matches_python(harness: Harness, vector: dict[str, Any]) -> None:
    assert harness.ask(f"crc {vector['data'] or '-'}") == [f"crc {vector['crc']:04x}"]


@pytest.mark.parametrize("vector", VECTORS["cobs"], ids=lambda v: v["name"])
def test_cobs_matches_python(harness: Harness, vector: dict[str, Any]) -> None:
    assert harness.ask(f"cobs_encode {vector['data'] or '-'}") == [vector["encoded"]]
    assert harness.ask(f"cobs_decode {vector['encoded']}") == [vector["data"] or "-"]


@pytest.mark.parametrize("vector", VECTORS["messages"], ids=lambda v: v["name"])
def test_c_encodes_every_message_as_python(harness: Harness, vector: dict[str, Any]) -> None:
    values = " ".join(str(v) for v in vector["values"])
    payload, crc, wire = harness.ask(f"encode {vector['type']} {values}")[0].split()
    assert (payload, int(crc, 16), wire) == (vector["payload"], vector["crc"], vector["wire"])


@pytest.mark.parametrize("vector", VECTORS["messages"], ids=lambda v: v["name"])
def test_c_decodes_every_message_as_python(harness: Harness, vector: dict[str, Any]) -> None:
    frame = bytes.fromhex(vector["wire"])[:-1]
    assert _parse_messages(harness.ask(f"decode {frame.hex()}")) == [
        (vector["type"], vector["values"])
    ]


@pytest.mark.parametrize("vector", VECTORS["corrupt"], ids=lambda v: v["name"])
def test_c_rejects_corrupted_frames(harness: Harness, vector: dict[str, Any]) -> None:
    assert harness.ask(f"decode {vector['frame'] or '-'}") == [f"err {REASONS[vector['reason']]}"]


@pytest.mark.parametrize("vector", VECTORS["streams"], ids=lambda v: v["name"])
def test_c_stream_decoder_matches_python(harness: Harness, vector: dict[str, Any]) -> None:
    lines = harness.ask(f"stream {vector['bytes']}")
    assert _parse_messages(lines) == [(m["type"], m["values"]) for m in vector["messages"]]
    assert lines[-1] == f"count {vector['frames']} {vector['errors']}"


# --- fuzzing: the C decoder agrees with protocol.FrameDecoder ----------------------------------

_valid_message = st.one_of(
    st.builds(
        protocol.Command,
        st.integers(0, 65535),
        st.integers(-(2**15), 2**15 - 1),
        st.builds(protocol.Flag, st.integers(0, 255)),
        st.integers(-(2**15), 2**15 - 1),
    ),
    st.builds(protocol.HelloRequest, st.integers(0, 255)),
    st.builds(protocol.Place, st.floats(width=32, allow_nan=False)),
    st.builds(
        protocol.State,
        st.builds(protocol.Status, st.integers(0, 255)),
        st.integers(0, 65535),
        st.integers(0, 2**32 - 1),
        st.integers(0, 65535),
        st.integers(-(2**15), 2**15 - 1),
        st.integers(-(2**31), 2**31 - 1),
    ),
)


def _assert_agree(harness: Harness, stream: bytes) -> None:
    decoder = protocol.FrameDecoder()
    expected = [_python_values(m) for m in decoder.feed(stream)]
    lines = harness.ask(f"stream {_hex(stream)}")
    assert _parse_messages(lines) == expected
    assert lines[-1] == f"count {decoder.frames} {decoder.errors}"


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(st.binary(max_size=2000))
def test_fuzz_c_decoder_on_random_bytes(harness: Harness, stream: bytes) -> None:
    _assert_agree(harness, stream)


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(st.lists(_valid_message, max_size=12), st.data())
def test_fuzz_c_decoder_on_damaged_streams(
    harness: Harness, messages: list[protocol.Message], data: st.DataObject
) -> None:
    stream = bytearray(b"".join(protocol.encode(m) for m in messages))
    for _ in range(data.draw(st.integers(0, 6))):
        if not stream:
            break
        at = data.draw(st.integers(0, len(stream) - 1))
        action = data.draw(st.sampled_from(["flip", "drop", "insert"]))
        if action == "flip":
            stream[at] ^= 1 << data.draw(st.integers(0, 7))
        elif action == "drop":
            del stream[at]
        else:
            stream.insert(at, data.draw(st.integers(0, 255)))
    _assert_agree(harness, bytes(stream))


# --- device state machine: the scenario table --------------------------------------------------


def _send_bytes(event: dict[str, Any]) -> bytes:
    if "send_hex" in event:
        return bytes.fromhex(event["send_hex"])
    spec = dict(event["send"])
    kind = spec.pop("type")
    if kind == "command":
        flags = protocol.Flag(0)
        for name in spec.pop("flags"):
            flags |= protocol.Flag[name]
        return protocol.encode(protocol.Command(flags=flags, **spec))
    if kind == "hello_request":
        return protocol.encode(protocol.HelloRequest(**spec))
    return protocol.encode(protocol.Place(**spec))


def _status(names: list[str]) -> int:
    value = 0
    for name in names:
        value |= protocol.Status[name]
    return value


@pytest.mark.parametrize("scenario", VECTORS["device_scenarios"], ids=lambda s: s["name"])
def test_device_scenario(harness: Harness, scenario: dict[str, Any]) -> None:
    assert harness.ask(f"dev_init {scenario['device']} 0") == ["ok"]
    for i, event in enumerate(scenario["events"]):
        where = f"event {i} at {event['at_us']} µs"
        if "tick" in event:
            sample = event["tick"]
            hw = _status(sample["hw_status"])
            lines = harness.ask(
                f"dev_tick {event['at_us']} {sample['sensor']} {sample['aux']} {hw}"
            )
            state = protocol.decode(bytes.fromhex(lines[0].split()[1])[:-1])
            assert isinstance(state, protocol.State), where
            for key, want in event.get("state", {}).items():
                got = getattr(state, key)
                if key == "status":
                    assert got == _status(want), f"{where}: status {protocol.Status(got)!r}"
                else:
                    assert got == want, f"{where}: {key}"
            motor_line = lines[1]
        else:
            lines = harness.ask(f"dev_rx {event['at_us']} {_send_bytes(event).hex()}")
            act, motor_line = int(lines[0].split()[1]), " ".join(lines[0].split()[2:])
            if "zero" in event:
                assert bool(act & 0x02) == event["zero"], f"{where}: zero action"
            if "reply" in event:
                hello = protocol.decode(bytes.fromhex(lines[1].split()[1])[:-1])
                assert isinstance(hello, protocol.Hello), where
                for key, want in event["reply"].items():
                    assert int(getattr(hello, key)) == want, f"{where}: Hello.{key}"
            else:
                assert len(lines) == 1, f"{where}: unexpected reply {lines[1:]}"
        if "motor" in event:
            motor = int(motor_line.split()[1])
            assert motor == event["motor"], f"{where}: motor"
            assert int(motor_line.split()[3]) in (0, 1)


@pytest.mark.parametrize("scenario", VECTORS["device_scenarios"], ids=lambda s: s["name"])
def test_python_firmware_follows_the_scenarios(
    scenario: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The emulator's state machine (frictiongym.hardware.firmware) obeys the same table.

    The emulator applies commands at the tick (zero-latency idealisation), so the motor output
    between ticks is not compared (after a tick it is: the guard's output for the next period),
    and its sensor is physics: the scripted sample replaces it.
    """
    firmware = pytest.importorskip("frictiongym.hardware.firmware")
    if "firmware_only" in scenario:
        pytest.skip(f"firmware only: {scenario['firmware_only']}")
    device = firmware.Firmware(scenario["device"])
    for i, event in enumerate(scenario["events"]):
        now, where = event["at_us"] * 1e-6, f"event {i} at {event['at_us']} µs"
        if "tick" in event:
            reading = event["tick"]["sensor"]
            monkeypatch.setattr(device, "_sensor", lambda reading=reading: reading)
            state = device.tick(now)
            for key, want in event.get("state", {}).items():
                if key == "tick_us":  # the emulator counts ticks from its own boot
                    continue
                got = getattr(state, key)
                want = _status(want) if key == "status" else want
                assert got == want, f"{where}: {key} {got!r}"
            if "motor" in event:
                assert device.motor_counts == event["motor"], f"{where}: motor"
            continue
        replies = [device.receive(m, now) for m in device.feed(_send_bytes(event))]
        if "reply" in event:
            (hello,) = replies
            for key, want in event["reply"].items():
                got = int(getattr(hello, key))
                if key == "capabilities":
                    got &= ~protocol.Capability.PLACE  # the emulator also honours Place
                assert got == want, f"{where}: Hello.{key}"


def test_c_guard_constants_equal_guard_py() -> None:
    """fg_device.h restates guard.py's constants: they must not drift apart."""
    text = (FIRMWARE / "common" / "fg_device.h").read_text()
    defines = {
        name: float(value) for name, value in re.findall(r"#define (FG_\w+) ([\d.]+)f?\b", text)
    }
    assert defines["FG_IR_NUMERATOR"] == IR_NUMERATOR
    assert defines["FG_IR_OFFSET"] == IR_OFFSET
    assert defines["FG_GUARD_LIMIT_CM"] == guard.LIMIT_CM
    assert defines["FG_GUARD_REACTION_PERIODS"] == guard.REACTION_PERIODS
    assert defines["FG_GUARD_STOPPED_SPEED"] == guard.STOPPED_SPEED
    assert defines["FG_GUARD_MASS_MIN"] == guard.MASS_MIN
    assert defines["FG_GUARD_MASS_MAX"] == guard.MASS_MAX
    assert defines["FG_GUARD_FRICTION"] == guard.FRICTION
    assert defines["FG_GUARD_VISCOUS"] == guard.VISCOUS


def test_device_amplifier_follows_arming(harness: Harness) -> None:
    assert harness.ask("dev_init rotary 0") == ["ok"]
    assert harness.ask("dev_tick 2000 0 0 0")[1] == "motor 0 amp 0"
    rearm = protocol.encode(
        protocol.Command(1, 0, protocol.Flag.REARM | protocol.Flag.ENABLE)
    ).hex()
    assert harness.ask(f"dev_rx 2500 {rearm}") == ["act 1 motor 0 amp 1"]
    assert harness.ask("dev_estop") == ["motor 0 amp 0"]


def test_device_watchdog_option(harness: Harness) -> None:
    hello = protocol.encode(protocol.HelloRequest()).hex()
    assert harness.ask("dev_init rotary 50") == ["ok"]
    reply = harness.ask(f"dev_rx 0 {hello}")[1].split()[1]
    message = protocol.decode(bytes.fromhex(reply)[:-1])
    assert isinstance(message, protocol.Hello)
    assert message.watchdog_ms == 50


# --- the reference sketches, on the host against a stub Arduino API ----------------------------


@pytest.fixture(scope="session")
def sketches(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Harness]]:
    gcc, gxx = shutil.which("gcc"), shutil.which("g++")
    if gcc is None or gxx is None:
        pytest.skip("gcc/g++ are not installed: the sketches cannot be built on the host")
    workdir = tmp_path_factory.mktemp("sketches")
    objects = []
    for source in COMMON:
        obj = workdir / f"{source.stem}.o"
        done = subprocess.run(
            [gcc, *CFLAGS, "-c", str(source), "-o", str(obj)],
            capture_output=True,
            text=True,
            check=False,
        )
        assert done.returncode == 0, done.stderr
        objects.append(str(obj))
    servers = {}
    for name in ("qube_bridge", "altino"):
        exe = workdir / name
        done = subprocess.run(
            [
                gxx,
                "-std=c++11",
                "-Wall",
                "-Wextra",
                "-Werror",
                f'-DSKETCH="../{name}/{name}.ino"',
                "-I",
                str(FIRMWARE / "test" / "arduino_stub"),
                "-I",
                str(FIRMWARE / "common"),
                str(FIRMWARE / "test" / "sketch_sim.cpp"),
                *objects,
                "-o",
                str(exe),
            ],
            capture_output=True,
            text=True,
            check=False,
        )
        assert done.returncode == 0, f"{name}.ino does not build on the host:\n{done.stderr}"
        servers[name] = Harness(exe)
    yield servers
    for server in servers.values():
        server.close()


def _sim(sim: Harness, request: str) -> tuple[list[bytes], dict[int, bytes]]:
    """SPI transactions (MOSI bytes) and serial output per port of one sketch request."""
    spi, tx = [], {0: b"", 1: b""}
    for line in sim.ask(request):
        word, rest = line.split(" ", 1)
        if word == "spi":
            mosi, clock, mode, ss = rest.split()
            assert (int(clock), int(mode), int(ss)) == (1_000_000, 8, 0), "1 MHz, mode 2, SS low"
            spi.append(bytes.fromhex(mosi))
        else:
            tx[int(word[2])] += bytes.fromhex(rest)
    return spi, tx


def _rx(link: int, message: protocol.Command) -> str:
    """The harness line that feeds ``message`` to the device on ``link``."""
    return f"rx {link} {protocol.encode(message).hex()}"


def _states(data: bytes) -> list[protocol.State]:
    messages = protocol.FrameDecoder().feed(data)
    states = [m for m in messages if isinstance(m, protocol.State)]
    assert len(states) == len(messages), f"not only States: {messages}"
    return states


def _miso(module: int = 777, encoder: int = 0, status: int = 0, current_raw: int = 8190) -> str:
    reply = bytearray(17)
    reply[0:2] = module.to_bytes(2, "big")
    reply[2:5] = (encoder & 0xFFFFFF).to_bytes(3, "big")
    reply[11] = status
    reply[12:14] = current_raw.to_bytes(2, "big")
    return reply.hex()


def _motor_word(mosi: bytes) -> int:
    return int.from_bytes(mosi[15:17], "big")


def test_qube_bridge_sketch(sketches: dict[str, Harness]) -> None:
    qube = sketches["qube_bridge"]
    spi, tx = _sim(qube, "setup")
    assert len(spi) == 1
    assert spi[0][2] & 0x60 == 0x60, "boot zeroes both encoders"
    assert _motor_word(spi[0]) == 0, "boot: motor 0, amplifier disabled"
    qube.ask(f"miso {_miso(encoder=-5, current_raw=8190 + 3276)}")  # -5 counts, 330 mA
    qube.ask(_rx(0, protocol.HelloRequest()))
    _, tx = _sim(qube, "run 50")
    (hello,) = protocol.FrameDecoder().feed(tx[0])
    assert hello == protocol.Hello(
        1,
        protocol.DeviceKind.ROTARY,
        protocol.Capability.WATCHDOG,
        500,
        2048,
        1000,
        10000,
        100,
        FIRMWARE_BUILD,
    )
    _, tx = _sim(qube, "run 2000")
    (state,) = _states(tx[0])
    assert state == protocol.State(protocol.Status.DISABLED, 1, state.tick_us, 0, 0, -5, 330)

    qube.ask(_rx(0, protocol.Command(1, 5000, protocol.Flag.REARM | protocol.Flag.ENABLE)))
    spi, _ = _sim(qube, "run 50")
    assert _motor_word(spi[-1]) == 0x8000 | 208, "5 V = 208 PWM counts (625/15), amplifier on"
    qube.ask(_rx(0, protocol.Command(2, -5000)))
    spi, _ = _sim(qube, "run 50")
    assert _motor_word(spi[-1]) == 0x8000 | (-208 & 0x7FFF)
    _, tx = _sim(qube, "run 2000")
    (state,) = _states(tx[0])
    assert (state.status, state.seq_applied, state.applied) == (0, 2, -5000)

    qube.ask(_rx(0, protocol.Command(3, 0, protocol.Flag.ENABLE | protocol.Flag.ZERO_POSITION)))
    spi, _ = _sim(qube, "run 50")
    assert spi[-1][2] & 0x60 == 0x20, "ZERO_POSITION zeroes encoder 0 only"

    spi, tx = _sim(qube, "run 110000")  # no commands: the watchdog trips after 100 ms
    states = _states(tx[0])
    assert len(states) == 55
    assert states[-1].status == protocol.Status.WATCHDOG | protocol.Status.DISABLED
    assert _motor_word(spi[-1]) == 0, "watchdog: motor 0, amplifier disabled"

    qube.ask(f"miso {_miso(module=0)}")  # no QUBE answering
    qube.ask(_rx(0, protocol.Command(4, 1000, protocol.Flag.REARM | protocol.Flag.ENABLE)))
    spi, tx = _sim(qube, "run 4000")
    assert _states(tx[0])[-1].status & protocol.Status.AMP_FAULT
    assert _motor_word(spi[-1]) == 0


def _car_reply(ir_front: int) -> str:
    reply = bytearray(31)
    reply[0], reply[1], reply[3], reply[4], reply[30] = 0x02, 31, 1, 1, 0x03
    reply[9:11] = ir_front.to_bytes(2, "big")  # IR[1], the front-centre sensor
    reply[2] = (sum(reply) - reply[2]) % 256
    return reply.hex()


def _car_frames(data: bytes) -> list[bytes]:
    frames = [data[i : i + 28] for i in range(0, len(data), 28)]
    for frame in frames:
        assert (frame[0], frame[1], frame[27]) == (0x02, 28, 0x03)
        assert frame[2] == (frame[1] + sum(frame[3:])) % 256, "vendor checksum"
    return frames


def _wheels(frame: bytes) -> tuple[tuple[int, int], tuple[int, int]]:
    """(mode, sign-magnitude value) of the right and the left wheel."""
    return (
        (frame[6], int.from_bytes(frame[7:9], "big")),
        (frame[9], int.from_bytes(frame[10:12], "big")),
    )


def test_altino_sketch(sketches: dict[str, Harness]) -> None:
    car = sketches["altino"]
    _, tx = _sim(car, "setup")
    (boot,) = _car_frames(tx[0])
    assert _wheels(boot) == ((255, 0), (255, 0)), "boot: both wheels stopped"
    car.ask(f"rx 0 {_car_reply(150)}")  # 4.95 cm
    car.ask(_rx(1, protocol.Command(1, 400, protocol.Flag.REARM | protocol.Flag.ENABLE)))
    _, tx = _sim(car, "run 10000")
    assert _wheels(_car_frames(tx[0])[-1]) == ((255, 0), (255, 0)), "no sample yet: refused"
    _, tx = _sim(car, "run 40000")  # the first tick samples the distance
    (state,) = _states(tx[1])
    assert (state.status, state.sensor, state.applied, state.seq) == (0, 150, 0, 1)
    car.ask(f"rx 0 {_car_reply(150)}")  # +400 held from rest would stop at 3.6 cm: passes
    car.ask(_rx(1, protocol.Command(1, 400, protocol.Flag.REARM | protocol.Flag.ENABLE)))
    _, tx = _sim(car, "run 10000")  # the vendor's 10 ms frame gap
    (drive,) = _car_frames(tx[0])
    assert _wheels(drive) == ((0, 400), (0, 400))
    _, tx = _sim(car, "run 35000")  # the sensor poll 10 ms before the tick
    assert len(_car_frames(tx[0])) == 1
    car.ask(f"rx 0 {_car_reply(150)}")
    _, tx = _sim(car, "run 5000")
    (state,) = _states(tx[1])
    assert (state.status, state.sensor, state.applied, state.seq) == (0, 150, 400, 2)

    # 4.95 cm -> 1.95 cm in a period: 60 cm/s, far too fast to stop 1.5 cm short of the wall
    car.ask(f"rx 0 {_car_reply(450)}")
    car.ask(_rx(1, protocol.Command(2, 400)))
    _, tx = _sim(car, "run 50000")
    (state,) = _states(tx[1])
    assert (state.status, state.sensor, state.applied) == (protocol.Status.LIMIT, 450, 400)
    _, tx = _sim(car, "run 10000")
    brake = (0, 32768 + 1000)
    assert _wheels(_car_frames(tx[0])[-1]) == (brake, brake), "the guard brakes: full reverse"
    car.ask(f"rx 0 {_car_reply(450)}")  # the car stopped there
    car.ask(_rx(1, protocol.Command(3, 400)))
    _, tx = _sim(car, "run 10000")
    assert _wheels(_car_frames(tx[0])[-1]) == (brake, brake), "forward: refused, still braking"
    _, tx = _sim(car, "run 30000")
    (state,) = _states(tx[1])
    assert (state.status, state.sensor, state.applied) == (protocol.Status.LIMIT, 450, -1000)
    _, tx = _sim(car, "run 10000")
    assert _wheels(_car_frames(tx[0])[-1]) == ((255, 0), (255, 0)), "stopped: no more brake"
    car.ask(_rx(1, protocol.Command(4, -300)))
    _, tx = _sim(car, "run 10000")
    assert _wheels(_car_frames(tx[0])[-1]) == ((0, 32768 + 300), (0, 32768 + 300))

    _, tx = _sim(car, "run 200000")  # commands and car replies stop
    states = _states(tx[1])
    assert states[-1].status & protocol.Status.AMP_FAULT
    assert states[-1].status & protocol.Status.DISABLED
    assert _wheels(_car_frames(tx[0])[-1]) == ((255, 0), (255, 0))


# --- AVR ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("mcu", ["atmega328p", "atmega2560"])
def test_common_code_builds_for_avr(mcu: str, tmp_path: Path) -> None:
    avr_gcc, avr_size = shutil.which("avr-gcc"), shutil.which("avr-size")
    if avr_gcc is None or avr_size is None:
        pytest.skip("avr-gcc is not installed (Debian: apt-get install gcc-avr avr-libc)")
    objects = []
    for source in COMMON:
        obj = tmp_path / f"{source.stem}.o"
        done = subprocess.run(
            [avr_gcc, f"-mmcu={mcu}", "-Os", *CFLAGS, "-c", str(source), "-o", str(obj)],
            capture_output=True,
            text=True,
            check=False,
        )
        assert done.returncode == 0, done.stderr
        objects.append(str(obj))
    sizes = subprocess.run(
        [avr_size, *objects], capture_output=True, text=True, check=True
    ).stdout.splitlines()[1:]
    text = sum(int(line.split()[0]) for line in sizes)
    data = sum(int(line.split()[1]) + int(line.split()[2]) for line in sizes)
    elf = tmp_path / "avr_size.elf"
    done = subprocess.run(
        [
            avr_gcc,
            f"-mmcu={mcu}",
            "-Os",
            *CFLAGS,
            "-ffunction-sections",
            "-fdata-sections",
            "-Wl,--gc-sections",
            str(FIRMWARE / "test" / "avr_size.c"),
            *map(str, COMMON),
            "-o",
            str(elf),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    linked = subprocess.run([avr_size, str(elf)], capture_output=True, text=True, check=True)
    flash = int(linked.stdout.splitlines()[1].split()[0])
    print(f"{mcu}: firmware/common text {text} B, data+bss {data} B; linked {flash} B flash")
    # Budgets: the protocol and state machine took 3.9 KiB (5.4 KiB linked) before the guard
    # bounded the speed and the car; build 3 takes 6.0 KiB (7.5 KiB linked) of an ATmega328P's
    # 32 KiB.
    assert text < 6656, "the shared protocol and device rules should stay under 6.5 KiB"
    assert data == 0, "the shared code keeps no globals: all state is in the caller's structs"
    assert flash < 8704, "the common code and its runtime (the guard's float maths) < 8.5 KiB"
