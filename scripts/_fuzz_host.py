"""The host side of ``fuzz_hardware.py``: actions through a device env, link faults, model
files and params files.

Imported by ``fuzz_hardware.py`` as ``_fuzz_host``; not part of the package.
"""

from __future__ import annotations

import base64
import fractions
import json
import math
import pickle
import random
import sys
import tempfile
import time
import warnings
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from _fuzz_wire import Part, Progress, case_rng, progress

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym import params as fp
from frictiongym.hardware import protocol as p
from frictiongym.hardware.emulated import EmulatedBackend
from frictiongym.hardware.errors import (
    DeviceDisconnectedError,
    DeviceTimeoutError,
    HardwareError,
    WatchdogTripError,
)
from frictiongym.hardware.runlog import read_steps
from frictiongym.hardware.transport import Faults

ROOT = Path(__file__).resolve().parents[1]
SERVO, ALTINO = "frictiongym/RotaryServo-v0", "frictiongym/AltinoDistance-v0"
KIND = {SERVO: "rotary", ALTINO: "altino"}
#: Longest wait for the emulator to show a zeroed motor after an error, s.
STOP_WAIT = 1.0


def _motor_zero_within(emulator: Any, seconds: float) -> float | None:
    """Wait for the emulated motor to read 0; return how long it took (None: it did not)."""
    started = time.perf_counter()
    while time.perf_counter() - started < seconds:
        if emulator.motor == 0.0:
            return time.perf_counter() - started
        time.sleep(0.0005)
    return None


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
        self.commands: list[p.Command] = []
        firmware = emulator.firmware
        feed = firmware.feed

        def spied(data: bytes) -> list[p.Message]:
            messages = feed(data)
            self.commands += [m for m in messages if isinstance(m, p.Command)]
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
            took = _motor_zero_within(emulator, STOP_WAIT)
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
        part.fail(f"actions {KIND[env_id]}: the device received {len(beyond)} commands beyond "
                  f"its limit, e.g. {beyond[0]}")  # fmt: skip
    rows = len(read_steps(log)["step"])
    if rows != returned:
        part.fail(f"actions {KIND[env_id]}: the log holds {rows} rows, {returned} samples "
                  "were returned")  # fmt: skip


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
                        part.fail(f"stock case {case} ({what}): no {STOP_REPEATS} stop frames "
                                  f"after the error: {car.commands[sent:]}")  # fmt: skip
                    backend.start()
                progress(say, part, cases, case, "commands")
        finally:
            backend.close()
    beyond = [c for c in car.commands if max(abs(c.left), abs(c.right)) > GO_LIMIT]
    if beyond or car.bad_frames:
        part.fail(f"stock: the car received {len(beyond)} wheel values beyond {GO_LIMIT} and "
                  f"{car.bad_frames} malformed frames")  # fmt: skip
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
        "unplug": [], "freeze": [], "delay": [], "silence": [], "corrupt": [],
    }  # fmt: skip
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
                part.notes.append(f"faults: corrupt: {min(values):.1%}-{max(values):.1%} of "
                                  f"the frames damaged; {tally.checked} samples checked against "
                                  "the device's record")  # fmt: skip
                continue
            what = "motor 0 (device time)" if fault == "silence" else "error raised"
            part.notes.append(f"faults: {fault}: {what} {min(values) * 1000:.1f}-"
                              f"{max(values) * 1000:.1f} ms after it began")  # fmt: skip
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
        if _motor_zero_within(emulator, STOP_WAIT) is None:
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
    for row in zip(*(rows[k] for k in ("tick_us", "seq", "seq_applied", "status", "applied",
                                      "measured")), strict=True):  # fmt: skip
        tick = history.get(round(row[0] / period_us))
        if tick is None:
            part.fail(f"{where}: a sample of tick {row[0]} µs the device never sent")
            return faults.corrupt
        sent = (tick.tick & 0xFFFF, tick.seq_applied, int(tick.status),
                tick.applied / hello.command_scale,
                tick.sensor * (2.0 * math.pi / hello.counts_per_rev))  # fmt: skip
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
    if stopped is None or not stopped.status & p.Status.WATCHDOG:
        part.fail(f"{where}: the motor was not stopped by the watchdog in {watchdog_s + 0.2} s")
        return None
    took = (stopped.tick - last_tick) * dt
    if took > watchdog_s + 2 * dt:
        part.fail(f"{where}: the watchdog stopped the motor {took * 1000:.1f} ms after the "
                  f"last command (its time: {watchdog_s * 1000:.0f} ms)")  # fmt: skip
    try:
        env.step(np.array([2.0]))
    except WatchdogTripError:
        pass
    except Exception as exc:
        part.fail(f"{where}: after the trip a step raised {type(exc).__name__}: {exc}")
    else:
        part.fail(f"{where}: a step after the watchdog trip did not raise")
    return took


# --- model files --------------------------------------------------------------------------------

SHIPPED_MODEL = ROOT / "models" / "residual" / "rotary.zip"
#: Audit events that mean code ran or a pickle was read while a model loaded.
FORBIDDEN_EVENTS = ("pickle.find_class", "os.system", "subprocess.Popen", "os.exec",
                    "os.posix_spawn", "os.spawn", "os.fork")  # fmt: skip


class Touch:
    """A pickle that creates a file when unpickled: the stand-in for any code."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return (Path.touch, (self.marker,))


def _pickled(marker: Path) -> dict[str, str]:
    payload = base64.b64encode(pickle.dumps(Touch(marker))).decode()
    return {":type:": "<class 'object'>", ":serialized:": payload}


class AuditWatch:
    """Records forbidden audit events while :attr:`watching` (a hook cannot be removed)."""

    def __init__(self) -> None:
        self.watching = False
        self.seen: list[str] = []
        sys.addaudithook(self._hook)

    def _hook(self, event: str, args: tuple[Any, ...]) -> None:
        if self.watching and event in FORBIDDEN_EVENTS:
            self.seen.append(f"{event}{args!r:.80}")


def _hostile_zip(rng: random.Random, marker: Path, target: Path) -> str:
    """Write a copy of the shipped model made hostile in one or more ways; say how."""
    ways = rng.sample(["added entry", "SB3 entries", "policy_kwargs", "weights", "variables",
                       "torch pickle", "bytes", "json"], rng.randint(1, 3))  # fmt: skip
    with zipfile.ZipFile(SHIPPED_MODEL) as source:
        members = {name: source.read(name) for name in source.namelist()}
    data = json.loads(members["data"])
    if "added entry" in ways:
        data[f"evil{rng.randrange(100)}"] = _pickled(marker)
    if "SB3 entries" in ways:
        for key in rng.sample(["policy_class", "observation_space", "action_space",
                               "lr_schedule", "clip_range"], 2):  # fmt: skip
            data[key] = _pickled(marker)
    if "policy_kwargs" in ways:
        data["policy_kwargs"] = _pickled(marker)
    if "json" in ways:
        key = rng.choice(sorted(data))
        data[key] = rng.choice([None, 1e308, "x" * 1000, [[[]]], {"_shape": "[6]"}, -1])
    members["data"] = json.dumps(data).encode()
    if "weights" in ways:
        members["policy.pth"] = pickle.dumps(Touch(marker))
    if "variables" in ways:
        members["pytorch_variables.pth"] = pickle.dumps(Touch(marker))
    if "torch pickle" in ways:
        import torch

        buffer = target.with_suffix(".pth")
        torch.save({"weight": Touch(marker)}, buffer)
        members[rng.choice(["policy.pth", "pytorch_variables.pth"])] = buffer.read_bytes()
    with zipfile.ZipFile(target, "w") as out:
        for name, content in members.items():
            out.writestr(name, content)
    if "bytes" in ways:
        raw = bytearray(target.read_bytes())
        for _ in range(rng.randint(1, 8)):
            raw[rng.randrange(len(raw))] ^= 1 << rng.randrange(8)
        if rng.random() < 0.3:
            del raw[rng.randrange(len(raw)) :]
        target.write_bytes(bytes(raw))
    return "+".join(ways)


def fuzz_models(cases: range, seed: int, say: Progress) -> Part:
    """Hostile copies of the shipped model through ResidualController's loader."""
    from stable_baselines3 import PPO

    from frictiongym.controllers.policy_file import load_policy

    part = Part.named("model files")
    watch, outcomes = AuditWatch(), {"loaded": 0, "refused": 0}
    with tempfile.TemporaryDirectory(prefix="fuzz-models-") as folder:
        for case in cases:
            rng = case_rng(seed, "models", case)
            marker = Path(folder) / f"ran-{case}"
            target = Path(folder) / f"model-{case}.zip"
            ways = _hostile_zip(rng, marker, target)
            where = f"models case {case} ({ways})"
            watch.watching = True
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    load_policy(target, PPO, 6, 100.0)
                outcomes["loaded"] += 1
            except ValueError:
                outcomes["refused"] += 1
            except Exception as exc:
                part.fail(f"{where}: raised {type(exc).__name__}: {str(exc)[:120]}")
            finally:
                watch.watching = False
            if marker.exists():
                part.fail(f"{where}: the pickle ran")
            if watch.seen:
                part.fail(f"{where}: {watch.seen[0]}")
                watch.seen.clear()
            target.unlink()
            progress(say, part, cases, case, "files")
    part.cases = len(cases)
    part.notes.append(f"models: {outcomes['loaded']} loaded (pickles ignored), "
                      f"{outcomes['refused']} refused with ValueError")  # fmt: skip
    return part


# --- params files -------------------------------------------------------------------------------

PARAMS_FILES = [
    ROOT / "docs" / "identification" / d / "friction.json" for d in ("rotary", "altino")
]
ODD_VALUES: list[Callable[[random.Random], str]] = [
    lambda r: "NaN", lambda r: "Infinity", lambda r: "-Infinity", lambda r: "1e308",
    lambda r: "-1", lambda r: "0", lambda r: '"1.5"', lambda r: "null", lambda r: "true",
    lambda r: "[]", lambda r: "{}", lambda r: str(10**400), lambda r: "1e-320",
    lambda r: "[" * r.choice([10, 1000, 100_000]) + "]" * r.choice([0, 10]),
    lambda r: str(r.uniform(-1e7, 1e7)), lambda r: '"\\ud800"',
]  # fmt: skip


def _mutated_params(rng: random.Random, text: str) -> tuple[str, bytes]:
    how = rng.choice(["value", "value", "key dropped", "bytes", "truncated", "not utf-8",
                      "top level", "duplicate key"])  # fmt: skip
    data = json.loads(text)
    keys = [k for k in data if k not in ("units", "uncertainty", "metadata")]
    key = rng.choice(keys)
    if how == "value":
        new = json.dumps(data).replace(f'"{key}": {json.dumps(data[key])}',
                                       f'"{key}": {rng.choice(ODD_VALUES)(rng)}', 1)  # fmt: skip
        return f"{key} = odd value", new.encode()
    if how == "key dropped":
        del data[key]
        return f"{key} dropped", json.dumps(data).encode()
    if how == "duplicate key":
        return f"{key} twice", text.replace("{", f'{{"{key}": 1e9, ', 1).encode()
    if how == "top level":
        return how, rng.choice([b"[]", b"1", b'"x"', b"null", b""])
    raw = bytearray(text.encode())
    if how == "bytes":
        for _ in range(rng.randint(1, 6)):
            raw[rng.randrange(len(raw))] = rng.randrange(32, 127)
    elif how == "truncated":
        del raw[rng.randrange(len(raw)) :]
    else:
        raw[rng.randrange(len(raw))] = rng.choice([0x80, 0xC3, 0xFF])
    return how, bytes(raw)


def fuzz_params(cases: range, seed: int, say: Progress) -> Part:
    """Mutated friction.json files through load_params."""
    part = Part.named("params files")
    texts = [path.read_text() for path in PARAMS_FILES]
    loaded = 0
    with tempfile.TemporaryDirectory(prefix="fuzz-params-") as folder:
        target = Path(folder) / "friction.json"
        for case in cases:
            rng = case_rng(seed, "params", case)
            how, content = _mutated_params(rng, rng.choice(texts))
            target.write_bytes(content)
            loaded += _load_params(part, f"params case {case} ({how})", target)
            progress(say, part, cases, case, "files")
    part.cases = len(cases)
    part.notes.append(f"params: {loaded} of {len(cases)} mutated files loaded (all in range), the "
                      "rest refused with ParamsFileError")  # fmt: skip
    return part


def _load_params(part: Part, where: str, path: Path) -> bool:
    """Load ``path``; record any error but ParamsFileError; return whether it loaded."""
    try:
        params = fp.load_params(path)
    except fp.ParamsFileError:
        return False
    except Exception as exc:  # RecursionError and OverflowError among the findings
        part.fail(f"{where}: {type(exc).__name__}: {str(exc)[:100]}")
        return False
    _check_loaded(part, where, params)
    return True


def _check_loaded(part: Part, where: str, params: fp.DeviceParams) -> None:
    values = {"J": params.inertia, "B": params.damping}
    values.update({k: v for k, v in vars(params.friction).items() if isinstance(v, float)})
    for key, value in values.items():
        low, high = fp.PARAM_LIMITS.get(key, (-math.inf, math.inf))
        if not (math.isfinite(value) and (low <= value <= high or value == 0.0)):
            part.fail(f"{where}: loaded {key} = {value!r}, outside [{low:g}, {high:g}]")
