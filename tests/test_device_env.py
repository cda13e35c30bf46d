"""Envs on a device backend: the emulator over a real pty and pyserial, and the safety rules."""

from __future__ import annotations

import gc
import json
import time

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.controllers import PID, FrictionCompensator, PIDGains
from frictiongym.hardware import (
    DeviceDisconnectedError,
    DeviceTimeoutError,
    HardwareError,
    ProtocolError,
    WatchdogTripError,
)
from frictiongym.hardware.emulated import EmulatedBackend
from frictiongym.hardware.protocol import Status
from frictiongym.hardware.runlog import read_steps
from frictiongym.plants.presets import (
    ALTINO_PAPER_GAINS_COMPENSATED,
    ALTINO_PAPER_GAINS_KI10,
    ROTARY_PAPER_GAINS,
)

SERVO = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"
LOCKSTEP = {SERVO: "emulator://rotary?lockstep=1", ALTINO: "emulator://altino?lockstep=1"}
GAINS = {SERVO: PIDGains(**ROTARY_PAPER_GAINS), ALTINO: PIDGains(**ALTINO_PAPER_GAINS_KI10)}


def emulator_of(env):
    return env.unwrapped.sim.backend.emulator


def run_closed_loop(env, controller, steps):
    obs, _ = env.reset(seed=0)
    controller.reset()
    observations, applied = [obs], []
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(controller(obs))
        observations.append(obs)
        applied.append(info["command"])
        if terminated or truncated:
            break
    return np.array(observations), np.array(applied)


@pytest.mark.parametrize("env_id", [SERVO, ALTINO])
@pytest.mark.parametrize("compensated", [False, True])
def test_a_closed_loop_episode_over_the_pty_matches_the_simulator(tmp_path, env_id, compensated):
    """Same readings, same code: the device env's observations equal the simulator's bit for bit
    when the simulator is fed the commands the device applied (1 mV / 1 unit resolution)."""
    env = gym.make(env_id, backend=LOCKSTEP[env_id], log=tmp_path / "log")
    assert env.spec.nondeterministic
    assert env.unwrapped.sim.backend.port.startswith("/dev/")  # a real pty, through pyserial
    controller = PID.for_env(env, GAINS[env_id])
    if compensated:
        gains = GAINS[env_id] if env_id == SERVO else PIDGains(**ALTINO_PAPER_GAINS_COMPENSATED)
        controller = FrictionCompensator(PID.for_env(env, gains))
    steps = 600 if env_id == SERVO else 200
    device_obs, applied = run_closed_loop(env, controller, steps)
    env.close()

    sim = gym.make(env_id)
    obs, _ = sim.reset(seed=0)
    sim_obs = [obs]
    for u in applied:
        sim_obs.append(sim.step(np.array([u]))[0])
    np.testing.assert_array_equal(device_obs, np.array(sim_obs))
    # ... and the loop did something: the output moved most of the way to the target.
    column = 0 if env_id == SERVO else 1
    target = device_obs[-1, -1]
    assert abs(device_obs[-1, column] - target) < 0.2 * abs(device_obs[0, column] - target)


def test_the_run_log_keeps_every_step_with_metadata(tmp_path):
    metadata = {"controller": "pid", "gains": ROTARY_PAPER_GAINS}
    env = gym.make(SERVO, backend=LOCKSTEP[SERVO], log=tmp_path, run_metadata=metadata)
    pid = PID.for_env(env, GAINS[SERVO])
    run_closed_loop(env, pid, 50)
    run_closed_loop(env, pid, 30)
    env.close()
    steps = read_steps(tmp_path)
    assert steps["episode"].tolist() == [0] * 51 + [1] * 31
    assert steps["step"][:3].tolist() == [0, 1, 2]
    assert np.all(np.diff(steps["seq_applied"][1:51]) == 1)
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["controller"] == "pid"
    assert meta["gains"] == ROTARY_PAPER_GAINS
    assert meta["backend"]["kind"] == "rotary"
    assert meta["rows"] == 82
    assert meta["timing"]["steps"] == 80
    assert meta["software"]["frictiongym"]


def test_real_time_at_500_hz_holds_the_period(tmp_path):
    env = gym.make(SERVO, backend="emulator://rotary", log=False)
    pid = PID.for_env(env, GAINS[SERVO])
    device_obs, _ = run_closed_loop(env, pid, 500)
    timing = env.unwrapped.sim.timing()
    env.close()
    assert timing.steps == 500
    # The device's clock paces the loop: 1 s of steps takes about 1 s (loose: a busy CI VM).
    assert 0.9 < timing.duration < 1.5
    assert abs(device_obs[-1, 0] - 1.0) < 0.05


def test_non_finite_commands_never_reach_the_device_and_zero_the_motor():
    env = gym.make(SERVO, backend=LOCKSTEP[SERVO], log=False)
    env.reset(seed=0)
    env.step(np.array([3.0]))
    emulator = emulator_of(env)
    sent = len(emulator.history)
    assert emulator.motor == 3.0
    with pytest.raises(ValueError, match="not a finite number"):
        env.step(np.array([np.nan]))
    time.sleep(0.05)
    assert emulator.motor == 0.0
    assert all(np.isfinite(tick.applied) for tick in emulator.history[sent:])
    with pytest.raises(ValueError, match="not a finite number"):
        env.step(np.array([np.inf]))
    env.close()


def test_commands_beyond_the_limit_are_saturated_as_in_simulation():
    env = gym.make(SERVO, backend=LOCKSTEP[SERVO], log=False)
    env.reset(seed=0)
    info = env.step(np.array([55.0]))[-1]
    assert info["command"] == 10.0
    assert emulator_of(env).motor == 10.0
    info = env.step(np.array([-1e9]))[-1]
    assert info["command"] == -10.0
    env.close()


def test_close_and_the_end_of_an_episode_zero_the_motor():
    env = gym.make(SERVO, backend=LOCKSTEP[SERVO], log=False, safety_limit=0.05)
    emulator = emulator_of(env)
    env.reset(seed=0)
    terminated = False
    for _ in range(200):
        _, _, terminated, _, _ = env.step(np.array([5.0]))
        if terminated:
            break
    assert terminated
    time.sleep(0.02)
    assert emulator.motor == 0.0
    with pytest.raises(HardwareError, match="reset"):
        env.step(np.array([1.0]))
    env.reset()
    env.step(np.array([2.0]))
    assert emulator.motor == 2.0
    env.close()
    assert emulator.motor == 0.0 or not emulator.running
    env.close()  # idempotent


def test_the_next_reset_zeroes_the_motor_after_a_time_limit():
    env = gym.make(SERVO, backend=LOCKSTEP[SERVO], log=False, max_episode_steps=5)
    emulator = emulator_of(env.unwrapped)
    env.reset(seed=0)
    for _ in range(5):
        *_, truncated, _ = env.step(np.array([1.0]))
    assert truncated
    assert emulator.motor == 1.0  # the env cannot see the TimeLimit wrapper's decision
    env.reset()
    time.sleep(0.02)
    assert emulator.motor == 0.0
    env.close()


def test_ctrl_c_inside_a_step_zeroes_the_motor(monkeypatch):
    env = gym.make(SERVO, backend=LOCKSTEP[SERVO], log=False)
    emulator = emulator_of(env)
    env.reset(seed=0)
    env.step(np.array([4.0]))
    backend = env.unwrapped.sim.backend

    def interrupted(seq):
        raise KeyboardInterrupt

    monkeypatch.setattr(backend, "_await", interrupted)
    with pytest.raises(KeyboardInterrupt):
        env.step(np.array([4.0]))
    time.sleep(0.05)
    assert emulator.motor == 0.0
    assert emulator.status & Status.DISABLED
    env.close()


def test_an_unplugged_device_raises_promptly_and_the_log_keeps_every_step(tmp_path):
    env = gym.make(SERVO, backend="emulator://rotary", log=tmp_path)
    emulator = emulator_of(env)
    env.reset(seed=0)
    for _ in range(100):
        env.step(np.array([0.5]))
    emulator.unplug()
    started = time.monotonic()
    with pytest.raises((DeviceDisconnectedError, DeviceTimeoutError)):  # noqa: PT012
        for _ in range(1000):
            env.step(np.array([0.5]))
    assert time.monotonic() - started < 1.0
    assert len(read_steps(tmp_path)["step"]) >= 101  # the reset sample and every step before
    time.sleep(2 * emulator.firmware.watchdog_s)  # the device's watchdog zeroed the motor
    assert emulator.motor == 0.0
    env.close()


def test_a_silent_device_times_out():
    backend = EmulatedBackend("rotary", timeout=0.2)
    env = gym.make(SERVO, backend=backend, log=False)
    env.reset(seed=0)
    env.step(np.array([0.5]))
    emulator_of(env).freeze()
    started = time.monotonic()
    with pytest.raises(DeviceTimeoutError, match="no state frame"):  # noqa: PT012
        for _ in range(100):
            env.step(np.array([0.5]))
    assert time.monotonic() - started < 0.6
    env.close()


def test_the_device_watchdog_stops_the_motor_when_the_host_stalls(tmp_path):
    env = gym.make(SERVO, backend="emulator://rotary", log=tmp_path)
    emulator = emulator_of(env)
    env.reset(seed=0)
    env.step(np.array([2.0]))
    time.sleep(5 * env.unwrapped.sim.info.watchdog_s)  # the host stalls for five watchdog times
    assert emulator.motor == 0.0
    assert emulator.status & Status.WATCHDOG
    with pytest.raises(WatchdogTripError, match="watchdog"):
        env.step(np.array([2.0]))
    (fault,) = json.loads((tmp_path / "meta.json").read_text())["faults"]  # the log says so
    assert (fault["episode"], fault["step"], fault["error"]) == (0, 2, "WatchdogTripError")
    env.reset()  # re-arms
    env.step(np.array([2.0]))
    env.close()


def test_a_host_stalled_inside_a_wait_does_not_blame_the_device(monkeypatch):
    """The host is held up (a garbage collection, the scheduler) for three timeouts inside a
    wait that then returns nothing: the frame that came meanwhile is read, no timeout."""
    backend = EmulatedBackend("rotary", lockstep=True)
    env = gym.make(SERVO, backend=backend, log=False)
    env.reset(seed=0)
    env.step(np.array([0.5]))
    original, stalls = backend._read_available, []

    def read_available(wait=True):
        if wait and not stalls:
            stalls.append(3 * backend.timeout)
            time.sleep(stalls[0])
            return b""
        return original(wait)

    monkeypatch.setattr(backend, "_read_available", read_available)
    env.step(np.array([0.5]))
    assert stalls
    assert not env.unwrapped.sim.last_sample.late
    env.close()


def test_a_device_episode_keeps_older_objects_out_of_the_collectors_scans():
    """A full collection of a large process stalls a loop for longer than a watchdog: each reset
    freezes the objects alive then (gc.freeze), and closing the env hands them back."""
    env = gym.make(SERVO, backend=LOCKSTEP[SERVO], log=False)
    before = gc.get_freeze_count()
    alive = [[k] for k in range(1000)]  # tracked objects made before the episode
    env.reset(seed=0)
    assert gc.get_freeze_count() >= before + len(alive)
    env.step(np.array([0.5]))
    env.close()
    assert gc.get_freeze_count() == 0


@pytest.mark.parametrize("command", [300.0, 600.0, 1000.0])
@pytest.mark.parametrize("start", [2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 15.0, 30.0, None])
def test_the_altino_never_reaches_the_wall(start, command):
    """From rest anywhere (None: the default start), the guard stops the car short of the wall.

    Close to the wall it refuses the forward command before the car moves (guard.py: the
    command is judged, held over the reaction time, before the motor gets it).
    """
    env = gym.make(ALTINO, backend=LOCKSTEP[ALTINO], log=False)
    emulator = emulator_of(env)
    env.reset(seed=0, options=None if start is None else {"position": start})
    terminated, steps = False, 0
    while not terminated and steps < 400:
        _, reward, terminated, _, _ = env.step(np.array([command]))
        steps += 1
    assert terminated
    assert reward < -50  # the limit penalty
    assert env.unwrapped.sim.last_sample.status & Status.LIMIT  # the device's guard ended it
    time.sleep(0.05)
    assert emulator.motor <= 0.0
    # The car coasts (and the guard brakes, e-stopped as it is) to a stop short of the wall:
    # in lock-step every e-stop the host sends is one more period of device time.
    backend, ticks = env.unwrapped.sim.backend, emulator.stats().ticks
    for _ in range(20):
        backend.stop()  # two ESTOP commands each
    deadline = time.monotonic() + 5.0
    while emulator.stats().ticks < ticks + 40 and time.monotonic() < deadline:
        time.sleep(0.002)
    assert emulator.stats().ticks >= ticks + 40
    assert emulator.velocity == 0.0
    assert emulator.motor == 0.0
    assert min(tick.position for tick in emulator.history) > 1.0
    env.close()


def test_device_runs_refuse_simulator_only_settings_and_the_wrong_device():
    with pytest.raises(ValueError, match="randomize"):
        gym.make(SERVO, backend=LOCKSTEP[SERVO], randomize={"friction": (0.9, 1.1)})
    with pytest.raises(ValueError, match="device is one env"):
        gym.make_vec(SERVO, 2, vectorization_mode="vector_entry_point", backend="emulator://")
    with pytest.raises(ProtocolError, match="is an Altino car, but this env drives a QUBE-Servo 2"):
        gym.make(SERVO, backend="emulator://altino?lockstep=1", log=False)
    with pytest.raises(ValueError, match="dt="):
        gym.make(SERVO, backend=LOCKSTEP[SERVO], dt=0.001, log=False)
    with pytest.raises(ValueError, match="unknown option"):
        gym.make(SERVO, backend="emulator://rotary?speed=2", log=False)
