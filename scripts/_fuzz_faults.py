"""Link faults on the real-time emulator: unplugged, frozen, silent host, delayed and damaging
links. Part of ``fuzz_hardware.py``.
"""

from __future__ import annotations

import math
import random
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from _fuzz_common import Part, Progress, case_rng
from _fuzz_device import SERVO, STOP_WAIT, motor_zero_within

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.hardware import protocol
from frictiongym.hardware.emulated import EmulatedBackend
from frictiongym.hardware.errors import (
    DeviceDisconnectedError,
    DeviceTimeoutError,
    HardwareError,
    WatchdogTripError,
)
from frictiongym.hardware.runlog import read_steps
from frictiongym.hardware.transport import Faults

# --- link faults, real time ---------------------------------------------------------------------


@dataclass
class Tally:
    """What the faults raised (by type) and how many samples were checked."""

    raised: dict[str, int] = field(default_factory=dict)
    checked: int = 0

    def count(self, error: Exception) -> None:
        """Count ``error`` by its type's name."""
        name = type(error).__name__
        self.raised[name] = self.raised.get(name, 0) + 1


def fuzz_faults(runs: int, seed: int, say: Progress) -> Part:
    """Unplug, freeze and host silence on the real-time emulator; times to error and stop."""
    part = Part.named("faults")
    times: dict[str, list[float]] = {
        "unplug": [],
        "freeze": [],
        "delay": [],
        "silence": [],
        "corrupt": [],
    }
    tally = Tally()
    with tempfile.TemporaryDirectory(prefix="fuzz-faults-") as folder:
        for run in range(runs):
            for fault in times:
                rng = case_rng(seed, f"faults-{fault}", run)
                took = _one_fault(part, fault, run, rng, Path(folder) / f"{fault}-{run}", tally)
                if took is not None:
                    times[fault].append(took)
            say(f"faults: {run + 1}/{runs} rounds, {len(part.failures)} failures")
    part.cases = len(times) * runs
    for fault, values in times.items():
        if values:
            if fault == "corrupt":
                part.notes.append(
                    f"faults: corrupt: {min(values):.1%}-{max(values):.1%} of "
                    f"the frames damaged; {tally.checked} samples checked against "
                    "the device's record"
                )
                continue
            what = "motor 0 (device time)" if fault == "silence" else "error raised"
            part.notes.append(
                f"faults: {fault}: {what} {min(values) * 1000:.1f}-"
                f"{max(values) * 1000:.1f} ms after it began"
            )
    errors = ", ".join(f"{name} {count}" for name, count in sorted(tally.raised.items()))
    part.notes.append(f"faults: errors raised: {errors}")
    return part


def _one_fault(
    part: Part, fault: str, run: int, rng: random.Random, log: Path, tally: Tally
) -> float | None:
    where = f"faults {fault} run {run}"
    if fault == "delay":
        return _delayed_link(part, where, rng, log, tally)
    if fault == "corrupt":
        return _corrupt_link(part, where, rng, log, tally)
    env = gym.make(SERVO, backend="emulator://rotary", log=log)
    try:
        device = env.unwrapped.sim  # type: ignore[attr-defined]
        emulator = device.backend.emulator
        env.reset(seed=run)
        steps = rng.randint(20, 200)
        for _ in range(steps):
            env.step(np.array([rng.uniform(-1.0, 1.0)]))
        if fault == "silence":
            return _silence(part, where, env, emulator, device.info.watchdog_s, device.dt)
        expected = (DeviceDisconnectedError, DeviceTimeoutError)
        fault_now = emulator.unplug if fault == "unplug" else emulator.freeze
        took, returned = _run_into_error(part, where, env, expected, tally, fault_now)
        _check_rows(part, where, log, steps + 1 + returned)
        return took
    finally:
        env.close()


def _run_into_error(
    part: Part,
    where: str,
    env: gym.Env,
    expected: tuple[type[Exception], ...],
    tally: Tally,
    first: Callable[[], object],
    first_samples: bool = False,
    steps: int = 10_000,
) -> tuple[float | None, int]:
    """Call ``first()``, then step until an error; return its time and the samples returned.

    ``first`` starts the fault (or resets the env into it: ``first_samples``, one sample).
    The time is None (a failure recorded) for an error not ``expected``, or none at all.
    """
    started, returned = time.perf_counter(), 0
    try:
        first()
        returned += first_samples
        for _ in range(steps):
            env.step(np.array([0.5]))
            returned += 1
    except expected as exc:
        tally.count(exc)
        return time.perf_counter() - started, returned
    except Exception as exc:
        part.fail(f"{where}: raised {type(exc).__name__}: {exc}")
        return None, returned
    part.fail(f"{where}: {steps} steps into the fault and no error")
    return None, returned


def _check_rows(part: Part, where: str, log: Path, samples: int) -> None:
    rows = len(read_steps(log)["step"])
    if rows != samples:
        part.fail(f"{where}: the log holds {rows} rows of {samples} samples returned")


def _delayed_link(
    part: Part, where: str, rng: random.Random, log: Path, tally: Tally
) -> float | None:
    """A link that holds every device frame back by 0.12-0.3 s from the start (stale news).

    The device's watchdog is 1 s here, so that the host, which waits for each delayed sample
    before it sends the next command, does not trip it: only the sample age can end the run.
    """
    faults = Faults(delay=rng.uniform(0.12, 0.3))
    backend = EmulatedBackend("rotary", faults=faults, watchdog_ms=1000)
    env = gym.make(SERVO, backend=backend, log=log)
    emulator = env.unwrapped.sim.backend.emulator  # type: ignore[attr-defined]
    try:
        took, returned = _run_into_error(
            part, where, env, (HardwareError,), tally, lambda: env.reset(seed=0), True, 25
        )
        if took is not None and motor_zero_within(emulator, STOP_WAIT) is None:
            part.fail(f"{where}: the motor was not zeroed after the error")
    finally:
        env.close()
    _check_rows(part, where, log, returned)
    return took


def _corrupt_link(part: Part, where: str, rng: random.Random, log: Path, tally: Tally) -> float:
    """500 steps over a link that damages 1-10 % of the device's frames and drops bytes.

    Every sample the env returned (its row in the log) must be the device's own state at that
    tick, as the emulator recorded it: a damaged frame is dropped, never taken as a sample.
    Returns the share of frames damaged (in place of a time).
    """
    faults = Faults(corrupt=rng.uniform(0.01, 0.1), drop=rng.uniform(0.0, 0.002))
    env = gym.make(SERVO, backend=EmulatedBackend("rotary", faults=faults), log=log)
    emulator = env.unwrapped.sim.backend.emulator  # type: ignore[attr-defined]
    try:
        env.reset(seed=0)
        for step in range(500):
            try:
                env.step(np.array([np.sin(step / 40.0)]))
            except HardwareError as exc:  # a burst of drops may time a step out: reset
                tally.count(exc)
                env.reset()
        history = {tick.tick: tick for tick in emulator.history}
        hello, period_us = emulator.firmware.hello, round(emulator.dt * 1e6)
    finally:
        env.close()
    rows = read_steps(log)
    tally.checked += len(rows["seq"])
    for row in zip(
        *(rows[k] for k in ("tick_us", "seq", "seq_applied", "status", "applied", "measured")),
        strict=True,
    ):
        tick = history.get(round(row[0] / period_us))
        if tick is None:
            part.fail(f"{where}: a sample of tick {row[0]} µs the device never sent")
            return faults.corrupt
        sent = (
            tick.tick & 0xFFFF,
            tick.seq_applied,
            int(tick.status),
            tick.applied / hello.command_scale,
            tick.sensor * (2.0 * math.pi / hello.counts_per_rev),
        )
        got = tuple(float(value) for value in row[1:])
        if got != sent:
            part.fail(f"{where}: a sample {got} differs from the device's state {sent}")
            return faults.corrupt
    return faults.corrupt


def _silence(
    part: Part, where: str, env: gym.Env, emulator: Any, watchdog_s: float, dt: float
) -> float | None:
    env.step(np.array([2.0]))
    last_tick = emulator.history[-1].tick
    time.sleep(watchdog_s + 0.2)
    ticks = [t for t in emulator.history if t.tick > last_tick]
    stopped = next((t for t in ticks if t.applied == 0), None)
    if stopped is None or not stopped.status & protocol.Status.WATCHDOG:
        part.fail(f"{where}: the motor was not stopped by the watchdog in {watchdog_s + 0.2} s")
        return None
    took = (stopped.tick - last_tick) * dt
    if took > watchdog_s + 2 * dt:
        part.fail(
            f"{where}: the watchdog stopped the motor {took * 1000:.1f} ms after the "
            f"last command (its time: {watchdog_s * 1000:.0f} ms)"
        )
    try:
        env.step(np.array([2.0]))
    except WatchdogTripError:
        pass
    except Exception as exc:
        part.fail(f"{where}: after the trip a step raised {type(exc).__name__}: {exc}")
    else:
        part.fail(f"{where}: a step after the watchdog trip did not raise")
    return took
