"""The device emulator, driven with raw protocol frames over pyserial (pty and TCP).

Real-time tests are loose (CI is a noisy VM); every wait has a deadline, so none can hang.
"""

import math
import subprocess
import sys
import threading
import time
from functools import partial
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from _emulator_cli import emulator_port
from hypothesis import given, settings
from hypothesis import strategies as st

import frictiongym  # noqa: F401  (registers the envs)
from frictiongym.controllers import PID, FrictionCompensator, PIDGains
from frictiongym.devices import ROTARY
from frictiongym.envs import _kernel as env_kernel
from frictiongym.envs.core import Simulation
from frictiongym.hardware import protocol
from frictiongym.hardware.emulator import Emulator, Faults
from frictiongym.hardware.firmware import FIRMWARE_BUILD, Firmware
from frictiongym.hardware.guard import LIMIT_CM
from frictiongym.plants import _kernel as plant_kernel
from frictiongym.plants.presets import (
    ALTINO_PAPER_GAINS_COMPENSATED,
    ALTINO_PAPER_GAINS_KI10,
    ALTINO_PAPER_GAINS_KI20,
)
from frictiongym.plants.sensors import ir_readout

serial = pytest.importorskip("serial")

STEP = 2.0 * math.pi / 2048
SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "emulate.py"
ARM = protocol.Flag.REARM | protocol.Flag.ENABLE


class Host:
    """A minimal host speaking raw frames (independent of SerialBackend)."""

    def __init__(self, url: str) -> None:
        self.port = serial.serial_for_url(url, timeout=0.02)
        self.decoder = protocol.FrameDecoder()
        self.seq = 0

    def send(self, message: protocol.Message) -> None:
        self.port.write(protocol.encode(message))

    def command(self, counts: int, flags: protocol.Flag = protocol.Flag.ENABLE) -> int:
        self.seq = (self.seq + 1) & 0xFFFF
        self.send(protocol.Command(self.seq, counts, flags))
        return self.seq

    def read(self) -> list[protocol.Message]:
        return self.decoder.feed(self.port.read(max(1, self.port.in_waiting)))

    def collect(self, seconds: float) -> list[protocol.Message]:
        end, out = time.monotonic() + seconds, []
        while time.monotonic() < end:
            out += self.read()
        return out

    def wait(self, kind: type, test=lambda m: True, timeout: float = 2.0):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for message in self.read():
                if isinstance(message, kind) and test(message):
                    return message
        raise AssertionError(f"no {kind.__name__} within {timeout} s")

    def hello(self) -> protocol.Hello:
        self.send(protocol.HelloRequest())
        return self.wait(protocol.Hello)

    def step(self, counts: int, flags: protocol.Flag = protocol.Flag.ENABLE) -> protocol.State:
        seq = self.command(counts, flags)
        return self.wait(protocol.State, lambda s: s.seq_applied == seq)

    def close(self) -> None:
        self.port.close()


@pytest.fixture
def serve(request):
    """``serve(kind, **kwargs) -> (emulator, host)`` on a pty (or TCP), closed after the test."""
    made = []

    def make(kind="rotary", tcp=False, **kwargs):
        emu = Emulator(kind, **kwargs)
        made.append(emu)
        url = emu.serve_tcp() if tcp else emu.serve_pty()
        host = Host(url)
        made.append(host)
        return emu, host

    yield make
    for thing in reversed(made):
        thing.close()


@pytest.mark.parametrize(
    ("kind", "rate", "cpr", "scale", "limit", "wd", "caps"),
    [
        (
            "rotary",
            500,
            2048,
            1000,
            10000,
            100,
            protocol.Capability.WATCHDOG | protocol.Capability.PLACE,
        ),
        (
            "altino",
            20,
            0,
            1,
            1000,
            150,
            protocol.Capability.WATCHDOG
            | protocol.Capability.PLACE
            | protocol.Capability.DISTANCE_LIMIT,
        ),
    ],
)
def test_hello_describes_the_device(serve, kind, rate, cpr, scale, limit, wd, caps):
    emu, host = serve(kind)
    hello = host.hello()
    assert hello == protocol.Hello(
        protocol.PROTOCOL_VERSION,
        protocol.DeviceKind[kind.upper()],
        caps,
        rate,
        cpr,
        scale,
        limit,
        wd,
        FIRMWARE_BUILD,
    )
    host.send(
        protocol.HelloRequest(version=7)
    )  # another version still gets a Hello: the host decides
    assert host.wait(protocol.Hello) == hello
    assert emu.dt == pytest.approx(1.0 / rate)


def test_boots_disabled_and_streams_states_at_its_rate(serve):
    emu, host = serve("rotary")
    states = [m for m in host.collect(0.3) if isinstance(m, protocol.State)]
    assert len(states) > 30
    assert all(s.status & protocol.Status.DISABLED and s.applied == 0 for s in states)
    assert emu.motor == 0.0
    seqs, ticks = np.array([s.seq for s in states]), np.array([s.tick_us for s in states])
    assert np.all(np.diff(seqs) >= 1)
    assert np.all(np.diff(ticks) == np.diff(seqs) * 2000)  # the device's clock, 2 ms per tick
    host.step(3000)  # ENABLE without REARM: still off
    assert emu.motor == 0.0


@pytest.mark.parametrize(
    ("kind", "env_id", "commands"),
    [
        (
            "rotary",
            "frictiongym/RotaryServo-v1",
            [1500] * 150 + [-800] * 100 + [300] * 50 + list(range(-3000, 3000, 60)),
        ),
        (
            "altino",
            "frictiongym/AltinoDistance-v1",
            [400] * 15 + [-200] * 10 + [300] * 15 + [0] * 5,
        ),
    ],
)
def test_lockstep_episode_equals_the_simulated_env(serve, kind, env_id, commands):
    env = gym.make(env_id).unwrapped
    obs, _ = env.reset(seed=0)  # first: compiling the env's kernel must not trip the watchdog
    emu, host = serve(kind, lockstep=True)
    hello = host.hello()
    first = host.step(0, ARM | protocol.Flag.ZERO_POSITION)
    assert first.status == protocol.Status(0)
    assert first.sensor == (0 if kind == "rotary" else int(obs[0]))
    for counts in commands:
        state = host.step(counts)
        assert state.status == protocol.Status(0)
        assert state.applied == counts
        obs, *_ = env.step(np.array([state.applied / hello.command_scale], np.float32))
        if kind == "rotary":  # the env's own float product: bit-identical
            assert state.sensor * STEP == env.sim.state[env_kernel.E_ESTIMATE, 0]
            assert np.float32(state.sensor * STEP) == obs[0]
        else:
            assert state.sensor == obs[0]
    assert emu.position == pytest.approx(
        env.sim.state[plant_kernel.S_X, 0] * (1 if kind == "rotary" else -1)
    )
    assert [t.sensor for t in emu.history[-len(commands) :]] != [0] * len(commands)
    assert emu.stats().ticks == len(commands) + 1


@pytest.mark.parametrize("law", ["paper", "coulomb", "stribeck", "lugre", "none"])
def test_zero_position_at_rest_equals_a_fresh_reset(law):
    fw = Firmware("rotary", friction=law)
    fw.receive(protocol.Command(1, 0, ARM), 0.0)
    for counts in [2500] * 100 + [0] * 2500:  # turn, then come to rest (or slide forever)
        fw.receive(protocol.Command(2, counts, protocol.Flag.ENABLE), 0.0)
        fw.tick(0.0)
    assert fw.position > 1.0
    velocity = fw.velocity
    fw.receive(protocol.Command(3, 0, protocol.Flag.ENABLE | protocol.Flag.ZERO_POSITION), 0.0)
    fw.apply_pending()
    assert fw.position == 0.0
    assert fw.velocity == velocity
    fresh = Simulation(ROTARY, 1, friction=law, reference=0.0)
    fresh.prepare_reset(np.ones(1, bool), lambda _: np.random.default_rng(0))
    if law in ("paper", "coulomb", "stribeck"):  # laws with stiction come to rest exactly
        assert velocity == 0.0
        plant_state = fresh.state[: plant_kernel.STATE_SIZE, 0]
        np.testing.assert_array_equal(fw.plant.state[:, 0], plant_state)
        assert fw.sensor == env_kernel.task_state(fresh.state, "estimate")[0] == 0.0


@pytest.mark.parametrize("kind", ["rotary", "altino"])
def test_firmware_reads_the_env_sensor_with_the_env_draws(kind):
    """Noise, a randomised plant and sensor gain: the firmware's readings are the env's own."""
    spread = {"friction": (0.7, 1.3), "inertia": (0.8, 1.2), "sensor_gain": (0.9, 1.1)}
    start = 15.0 if kind == "altino" else 0.5  # the IR sensor reads 0 beyond 21 cm
    fw = Firmware(kind, sensor_noise=True, randomize=spread, seed=7, start=start)
    limit = 0.0 if kind == "altino" else 1e9  # the firmware ends nothing; the car stays ahead
    sim = Simulation(
        fw.device,
        1,
        sensor_noise=True,
        randomize=spread,
        reference=0.0,
        safety_limit=limit,
        parallel=False,
    )
    rng, fresh = np.random.default_rng(7), np.ones(1, dtype=bool)
    obs = np.zeros((1, sim.observation_size), dtype=np.float32)
    out, flags = np.zeros((env_kernel.OUT_SIZE, 1)), np.zeros((env_kernel.FLAG_SIZE, 1), dtype=bool)
    sim.prepare_reset(fresh, lambda _: rng, {"position": start})

    def env_reading(command: float) -> int:
        sim.run(np.array([command]), fresh, obs, out, flags)
        if kind == "rotary":
            return round(float(env_kernel.task_state(sim.state, "estimate")[0]) / STEP)
        return int(obs[0, 0])

    assert fw.sensor == env_reading(0.0)
    fresh[0] = False
    counts = [fw.hello.command_limit // 4] * 15 + [-fw.hello.command_limit // 4] * 30
    readings = []
    for count in counts:
        fw.hold(count)
        readings.append(fw.sensor)
        assert fw.sensor == env_reading(count / fw.scale)
        np.testing.assert_array_equal(fw.plant.state[:, 0], sim.state[: plant_kernel.STATE_SIZE, 0])
    assert len(set(readings)) > 10  # the plant moved and the noise showed


def test_the_firmware_and_emulator_do_not_import_the_envs():
    """The emulator's plant is the plant core's: importing it loads no env module."""
    code = (
        "import sys, frictiongym.hardware.emulator, frictiongym.hardware.firmware; "
        "print(sorted(m for m in sys.modules if m.startswith('frictiongym.envs.')))"
    )
    loaded = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert loaded == "[]"


_COMMANDS = st.builds(
    lambda flags, counts, seq: protocol.encode(protocol.Command(seq, counts, protocol.Flag(flags))),
    st.integers(0, 15),
    st.integers(-32768, 32767),
    st.integers(0, 0xFFFF),
)
_PLACES = st.builds(lambda x: protocol.encode(protocol.Place(x)), st.floats(width=32))
_CHUNKS = st.lists(st.one_of(st.binary(max_size=40), _COMMANDS, _PLACES), max_size=40)


@settings(max_examples=40, deadline=None)
@given(chunks=_CHUNKS, kind=st.sampled_from(["rotary", "altino"]))
def test_any_input_keeps_the_firmware_safe(chunks, kind):
    fw = Firmware(kind)
    for i, chunk in enumerate(chunks):
        for message in fw.feed(chunk):
            fw.receive(message, i * fw.dt)
        state = fw.tick(i * fw.dt)
        assert abs(state.applied) <= fw.hello.command_limit
        braking = state.status & protocol.Status.LIMIT and state.applied == -fw.hello.command_limit
        assert state.applied == 0 or (fw.armed and fw.enabled) or braking
        assert bool(state.status & protocol.Status.DISABLED) != (fw.armed and fw.enabled)
        assert math.isfinite(fw.position)


def test_zero_position_while_moving_keeps_the_velocity(serve):
    emu, host = serve("rotary", lockstep=True)
    host.step(0, ARM)
    for _ in range(100):
        host.step(3000)
    before = emu.velocity
    state = host.step(3000, protocol.Flag.ENABLE | protocol.Flag.ZERO_POSITION)
    assert 0 < state.sensor < before * emu.dt / STEP + 2  # one period of travel from zero
    assert emu.position == pytest.approx(before * emu.dt, rel=0.05)


def test_place_puts_the_plant_at_rest_there(serve):
    emu, host = serve("rotary", lockstep=True)
    host.send(protocol.Place(1.0))
    state = host.step(0, ARM)
    assert state.sensor == round(1.0 / STEP)
    assert emu.velocity == 0.0
    emu2, host2 = serve("altino", lockstep=True)
    host2.send(protocol.Place(-3.0))  # behind the wall: ignored
    host2.send(protocol.Place(8.0))
    state = host2.step(0, ARM)
    assert emu2.position == 8.0
    assert state.sensor == ir_readout(8.0)
    assert emu2.firmware.rejected == 1


def test_watchdog_zeroes_the_motor_in_time_and_latches(serve):
    emu, host = serve("rotary")
    host.hello()
    host.step(2000, ARM)
    for _ in range(50):
        state = host.step(2000)
    assert emu.motor == 2.0
    stopped = time.monotonic()
    while emu.motor != 0.0 and time.monotonic() - stopped < 1.0:
        time.sleep(0.0005)
    elapsed = time.monotonic() - stopped
    watchdog, dt = emu.firmware.watchdog_s, emu.dt
    assert watchdog == 0.1  # the default, max(3 periods, 100 ms)
    assert elapsed < watchdog + dt + 0.05  # loose: a noisy VM may wake us late
    # Exact on the device clock: zeroed on the first tick at or after watchdog_ms.
    ticks = emu.history
    last = max(t.tick for t in ticks if t.seq_applied == host.seq and t.applied == 2000)
    tripped = min(t.tick for t in ticks if t.status & protocol.Status.WATCHDOG)
    assert tripped - last <= round(watchdog / dt) + 1
    state = host.wait(protocol.State, lambda s: s.status & protocol.Status.WATCHDOG)
    assert state.status & protocol.Status.DISABLED
    assert state.applied == 0
    state = host.step(2000)  # latched: ENABLE alone does not restart it
    assert state.applied == 0
    assert state.status & protocol.Status.WATCHDOG
    state = host.step(2000, ARM)
    assert state.applied == 2000
    assert not state.status & protocol.Status.WATCHDOG
    host.step(0, protocol.Flag(0))


def test_lockstep_watchdog_sends_a_state_when_commands_stop(serve):
    emu, host = serve("altino", lockstep=True, watchdog_ms=60)
    host.step(300, ARM)
    sent = time.monotonic()
    state = host.wait(protocol.State, lambda s: s.status & protocol.Status.WATCHDOG, timeout=2.0)
    assert 0.05 <= time.monotonic() - sent < 1.0
    assert state.applied == 0
    assert emu.motor == 0.0
    assert host.collect(0.15) == []  # disarmed: nothing more until a command


def _hold_up_once(emu, monkeypatch, seconds, when):
    """Make the device thread stall ``seconds`` once, after a ``select`` for which ``when(ready)``
    holds, as a garbage collection or the scheduler would; return an Event set as it stalls."""
    stalling, original = threading.Event(), emu._wait

    def wait(timeout):
        ready = original(timeout)
        if not stalling.is_set() and when(ready):
            stalling.set()
            time.sleep(seconds)
        return ready

    monkeypatch.setattr(emu, "_wait", wait)
    return stalling


def test_a_late_emulator_thread_does_not_blame_the_host(serve, monkeypatch):
    """The real-time device thread stalls for 2.5 watchdog times after a command came: the ticks
    it missed are integrated, but their states never went out, so the host could not answer
    them and the watchdog must not trip."""
    emu, host = serve("rotary")
    host.step(2000, ARM)
    received = emu.firmware.commands
    seq = host.command(2000)
    stalling = _hold_up_once(
        emu,
        monkeypatch,
        2.5 * emu.firmware.watchdog_s,
        lambda ready: emu.firmware.commands > received,
    )
    state = host.wait(protocol.State, lambda s: s.seq_applied == seq, timeout=2.0)
    states = [state] + [host.step(2000) for _ in range(20)]
    assert stalling.is_set()
    assert emu.stats().missed >= 2 * emu.firmware.watchdog_s / emu.dt  # it did stall
    assert not any(s.status & protocol.Status.WATCHDOG for s in states)
    assert emu.motor == 2.0


def test_lockstep_watchdog_reads_before_it_trips(serve, monkeypatch):
    """The lock-step device thread is held up past its watchdog right after a wait that found
    nothing, while a command arrives: the command counts, the watchdog does not trip."""
    emu, host = serve("rotary", lockstep=True, watchdog_ms=60)
    host.step(1000, ARM)
    stalling = _hold_up_once(emu, monkeypatch, 0.2, lambda ready: not ready)
    assert stalling.wait(1.0)
    state = host.step(1000)
    assert not state.status & protocol.Status.WATCHDOG
    assert state.applied == 1000


def test_estop_disarms_until_rearm(serve):
    emu, host = serve("rotary", lockstep=True)
    assert host.step(1000, ARM).applied == 1000
    state = host.step(1000, protocol.Flag.ENABLE | protocol.Flag.ESTOP)
    assert state.applied == 0
    assert state.status & protocol.Status.DISABLED
    assert emu.motor == 0.0
    assert host.step(1000).applied == 0
    assert host.step(-1000, ARM).applied == -1000
    assert emu.motor == -1.0
    assert host.step(25000).applied == 10000  # clipped to the limit: 10 V


def _drive_until_the_guard_trips(host: Host, counts: int) -> None:
    host.step(0, ARM)
    for _ in range(100):
        state = host.step(counts)
        assert state.applied == counts  # what was held over the period that ended
        if state.status & protocol.Status.LIMIT:
            return
    raise AssertionError("the car drove on without the distance guard tripping")


def test_altino_guard_brakes_then_refuses_forward(serve):
    emu, host = serve("altino", lockstep=True)
    _drive_until_the_guard_trips(host, 600)
    assert emu.motor == -1000.0  # full reverse from the next period on
    applied = []
    while emu.velocity != 0.0 and len(applied) < 40:  # the host keeps asking for +600
        state = host.step(600)
        assert state.status == protocol.Status.LIMIT
        applied.append(state.applied)
    stopped = applied.index(0)
    assert stopped >= 1
    assert applied == [-1000] * stopped + [0] * (len(applied) - stopped)
    assert emu.velocity == 0.0
    assert min(t.position for t in emu.history) > 1.0
    state = host.step(-300)  # backing away passes, the trip stays latched
    assert state.applied == -300
    assert state.status == protocol.Status.LIMIT
    assert host.step(300).applied == 0  # forward: refused
    state = host.step(300, ARM)  # REARM, at rest well clear of the limit: cleared
    assert state.status == protocol.Status(0)
    assert state.applied == 300


@pytest.mark.parametrize("counts", [600, 1000])
def test_altino_guard_brakes_through_an_estop(serve, counts):
    """The host e-stops when it sees LIMIT: the brake goes on while the car approaches.

    From 20 cm, within the IR range: from the default 30 cm, +1000 trips the guard before the
    car is in range (the car could become too fast to stop within it), where it does not brake
    blind.
    """
    emu, host = serve("altino", lockstep=True, start=20.0)
    _drive_until_the_guard_trips(host, counts)
    state = host.step(0, protocol.Flag.ESTOP)
    assert state.status == protocol.Status.LIMIT | protocol.Status.DISABLED
    assert state.applied == -1000
    for _ in range(40):
        state = host.step(0, protocol.Flag.ESTOP)
        assert state.applied in (-1000, 0)
    assert emu.velocity == 0.0
    assert emu.motor == 0.0
    assert state.applied == 0
    assert min(t.position for t in emu.history) > 1.0
    assert host.step(300).applied == 0  # disarmed: ENABLE without REARM


@pytest.mark.parametrize(
    ("gains", "compensated"),
    [
        (ALTINO_PAPER_GAINS_KI10, False),
        (ALTINO_PAPER_GAINS_KI20, False),  # overshoots to 1.9 cm in our model
        (ALTINO_PAPER_GAINS_COMPENSATED, True),
    ],
)
def test_the_paper_gains_never_trip_the_guard(gains, compensated):
    env = gym.make(
        "frictiongym/AltinoDistance-v1", backend="emulator://altino?lockstep=1", log=False
    )
    emulator = env.unwrapped.sim.backend.emulator
    controller = PID.for_env(env, PIDGains(**gains))
    if compensated:
        controller = FrictionCompensator(controller)
    obs, _ = env.reset(seed=0)
    controller.reset()
    steps, truncated = 0, False
    while not truncated:
        obs, _, terminated, truncated, _ = env.step(controller(obs))
        assert not terminated, f"step {steps}: the episode ended (status {emulator.status!r})"
        steps += 1
    env.close()
    assert steps == 400
    ticks = emulator.history
    assert not any(t.status & protocol.Status.LIMIT for t in ticks)
    assert min(t.position for t in ticks) > LIMIT_CM


def test_bad_frames_set_the_crc_error_bit_once(serve):
    emu, host = serve("rotary", lockstep=True)
    host.step(0, ARM)
    frame = bytearray(protocol.encode(protocol.Command(5, 100, protocol.Flag.ENABLE)))
    frame[3] ^= 0x10
    host.port.write(b"\x13\x37garbage\x00" + bytes(frame))
    state = host.step(0)
    assert state.status & protocol.Status.CRC_ERROR
    assert not host.step(0).status & protocol.Status.CRC_ERROR
    assert emu.stats().crc_errors == 2


@pytest.mark.parametrize("faults", [Faults(drop=0.02), Faults(corrupt=0.3)])
def test_link_faults_show_as_decoder_errors(serve, faults):
    _, host = serve("rotary", faults=faults, seed=3)
    states = [m for m in host.collect(0.4) if isinstance(m, protocol.State)]
    assert host.decoder.errors > 0
    assert len(states) > 20  # the decoder resynchronises; good frames still pass


def test_delay_holds_frames(serve):
    _, host = serve("altino", faults=Faults(delay=0.1, jitter=0.02))
    host.collect(0.15)
    sent = time.monotonic()
    host.send(protocol.HelloRequest())
    host.wait(protocol.Hello)
    assert time.monotonic() - sent >= 0.1


def _link_failure(port, seconds: float) -> OSError | None:
    """Read and write ``port`` until it fails (pyserial's errors are OSErrors) or time is up."""
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            port.read(max(1, port.in_waiting))
            port.write(b"\x00")
    except OSError as exc:
        return exc
    return None


@pytest.mark.parametrize("tcp", [False, True])
def test_unplug_fails_the_host_and_the_watchdog_stops_the_motor(serve, tcp):
    emu, host = serve("rotary", tcp=tcp)
    host.step(1500, ARM)
    host.step(1500)
    emu.unplug()
    unplugged = time.monotonic()
    assert isinstance(_link_failure(host.port, 0.5), OSError)
    assert time.monotonic() - unplugged < 0.5
    end = time.monotonic() + 1.0
    while emu.motor != 0.0 and time.monotonic() < end:
        time.sleep(0.005)
    assert emu.motor == 0.0
    assert emu.status & protocol.Status.WATCHDOG
    assert emu.running  # the device itself keeps going


def test_unplug_and_freeze_after_device_time(serve):
    _, host = serve("altino", faults=Faults(unplug_after=0.2))
    host.wait(protocol.State)
    assert isinstance(_link_failure(host.port, 2.0), OSError)
    emu2, host2 = serve("rotary", faults=Faults(freeze_after=0.1))
    host2.wait(protocol.State)
    host2.collect(0.2)
    assert host2.collect(0.2) == []  # the host times out; the link is still open
    host2.send(protocol.HelloRequest())
    assert host2.collect(0.1) == []
    assert emu2.running
    assert host2.port.is_open


def test_freeze_keeps_the_link_open_and_silent(serve):
    emu, host = serve("rotary")
    host.hello()
    host.step(500, ARM)
    emu.freeze()
    host.collect(0.05)
    assert host.collect(0.2) == []
    assert emu.motor == 0.0  # the watchdog still runs


def test_tcp_serves_one_client_after_another(serve):
    emu, host = serve("altino", tcp=True)
    assert emu.url.startswith("socket://127.0.0.1:")
    assert host.hello().kind == protocol.DeviceKind.ALTINO
    host.close()
    again = Host(emu.url)
    try:
        assert again.hello().rate_hz == 20
    finally:
        again.close()


def test_pty_survives_the_host_closing_the_port(serve):
    emu, host = serve("rotary")
    host.hello()
    host.close()
    time.sleep(0.1)  # the emulator sees EIO on the master, waits and retries
    again = Host(emu.url)
    try:
        assert again.hello().kind == protocol.DeviceKind.ROTARY
    finally:
        again.close()
    assert emu.running
    assert emu.error is None


def test_keeps_up_at_500_hz(serve):
    emu, host = serve("rotary")
    host.step(0, ARM)
    for _ in range(250):  # half a second of closed loop
        host.step(500)
    stats = emu.stats()
    assert stats.ticks >= 200
    assert stats.missed < stats.ticks // 4
    assert stats.tick_time_mean < emu.dt / 2


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="probability"):
        Faults(drop=-0.1)
    with pytest.raises(ValueError, match="delay must be finite, got inf"):
        Faults(delay=math.inf)
    with pytest.raises(ValueError, match=r"delay must be >= 0 s, got -1"):
        Faults(delay=-1)
    with pytest.raises(ValueError, match="unknown device"):
        Emulator("segway")
    with pytest.raises(ValueError, match="watchdog_ms"):
        Emulator("rotary", watchdog_ms=-5)
    emu = Emulator("rotary")
    emu.close()
    emu.close()
    with pytest.raises(RuntimeError, match="closed"):
        emu.serve_pty()


def test_cli_prints_a_connectable_port_and_stops_on_sigint():
    with emulator_port([sys.executable, str(SCRIPT), "--device", "rotary", "--quiet"]) as url:
        assert url.startswith("/dev/")
        host = Host(url)
        try:
            assert host.hello().kind == protocol.DeviceKind.ROTARY
        finally:
            host.close()


def test_cli_duration_status_lines_and_bad_input(tmp_path, capsys):
    from frictiongym.cli import tool_main

    main = partial(tool_main, "emulate")

    assert main(["--device", "altino", "--tcp", "0", "--duration", "1.2"]) == 0
    out, err = capsys.readouterr()
    assert out.splitlines()[0].startswith("socket://127.0.0.1:")
    assert "ticks" in err
    assert "DISABLED" in err
    assert "# device thread: " in err  # SCHED_FIFO, or why not
    assert main(["--device", "altino", "--tcp", "0", "--duration", "0.3", "--no-realtime"]) == 0
    assert "# device thread: ordinary, SCHED_FIFO not asked for" in capsys.readouterr().err
    bad = tmp_path / "friction.json"
    bad.write_text("{not json")
    other = Path(__file__).resolve().parents[1] / "docs" / "identification" / "altino"
    for extra in (
        ["--drop", "-0.5"],
        ["--corrupt", "2"],
        ["--params", str(bad)],
        ["--params", str(tmp_path / "x")],
        ["--duration", "-1"],
        ["--friction", "glue"],
        ["--watchdog", "-3"],
        ["--tcp", "1.2.3.4.5:99"],
        *([["--params", str(other)]] if other.exists() else []),
    ):
        assert main(["--device", "rotary", *extra]) == 2, extra
        out, err = capsys.readouterr()
        assert err.startswith("error:"), (extra, err)
        assert out == "", extra


def test_cli_help_and_unknown_device(capsys):
    from frictiongym.cli import tool_main, tool_parser

    main = partial(tool_main, "emulate")

    text = tool_parser("emulate").format_help()
    for word in ("--device", "--tcp", "--drop", "--unplug-after", "serial://", "socket://"):
        assert word in text
    with pytest.raises(SystemExit) as exit_:
        main(["--device", "rotary", "--tcp", "port"])
    assert exit_.value.code == 2
    assert main(["--device", "segway"]) == 2  # neither a device nor a description file
    assert "unknown device 'segway'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    assert "--lockstep" in capsys.readouterr().out
