"""AltinoStockBackend: the vendor's frames, and the backend against a fake stock car on a pty."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import gymnasium as gym
import numpy as np
import pytest
from _altino_stock_device import FakeStockAltino, StepSim

from frictiongym.devices import ALTINO
from frictiongym.hardware import resolve_backend
from frictiongym.hardware.altino_frames import (
    STOCK_MAX_RATE_HZ,
    STOP_REPEATS,
    BadReply,
    StockSensors,
    command_checksum,
    go_frame,
    parse_go_frame,
    parse_sensor_reply,
    reply_checksum,
    sensor_reply,
    sensor_request_frame,
    take_reply,
)
from frictiongym.hardware.altino_stock import AltinoStockBackend
from frictiongym.hardware.errors import (
    DeviceDisconnectedError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    HardwareError,
    ProtocolError,
)
from frictiongym.hardware.guard import STOPPED_SPEED, CarBounds, readout_jump_possible
from frictiongym.hardware.protocol import Status
from frictiongym.plants._kernel import S_V

ALTINO_ID = "frictiongym/AltinoDistance-v1"
RATE = 50.0  # Hz: fast enough for short tests, within the stock link's 66 Hz
TARGET_CM = 10.0
KP = 60.0  # motor units per cm


def p_command(readout: float) -> float:
    """P controller toward TARGET_CM on the IR distance estimate (positive drives to the wall)."""
    distance = 966.0 / (readout + 45.0)
    return max(-1000.0, min(1000.0, KP * (distance - TARGET_CM)))


def settle(fake: FakeStockAltino, count: int, timeout: float = 2.0) -> None:
    """Wait until the fake has received ``count`` frames."""
    deadline = time.monotonic() + timeout
    while len(fake.commands) < count and time.monotonic() < deadline:
        time.sleep(0.005)


@pytest.fixture
def fake() -> Iterator[FakeStockAltino]:
    with FakeStockAltino(start_cm=20.0, rate_hz=RATE) as device:
        yield device


@pytest.fixture
def backend(fake: FakeStockAltino) -> Iterator[AltinoStockBackend]:
    device = AltinoStockBackend(fake.port, rate_hz=RATE, timeout=0.3)
    with device:
        yield device


# -- codec ------------------------------------------------------------------------------------


def test_go_frame_checksum_vectors_by_hand() -> None:
    # Go(0, 0) after Open(): STX, 28, cs, 1, request 1, mode 255 twice, byte 21 bit 0, ETX.
    # Checksum: 28 + (1 + 1 + 255 + 255 + 1 + 3) = 544 = 0x220 -> 0x20.
    stop = go_frame(0, 0)
    assert stop == bytes([2, 28, 0x20, 1, 1, 0, 255, 0, 0, 255] + [0] * 11 + [1] + [0] * 5 + [3])
    # Go(left=300, right=-300): right 32768 + 300 = 0x812C, left 0x012C, modes 0.
    # Checksum: 28 + (1 + 1 + 0x81 + 0x2C + 0x01 + 0x2C + 1 + 3) = 252 = 0xFC.
    frame = go_frame(300, -300)
    assert frame[2] == 0xFC
    assert frame[6:12] == bytes([0, 0x81, 0x2C, 0, 0x01, 0x2C])
    assert command_checksum(frame) == frame[2]


def test_sensor_reply_checksum_vector_by_hand() -> None:
    # IR[1] = 438 = 0x01B6 at bytes 9-10; checksum 2 + 31 + 1 (group) + 1 + 0xB6 + 3 = 0xDC.
    reply = sensor_reply(StockSensors(group=1, ir=(0, 438, 0, 0, 0, 0)))
    assert len(reply) == 31
    assert reply[:5] == bytes([2, 31, 0xDC, 0, 1])
    assert reply[9:11] == bytes([0x01, 0xB6])
    assert reply[-1] == 3
    assert reply_checksum(reply) == 0xDC
    assert parse_sensor_reply(reply).ir[1] == 438


@pytest.mark.parametrize(("left", "right"), [(0, 0), (1, -1), (1000, -1000), (-437, 250)])
def test_go_frame_round_trip(left: int, right: int) -> None:
    command = parse_go_frame(go_frame(left, right))
    assert (command.left, command.right, command.request) == (left, right, 1)
    assert command.stop == (left == 0 and right == 0)


def test_sensor_request_is_a_go_frame() -> None:
    assert sensor_request_frame(1, left=120, right=120) == go_frame(120, 120)
    assert parse_go_frame(sensor_request_frame(10)).request == 10
    assert sensor_request_frame(10)[21] & 1
    assert not sensor_request_frame(2)[21] & 1


@pytest.mark.parametrize(
    "sensors",
    [
        StockSensors(group=1, ir=(1, 2, 800, 4, 5, 6), torque=(7, 8), temperature=30, cds=900),
        StockSensors(
            group=2,
            accel=(-1, 2, -32768),
            mag=(5, -6, 7),
            steering=512,
            steering_torque=3,
            battery=780,
            remote=9,
            motor_temperature=41,
        ),
        StockSensors(
            group=10,
            ir=(9, 8, 7, 6, 5, 4),
            torque=(1, 2),
            steering_torque=3,
            accel=(-4, 5, 6),
            mag=(7, 8, -9),
            gyro=(-10, 11, 12),
            cds=13,
            steering=14,
            battery=15,
            temperature=16,
            remote=17,
            motor_temperature=18,
        ),
    ],
)
def test_sensor_reply_round_trip(sensors: StockSensors) -> None:
    assert parse_sensor_reply(sensor_reply(sensors)) == sensors


def test_corrupt_frames_are_refused() -> None:
    reply = bytearray(sensor_reply(StockSensors(group=1, ir=(0, 100, 0, 0, 0, 0))))
    reply[10] ^= 0x01
    with pytest.raises(ProtocolError, match="checksum"):
        parse_sensor_reply(bytes(reply))
    frame = bytearray(go_frame(10, 10))
    frame[8] ^= 0x04
    with pytest.raises(ProtocolError, match="checksum"):
        parse_go_frame(bytes(frame))


@pytest.mark.parametrize("value", [1001, -1001, 1.5, True, math.nan])
def test_go_frame_refuses_values_out_of_range(value: object) -> None:
    with pytest.raises(ValueError, match=r"-1000\.\.1000"):
        go_frame(value, 0)  # type: ignore[arg-type]


def test_reply_search_skips_garbage_and_flags_bad_frames() -> None:
    reply = sensor_reply(StockSensors(group=1, ir=(0, 55, 0, 0, 0, 0)))
    buffer = bytearray(b"\x00\x02\x07junk" + reply[:10])
    assert take_reply(buffer, 31) is None
    buffer += reply[10:] + b"\x02"
    assert take_reply(buffer, 31) == reply
    assert buffer == b"\x02"
    bad = bytearray(reply)
    bad[2] ^= 0x10
    with pytest.raises(BadReply):
        take_reply(bytearray(bad), 31)


# -- configuration ----------------------------------------------------------------------------


def test_from_uri_parses_and_rejects_unknown_options() -> None:
    backend = AltinoStockBackend.from_uri(
        "/dev/rfcomm0", {"baud": "57600", "rate": "10", "limit_cm": "3"}
    )
    assert (backend.port, backend.baud, backend.rate_hz) == ("/dev/rfcomm0", 57600, 10.0)
    assert backend.limit_cm == 3.0
    assert not backend.is_open  # configuration only: nothing opened
    with pytest.raises(ValueError, match=r"unknown option\(s\) speed.*accepted: baud, rate"):
        AltinoStockBackend.from_uri("/dev/rfcomm0", {"speed": "9600"})
    with pytest.raises(ValueError, match=r"rate=.*positive"):
        AltinoStockBackend.from_uri("/dev/rfcomm0", {"rate": "-3"})
    with pytest.raises(ValueError, match="names no port"):
        AltinoStockBackend.from_uri("", {})


def test_unrealistic_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="10-20 Hz is realistic"):
        AltinoStockBackend("loop://", rate_hz=STOCK_MAX_RATE_HZ + 1.0)
    with pytest.raises(ValueError, match="IR sensor's range"):
        AltinoStockBackend("loop://", limit_cm=0.5)
    with pytest.raises(ValueError, match="sensor_group"):
        AltinoStockBackend("loop://", sensor_group=2)


def test_open_errors_say_what_to_check() -> None:
    with pytest.raises(DeviceNotFoundError, match="check the path"):
        AltinoStockBackend("/dev/does-not-exist-altino").open()
    # loop:// echoes our own 28-byte frame: no reply, so the probe times out and closes.
    backend = AltinoStockBackend("loop://", timeout=0.05)
    with pytest.raises(DeviceTimeoutError, match="stock firmware"):
        backend.open()
    assert not backend.is_open


# -- against the fake car ---------------------------------------------------------------------


def test_closed_loop_is_the_simulator_with_one_period_more_dead_time(
    fake: FakeStockAltino, backend: AltinoStockBackend
) -> None:
    info = backend.open()
    assert info.watchdog_s is None
    assert info.kind == "altino"
    assert info.distance_limit
    sim = StepSim(ALTINO, 20.0, 1.0 / RATE, delay=fake.car.sim.plant.dead_time + 1.0 / RATE)
    sample = backend.start()
    applied = [0.0]
    for _ in range(40):
        assert sample.measured == sim.readout
        command = p_command(sample.measured)
        sim.step(round(command))
        sample = backend.step(command)
        assert sample.applied == applied[-1]  # the command of the previous step
        applied.append(float(round(command)))
    assert sample.measured == sim.readout
    assert sample.status == 0  # the guard never acted
    assert abs(fake.car.position - TARGET_CM) < 2.5  # it got there, P control leaves an offset


def test_pacing_and_missed_ticks(backend: AltinoStockBackend) -> None:
    backend.start()
    start = time.perf_counter()
    for _ in range(10):
        backend.step(0.0)
    elapsed = time.perf_counter() - start
    assert 0.7 * 10 / RATE < elapsed < 3.0 * 10 / RATE  # loose: a shared VM
    time.sleep(2.5 / RATE)  # the controller stalls: the next tick passes, and half of one more
    sample = backend.step(0.0)
    assert sample.late
    assert sample.skipped >= 1
    assert sample.seq - sample.seq_applied == 1 + sample.skipped
    assert backend.missed_ticks >= 1


def test_distance_guard_brakes_before_the_wall(fake: FakeStockAltino) -> None:
    limit = 5.0
    with AltinoStockBackend(fake.port, rate_hz=RATE, timeout=0.3, limit_cm=limit) as backend:
        backend.start()
        statuses = [backend.step(600.0).status for _ in range(50)]
        tripped = statuses.index(Status.LIMIT)  # raises if it never tripped
        assert all(s == Status.LIMIT for s in statuses[tripped:])  # latched until start()
        assert limit < fake.car.position < 15.0  # it braked early (the guard is conservative)
        first_brake = next(i for i, c in enumerate(fake.commands) if c.left < 0)
        assert fake.commands[first_brake].left == -1000  # full reverse, at once
        assert all(c.left <= 0 for c in fake.commands[first_brake:])  # never forward again
        assert backend.step(-300.0).status == Status.LIMIT  # backing away is allowed
        settle(fake, len(fake.commands) + 1, timeout=0.2)
        assert fake.commands[-1].left == -300


def test_nan_is_never_sent_and_stops(fake: FakeStockAltino, backend: AltinoStockBackend) -> None:
    backend.start()
    backend.step(200.0)
    with pytest.raises(ValueError, match="not a finite number"):
        backend.step(math.nan)
    with pytest.raises(HardwareError, match=r"start\(\) it again"):
        backend.step(100.0)
    settle(fake, 3 + STOP_REPEATS)  # probe, start, step, stops
    assert [c.left for c in fake.commands] == [0, 0, 200] + [0] * STOP_REPEATS
    assert all(c.stop for c in fake.commands[3:])


def test_close_sends_repeated_stops(fake: FakeStockAltino) -> None:
    backend = AltinoStockBackend(fake.port, rate_hz=RATE, timeout=0.3)
    backend.start()
    backend.step(500.0)
    backend.close()
    backend.close()  # idempotent
    settle(fake, 3 + STOP_REPEATS)
    assert [(c.left, c.right, c.stop) for c in fake.commands[3:]] == [(0, 0, True)] * STOP_REPEATS


def test_timeout_when_the_car_stops_answering(
    fake: FakeStockAltino, backend: AltinoStockBackend
) -> None:
    backend.start()
    backend.step(300.0)
    fake.answering = False
    start = time.perf_counter()
    with pytest.raises(DeviceTimeoutError, match="did not answer"):
        backend.step(300.0)
    assert time.perf_counter() - start < 1.0  # the 0.3 s timeout, promptly
    settle(fake, 4 + STOP_REPEATS)
    assert [c.left for c in fake.commands[-STOP_REPEATS:]] == [0] * STOP_REPEATS


def test_disconnect_when_the_port_vanishes(
    fake: FakeStockAltino, backend: AltinoStockBackend
) -> None:
    backend.start()
    fake.unplug()
    start = time.perf_counter()
    with pytest.raises(DeviceDisconnectedError, match="went away"):
        backend.step(100.0)
    assert time.perf_counter() - start < 1.0
    backend.close()  # still closes cleanly


def test_a_bad_checksum_is_retried_once_then_refused(
    fake: FakeStockAltino, backend: AltinoStockBackend
) -> None:
    backend.start()
    fake.corrupt = 1
    backend.step(0.0)
    assert backend.bad_replies == 1
    fake.corrupt = 2
    with pytest.raises(ProtocolError, match="failed their checksum"):
        backend.step(0.0)
    assert backend.bad_replies == 3


@pytest.mark.parametrize("mass_factor", [1.0, 2.5])  # the model's 2.2 and the heaviest 5.5
def test_the_brake_outlasts_the_end_of_the_episode(mass_factor: float) -> None:
    randomize = {"inertia": (mass_factor, mass_factor)}
    with FakeStockAltino(start_cm=20.0, rate_hz=20.0, randomize=randomize) as fake:
        env = gym.make(ALTINO_ID, backend=AltinoStockBackend(fake.port, timeout=0.3))
        env.reset()
        for _ in range(100):
            if env.step(np.array([1000.0]))[2]:  # LIMIT ends the episode: the env stops
                break
        settle(fake, len(fake.commands) + STOP_REPEATS, timeout=2.0)
        first_brake = next(i for i, c in enumerate(fake.commands) if c.left < 0)
        after = [c.left for c in fake.commands[first_brake:]]
        brakes = after.index(0)
        assert brakes >= 2, f"the stop cancelled the brake at once: {after}"
        assert after == [-1000] * brakes + [0] * STOP_REPEATS
        assert fake.car.sim.state[S_V, 0] <= STOPPED_SPEED, "still approaching at the stop"
        assert fake.car.position > 1.5
        env.close()


def test_readout_jumps_beyond_what_the_car_can_move_are_impossible() -> None:
    travel = CarBounds().top_speed(1000.0) * 0.05  # 77.7 cm/s over a 20 Hz period: 3.89 cm
    assert not readout_jump_possible(342, 86, travel)  # 2.50 -> 7.37 cm: two flipped bits
    assert not readout_jump_possible(86, 342, travel)
    assert readout_jump_possible(342, 300, travel)  # 2.50 -> 2.80 cm
    assert readout_jump_possible(86, 110, travel)  # 7.37 -> 6.23 cm
    assert not readout_jump_possible(0, 86, travel)  # from beyond 21.2 cm to 7.4 cm
    assert not readout_jump_possible(86, 0, travel)
    assert readout_jump_possible(0, 3, travel)  # 20.1 cm: just inside the range
    assert readout_jump_possible(0, 0, travel)
    assert readout_jump_possible(342, 86, 4.9)  # a car that can cover 4.9 cm could do it


def test_a_checksum_passing_jump_never_reaches_the_guard_or_controller() -> None:
    with FakeStockAltino(start_cm=966.0 / 387.0, rate_hz=20.0) as fake:  # IR 342: 2.50 cm
        env = gym.make(ALTINO_ID, backend=AltinoStockBackend(fake.port, timeout=0.3))
        backend = env.unwrapped.sim.backend
        obs, _ = env.reset()
        assert obs[0] == 342
        fake.forged = [86]  # 7.37 cm, checksum valid: the wall would look 4.9 cm farther
        obs, *_ = env.step(np.array([0.0]))
        assert obs[0] == 342, "the controller sees the car, not the corruption"
        assert backend.guard.predicted_stop() == pytest.approx(966.0 / 387.0)
        assert (backend.implausible_replies, backend.bad_replies) == (1, 1)
        assert fake.replies[-2:] == [86, 342], "refused, and the request sent again"
        fake.forged = [86, 86]
        with pytest.raises(ProtocolError, match="jump from 342 to 86, farther than the car"):
            env.step(np.array([0.0]))
        assert backend.implausible_replies == 3
        settle(fake, len(fake.commands) + STOP_REPEATS)
        assert all(c.stop for c in fake.commands[-STOP_REPEATS:])
        env.close()


def test_a_jump_is_bounded_by_the_commands_held_not_by_the_time_elapsed() -> None:
    with FakeStockAltino(start_cm=2.5, rate_hz=20.0) as fake:
        env = gym.make(ALTINO_ID, backend=AltinoStockBackend(fake.port, timeout=0.3))
        backend = env.unwrapped.sim.backend
        env.reset()
        env.step(np.array([0.0]))
        time.sleep(0.3)  # at top speed 23 cm; holding 0 at rest the car cannot move at all
        fake.forged = [86]  # 7.37 cm, checksum valid
        _, _, _, _, info = env.step(np.array([0.0]))
        assert info["position"] == pytest.approx(2.5, abs=0.05), "the forged readout was taken"
        assert backend.implausible_replies == 1
        env.close()


def test_a_jump_allows_the_readouts_noise() -> None:
    at_rest = 0.0  # readout noise alone: 19 cm read as 14 and as 6 (the model's 2-count std)
    assert readout_jump_possible(14, 6, at_rest, noise_counts=8.0)
    assert not readout_jump_possible(14, 6, at_rest)
    assert not readout_jump_possible(342, 86, at_rest, noise_counts=8.0)


def test_uri_and_env() -> None:
    backend = resolve_backend("altino-stock:///dev/rfcomm0?baud=115200&rate=20", "altino")
    assert isinstance(backend, AltinoStockBackend)
    assert (backend.port, backend.baud, backend.rate_hz) == ("/dev/rfcomm0", 115200, 20.0)
    with FakeStockAltino(start_cm=20.0, rate_hz=20.0) as fake:
        env = gym.make(ALTINO_ID, backend=AltinoStockBackend(fake.port), reference=10.0)
        obs, _ = env.reset()
        for _ in range(8):
            obs, _, terminated, _, info = env.step([p_command(float(obs[0]))])
            assert not terminated
        assert obs[0] == fake.replies[-1]
        assert info["command"] == fake.commands[-2].left  # the command held over the period
        env.close()
        settle(fake, len(fake.commands) + STOP_REPEATS - 1)
        assert fake.commands[-1].stop
