"""Devices under fuzzing: the firmware watchdog (C and its Python twin), hostile actions
through device envs on the lock-step emulator, and hostile commands through the stock Altino
backend. Part of ``fuzz_hardware.py``.
"""

from __future__ import annotations

import fractions
import math
import random
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from _fuzz_common import ROOT, CHarness, Part, Progress, case_rng, progress

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.hardware import protocol
from frictiongym.hardware.firmware import Firmware
from frictiongym.hardware.runlog import read_steps

SERVO, ALTINO = "frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1"
KIND = {SERVO: "rotary", ALTINO: "altino"}
#: Longest wait for the emulator to show a zeroed motor after an error, s: well under the
#: lock-step emulator's 1 s watchdog, which would otherwise stop a motor the host left running.
STOP_WAIT = 0.5


def motor_zero_within(emulator: Any, seconds: float) -> float | None:
    """Wait for the emulated motor to read 0; return how long it took (None: it did not)."""
    started = time.perf_counter()
    while time.perf_counter() - started < seconds:
        if emulator.motor == 0.0:
            return time.perf_counter() - started
        time.sleep(0.0005)
    return None


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
                flags = protocol.Flag.ENABLE | (protocol.Flag.REARM if seq == 1 else 0)
                frame = protocol.encode(protocol.Command(seq, command, flags))
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
            flags = protocol.Flag.ENABLE | (protocol.Flag.REARM if seq == 1 else 0)
            firmware.receive(protocol.Command(seq, command, flags), now)
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
        c_motors = [
            int(a[1].split()[1])
            for line, a in zip(lines, mine, strict=True)
            if line.startswith("dev_tick")
        ]
        if c_motors != python:
            pairs = enumerate(zip(c_motors, python, strict=False))
            first = next((i for i, (a, b) in pairs if a != b), min(map(len, (c_motors, python))))
            if first == min(len(c_motors), len(python)):
                part.fail(
                    f"watchdog case {case}: C ran {len(c_motors)} ticks, Python {len(python)}"
                )
                continue
            part.fail(
                f"watchdog case {case}: C motor {c_motors[first]}, Python "
                f"{python[first]} at tick {first}"
            )


# --- actions ----------------------------------------------------------------------------------


class Hostile:
    """An object with no number in it."""


def hostile_action(rng: random.Random, limit: float) -> tuple[str, object, bool]:
    """An action, what it is, and whether the env must refuse it (a non-finite value, a
    non-number or several numbers); a refused one must never reach the device."""
    kind = rng.randrange(14)
    if kind == 0:
        return "NaN", np.array([rng.choice([math.nan, -math.nan])]), True
    if kind == 1:
        return "inf", np.array([rng.choice([math.inf, -math.inf])], dtype=np.float32), True
    if kind == 2:
        return "huge float", np.array([rng.choice([-1, 1]) * 10.0 ** rng.randint(3, 308)]), False
    if kind == 3:
        return "huge int", rng.choice([-1, 1]) * 10 ** rng.randint(3, 400), False
    if kind == 4:
        return "string", rng.choice(["1.5", "nan", "", "1e9"]), True
    if kind == 5:
        return "date", np.datetime64("2020-01-01"), True
    if kind == 6:
        return "None", None, True
    if kind == 7:
        return "complex", complex(rng.uniform(-1, 1), 1.0), True
    if kind == 8:
        return "object", Hostile(), True
    if kind == 9:
        shape = rng.choice([(2,), (0,), (3, 1), (2, 2)])
        return f"shape {shape}", np.full(shape, 0.5 * limit), True
    if kind == 10:
        return "bool", rng.choice([True, np.bool_(True)]), True
    if kind == 11:
        return "object array", np.array([Hostile()], dtype=object), True
    if kind == 12:
        return "fraction", fractions.Fraction(rng.randint(-30, 30), 7), False
    return "int64 extreme", np.array([np.iinfo(np.int64).max * rng.choice([-1, 1])]), False


class CommandSpy:
    """Every ``Command`` the emulated device decoded, taken from its firmware's decoder."""

    def __init__(self, emulator: Any) -> None:
        self.commands: list[protocol.Command] = []
        firmware = emulator.firmware
        feed = firmware.feed

        def spied(data: bytes) -> list[protocol.Message]:
            messages = feed(data)
            self.commands += [m for m in messages if isinstance(m, protocol.Command)]
            return messages

        firmware.feed = spied


def fuzz_actions(cases: range, seed: int, say: Progress) -> Part:
    """Hostile and ordinary actions through device envs on the lock-step emulator."""
    part = Part.named("actions")
    refused: dict[str, int] = {}
    stops: list[float] = []
    with tempfile.TemporaryDirectory(prefix="fuzz-actions-") as folder:
        for env_id in (SERVO, ALTINO):
            half = cases.start + len(cases) // 2  # the servo's cases, then the Altino's
            share = range(cases.start, half) if env_id == SERVO else range(half, cases.stop)
            _actions_on(part, env_id, share, seed, Path(folder) / KIND[env_id], refused, stops)
            say(f"actions: {env_id} done, {len(part.failures)} failures")
    part.cases = len(cases)
    if stops:
        part.notes.append(
            f"actions: {sum(refused.values())} refused ({', '.join(sorted(refused))}); the "
            f"motor read 0 at most {max(stops) * 1000:.1f} ms after each refusal was raised"
        )
    return part


def _actions_on(
    part: Part,
    env_id: str,
    cases: range,
    seed: int,
    log: Path,
    refused: dict[str, int],
    stops: list[float],
) -> None:
    env = gym.make(env_id, backend=f"emulator://{KIND[env_id]}?lockstep=1", log=log)
    device = env.unwrapped.sim  # type: ignore[attr-defined]
    emulator = device.backend.emulator
    spy, limit = CommandSpy(emulator), device.plant.command_limit
    counts_limit = emulator.firmware.hello.command_limit
    env.reset(seed=seed)
    returned = 1  # samples the log must hold: the reset's and every step's that returned
    for case in cases:
        rng = case_rng(seed, f"actions-{KIND[env_id]}", case)
        action: object
        if rng.random() < 0.5:
            what, action, must_refuse = "ordinary", np.array([rng.uniform(-2, 2) * limit]), False
        else:
            what, action, must_refuse = hostile_action(rng, limit)
        where = f"actions {KIND[env_id]} case {case} ({what})"
        try:
            _, _, terminated, truncated, _ = env.step(action)
        except Exception as exc:
            refused[what] = refused.get(what, 0) + 1
            if not isinstance(exc, ValueError):
                part.fail(f"{where}: raised {type(exc).__name__}, not ValueError: {exc}")
            held = emulator.motor
            took = motor_zero_within(emulator, STOP_WAIT)
            if took is None:
                part.fail(f"{where}: the motor held {held} for {STOP_WAIT} s after the error")
            else:
                stops.append(took)
            env.reset()
            returned += 1
            continue
        returned += 1
        if must_refuse:
            part.fail(f"{where}: the env accepted {action!r}")
        if terminated or truncated:
            env.reset()
            returned += 1
    env.close()
    beyond = [c for c in spy.commands if abs(c.command) > counts_limit]
    if beyond:
        part.fail(
            f"actions {KIND[env_id]}: the device received {len(beyond)} commands beyond "
            f"its limit, e.g. {beyond[0]}"
        )
    rows = len(read_steps(log)["step"])
    if rows != returned:
        part.fail(
            f"actions {KIND[env_id]}: the log holds {rows} rows, {returned} samples were returned"
        )


def fuzz_stock(cases: range, seed: int, say: Progress) -> Part:
    """Hostile commands through the stock Altino backend, to a fake car on a pty."""
    sys.path.insert(0, str(ROOT / "tests"))  # the fake stock car of the backend's tests
    from _altino_stock_device import FakeStockAltino  # type: ignore[import-not-found]

    from frictiongym.hardware.altino_frames import GO_LIMIT, STOP_REPEATS
    from frictiongym.hardware.altino_stock import AltinoStockBackend

    part = Part.named("stock altino")
    with FakeStockAltino(start_cm=60.0, rate_hz=50.0) as car:
        backend = AltinoStockBackend(car.port, rate_hz=50.0, timeout=0.3)
        try:
            backend.start()
            for case in cases:
                rng = case_rng(seed, "stock", case)
                backend.step(rng.uniform(-GO_LIMIT, 0.0))  # away from the wall: no guard
                what, command, must_refuse = hostile_action(rng, float(GO_LIMIT))
                if isinstance(command, np.ndarray) and command.size == 1:
                    command = command.flat[0]  # a backend takes one number, not an array
                sent = len(car.commands)
                try:
                    backend.step(command)  # type: ignore[arg-type]
                    if must_refuse:
                        part.fail(f"stock case {case} ({what}): accepted {command!r}")
                except Exception as exc:
                    if not isinstance(exc, ValueError):
                        part.fail(f"stock case {case} ({what}): {type(exc).__name__}: {exc}")
                    if not _stops_arrive(car, sent, STOP_REPEATS):
                        part.fail(
                            f"stock case {case} ({what}): no {STOP_REPEATS} stop frames "
                            f"after the error: {car.commands[sent:]}"
                        )
                    backend.start()
                progress(say, part, cases, case, "commands")
        finally:
            backend.close()
    beyond = [c for c in car.commands if max(abs(c.left), abs(c.right)) > GO_LIMIT]
    if beyond or car.bad_frames:
        part.fail(
            f"stock: the car received {len(beyond)} wheel values beyond {GO_LIMIT} and "
            f"{car.bad_frames} malformed frames"
        )
    part.cases = len(cases)
    part.notes.append(f"stock altino: the car received {len(car.commands)} frames")
    return part


def _stops_arrive(car: Any, after: int, count: int) -> bool:
    """Wait up to :data:`STOP_WAIT` for ``count`` stop frames after frame ``after``."""
    deadline = time.perf_counter() + STOP_WAIT
    while time.perf_counter() < deadline:
        new = car.commands[after:]
        if len(new) >= count:
            return all(c.stop and c.left == c.right == 0 for c in new[:count])
        time.sleep(0.002)
    return False
