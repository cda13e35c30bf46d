"""Timing of the device path against the emulator, quiet and with a core busy; the decoder.

1. Loop: the paper's PID drives ``frictiongym emulate --device rotary`` (a separate process on
   a pseudo-terminal, paced by its own 500 Hz clock) through ``gym.make(..., backend=PORT)``
   for ``--seconds`` (default 10 s), as ``frictiongym sim2real`` does (its loop under
   ``realtime_priority``). Each case is run ``--rounds`` times, the cases interleaved:

   * ``quiet``: nothing else started by the script;
   * ``busy``: a third process spinning on one core (``while True: pass``) for the whole run;
   * ``busy-ordinary``: the same, with the host loop and the emulator's device thread left
     ordinary threads (``--no-realtime``), as on a system that does not permit ``SCHED_FIFO``;
   * ``busy-one-session``: as ``busy-ordinary``, but the spinning process is in this process's
     session, as if started from the same shell.

   The emulator, and the spinning process except in ``busy-one-session``, run in sessions of
   their own, as when started from other shells: Linux gives each session one share of the
   CPU (autogroup scheduling), so a process spinning in the loop's own session takes its
   time from the loop's share.

   We report the achieved rate, the period error |host period - 2 ms| p50/p99/max, late
   commands, device ticks the host missed ("skipped"), watchdog trips, the scheduling the
   host loop and the device thread got, and the emulator's own missed ticks.
2. Garbage collection: a full collection of a fresh process that imported what ``frictiongym
   sim2real`` imports, and of one that also imported torch and stable-baselines3 (as
   ``frictiongym train`` and a test run do), and the same after ``gc.freeze()``, as a device
   episode runs it.
3. Watchdog: what a dead host's last command does in the watchdog time: the model's disk
   from rest at the 10 V limit (simulated).
4. Decoder: ``FrameDecoder`` on a stream of State frames fed in 4 KiB reads, in frames per
   second, and as a ratio to a bare ``struct.unpack`` of the same payloads (no COBS, no CRC)
   in the same process.
5. With ``--example N``, instead of the above: the README's device example N times, with a
   process spinning on one core, each of the three in a session of its own as from three
   shells: ``frictiongym emulate --device rotary`` and ``frictiongym sim2real --env
   frictiongym/RotaryServo-v1 --backend serial://PORT --out DIR`` (five runs of 2500 steps).
   An example passes when it exits 0 with all five runs complete. ``--no-priority`` runs both
   commands without the right to real-time priority (as root: under ``setpriv`` without
   ``CAP_SYS_NICE``), as an ordinary user would.

Usage: python scripts/bench_hardware.py [--seconds 10] [--rounds 1] [--cases quiet,busy]
       [--frames 50000]
       python scripts/bench_hardware.py --example 10 [--no-priority]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator

import gymnasium as gym
import numpy as np

import frictiongym  # noqa: F401
from frictiongym.controllers import PID, PIDGains
from frictiongym.hardware import WatchdogTripError, protocol
from frictiongym.hardware.firmware import default_watchdog_ms
from frictiongym.hardware.realtime import realtime_priority
from frictiongym.plants.presets import ROTARY_DT, ROTARY_PAPER_GAINS, ROTARY_PLANT

#: case -> (a core busy: "" no, "own" in a session of its own, "shared" in this one;
#: real-time priority asked for)
CASES = {
    "quiet": ("", True),
    "busy": ("own", True),
    "busy-ordinary": ("own", False),
    "busy-one-session": ("shared", False),
}


@contextlib.contextmanager
def busy_core(session: str) -> Iterator[None]:
    """Keep one core busy with a spinning process for the block (``session``: see CASES)."""
    spinner = None
    if session:
        spinner = subprocess.Popen(
            [sys.executable, "-c", "while True: pass"], start_new_session=session == "own"
        )
    try:
        yield
    finally:
        if spinner is not None:
            spinner.kill()
            spinner.wait()


@contextlib.contextmanager
def maybe_priority(realtime: bool) -> Iterator[str]:
    """``realtime_priority()`` if ``realtime``, else an ordinary thread."""
    if realtime:
        with realtime_priority() as got:
            yield got
    else:
        yield "ordinary, SCHED_FIFO not asked for"


def loop_timing(seconds: float, busy: str, realtime: bool) -> dict[str, object]:
    """Run the PID against the emulator in another process for ``seconds``; time the loop."""
    command = [sys.executable, "-m", "frictiongym.cli", "emulate", "--device", "rotary"]
    with busy_core(busy), tempfile.TemporaryFile("w+") as status:
        emulator = subprocess.Popen(
            command + ([] if realtime else ["--no-realtime"]),
            stdout=subprocess.PIPE,
            stderr=status,
            text=True,
            start_new_session=True,
        )
        trips = 0
        try:
            assert emulator.stdout is not None
            port = emulator.stdout.readline().strip()
            env = gym.make(
                "frictiongym/RotaryServo-v1",
                backend=port,
                log=False,
                max_episode_steps=-1,
                reference="step_sequence",
            )
            pid = PID.for_env(env, PIDGains(**ROTARY_PAPER_GAINS))
            steps = round(seconds / env.unwrapped.dt)
            with maybe_priority(realtime) as host:
                obs, _ = env.reset(seed=0)
                for _ in range(steps):
                    try:
                        obs, *_ = env.step(pid(obs))
                    except WatchdogTripError:  # counted; the reset re-arms the device
                        trips += 1
                        obs, _ = env.reset()
            timing = env.unwrapped.sim.timing()
            env.close()
        finally:
            emulator.send_signal(signal.SIGINT)
            emulator.wait(timeout=10)
        status.seek(0)
        lines = status.read().splitlines()
    device = next((line for line in lines if line.startswith("# device thread:")), "?")
    last = next((line for line in reversed(lines) if line.startswith("ticks")), "")
    missed = last.split("(missed ")[1].split(")")[0] if "(missed " in last else "?"
    return {
        "steps": timing.steps,
        "duration_s": timing.duration,
        "rate_hz": timing.rate_hz,
        "p50_ms": 1e3 * timing.period_p50,
        "p99_ms": 1e3 * timing.period_p99,
        "max_ms": 1e3 * timing.period_max,
        "late": timing.late,
        "skipped": timing.skipped,
        "trips": trips,
        "host": host,
        "device": device.split(": ", 1)[-1],
        "emulator_missed": missed,
    }


#: Timing of a full collection, run in a fresh process after importing ``{imports}``.
COLLECTION_CODE = """
import gc, json, time
import {imports}
objects = len(gc.get_objects())
best_full = best_frozen = float("inf")
for _ in range(3):
    start = time.perf_counter()
    gc.collect()
    best_full = min(best_full, time.perf_counter() - start)
    gc.freeze()
    start = time.perf_counter()
    gc.collect()
    best_frozen = min(best_frozen, time.perf_counter() - start)
    gc.unfreeze()
print(json.dumps({{"objects": objects, "full_ms": 1e3 * best_full,
                  "frozen_ms": 1e3 * best_frozen}}))
"""
#: What the measured processes have imported: a device run's, and a training run's.
COLLECTION_IMPORTS = {
    "frictiongym sim2real": "frictiongym.sim2real, frictiongym.hardware.serial_backend, "
    "matplotlib.pyplot",
    "with torch and stable-baselines3": "frictiongym.sim2real, matplotlib.pyplot, torch, "
    "stable_baselines3, frictiongym.residual",
}


#: Runs a command without the right to raise its priority (root keeps CAP_SYS_NICE otherwise).
NO_PRIORITY = ["setpriv", "--bounding-set", "-sys_nice", "--inh-caps", "-sys_nice"]


def example(runs: int, priority: bool) -> None:
    """Run the README's two-shell device example ``runs`` times with a core busy (module doc)."""
    prefix = [] if priority or os.geteuid() != 0 else NO_PRIORITY
    cli = [*prefix, sys.executable, "-m", "frictiongym.cli"]
    passed = 0
    with busy_core("own"), tempfile.TemporaryDirectory() as scratch:
        for k in range(1, runs + 1):
            out = os.path.join(scratch, f"s2r-{k}")
            emulator = subprocess.Popen(
                [*cli, "emulate", "--device", "rotary", "--quiet"],
                stdout=subprocess.PIPE,
                text=True,
                start_new_session=True,
            )
            try:
                assert emulator.stdout is not None
                port = emulator.stdout.readline().strip()
                done = subprocess.run(
                    [
                        *cli,
                        "sim2real",
                        "--env",
                        "frictiongym/RotaryServo-v1",
                        "--backend",
                        f"serial://{port}",
                        "--out",
                        out,
                    ],
                    capture_output=True,
                    text=True,
                    start_new_session=True,
                )
            finally:
                emulator.send_signal(signal.SIGTERM)
                emulator.wait(timeout=10)
            try:
                with open(os.path.join(out, "sim2real.json")) as handle:
                    data = json.load(handle)
            except OSError:
                print(f"example {k}: exit {done.returncode}, no report: {done.stderr.strip()}")
                continue
            t = data["timing"]
            ok = done.returncode == 0 and data["complete_runs"] == data["repeats"]
            passed += ok
            print(
                f"example {k}: exit {done.returncode}, {data['complete_runs']} of "
                f"{data['repeats']} runs complete ({', '.join(r['ended'] for r in data['runs'])})"
                f"; {t['rate_hz']:.1f} Hz, |period - 2 ms| p99 {1e3 * t['period_p99']:.3f} ms, "
                f"max {1e3 * t['period_max']:.2f} ms, skipped device ticks {t['skipped']} of "
                f"{t['steps']}; host loop: {data['priority']}",
                flush=True,
            )
    print(f"examples with every run complete: {passed} of {runs}")


def collection_times(imports: str) -> dict[str, float]:
    """Time a full garbage collection of a fresh process that imported ``imports``, as it is
    and with its objects frozen (best of three)."""
    code = COLLECTION_CODE.format(imports=imports)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    result: dict[str, float] = json.loads(out.stdout)
    return result


def dead_host(watchdog_s: float) -> tuple[float, float]:
    """Angle (rad) and speed (rad/s) of the model's disk after ``watchdog_s`` at 10 V from rest."""
    from frictiongym.friction import ROTARY_PAPER
    from frictiongym.plants import Plant

    plant = Plant(ROTARY_PLANT, ROTARY_PAPER, dt=ROTARY_DT, num_plants=1)
    for _ in range(round(watchdog_s / ROTARY_DT)):
        plant.step(ROTARY_PLANT.command_limit)
    return float(plant.position[0]), float(plant.velocity[0])


def decoder_throughput(frames: int) -> dict[str, float]:
    rng = np.random.default_rng(0)
    states = [
        protocol.State(
            protocol.Status(0),
            k & 0xFFFF,
            (2000 * k) & 0xFFFFFFFF,
            k & 0xFFFF,
            int(rng.integers(-10000, 10000)),
            int(rng.integers(-(2**23), 2**23)),
            0,
        )
        for k in range(frames)
    ]
    stream = b"".join(protocol.encode(s) for s in states)
    chunks = [stream[i : i + 4096] for i in range(0, len(stream), 4096)]
    payloads = [protocol.pack(s) for s in states]
    fmt = protocol.State.FORMAT

    best_decode = best_unpack = float("inf")
    for _ in range(3):
        decoder = protocol.FrameDecoder()
        start = time.perf_counter()
        for chunk in chunks:
            decoder.feed(chunk)
        best_decode = min(best_decode, time.perf_counter() - start)
        if decoder.frames != frames or decoder.errors:
            raise RuntimeError(f"decoded {decoder.frames} of {frames}, {decoder.errors} errors")
        start = time.perf_counter()
        for payload in payloads:
            struct.unpack(fmt, payload)
        best_unpack = min(best_unpack, time.perf_counter() - start)
    return {
        "frames": frames,
        "bytes_per_frame": len(stream) / frames,
        "decode_per_s": frames / best_decode,
        "unpack_per_s": frames / best_unpack,
        "cost_vs_unpack": best_decode / best_unpack,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument(
        "--cases", default=",".join(CASES), help=f"comma-separated, of {list(CASES)}"
    )
    parser.add_argument("--frames", type=int, default=50_000)
    parser.add_argument("--example", type=int, metavar="N", help="the README example N times")
    parser.add_argument(
        "--no-priority",
        dest="priority",
        action="store_false",
        help="with --example: without the right to real-time priority",
    )
    args = parser.parse_args()
    if args.example:
        print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores, load {os.getloadavg()}")
        example(args.example, args.priority)
        return
    cases = [case.strip() for case in args.cases.split(",")]
    unknown = [case for case in cases if case not in CASES]
    if unknown:
        parser.error(f"unknown case(s) {unknown}; choose from {list(CASES)}")
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores, load {os.getloadavg()}")
    d = decoder_throughput(args.frames)
    print(
        f"decoder: {d['decode_per_s']:,.0f} State frames/s ({d['bytes_per_frame']:.0f} B each, "
        f"fed in 4 KiB reads); bare struct.unpack of the payloads: {d['unpack_per_s']:,.0f}/s; "
        f"decoding costs {d['cost_vs_unpack']:.1f}x the unpack"
    )
    for name, imports in COLLECTION_IMPORTS.items():
        try:
            g = collection_times(imports)
        except subprocess.CalledProcessError as exc:
            print(f"garbage collection [{name}]: not measured ({exc.stderr.splitlines()[-1]})")
            continue
        print(
            f"garbage collection [{name}]: a full collection of {g['objects']:,} objects takes "
            f"{g['full_ms']:.1f} ms, {g['frozen_ms']:.2f} ms with them frozen"
        )
    watchdog = default_watchdog_ms(ROTARY_DT) / 1000.0
    angle, speed = dead_host(watchdog)
    print(
        f"watchdog: {1e3 * watchdog:.0f} ms; a dead host's last command at the 10 V limit "
        f"turns the model's disk {angle:.2f} rad from rest in that time, to {speed:.0f} rad/s"
    )
    for r in range(args.rounds):
        for case in cases:
            busy, realtime = CASES[case]
            t = loop_timing(args.seconds, busy, realtime)
            print(
                f"loop [{case}] round {r + 1}: {t['steps']} steps in {t['duration_s']:.3f} s = "
                f"{t['rate_hz']:.2f} Hz (target 500 Hz); |period - 2 ms| p50 "
                f"{t['p50_ms']:.3f} ms, p99 {t['p99_ms']:.3f} ms, max {t['max_ms']:.3f} ms; "
                f"late commands {t['late']}, skipped device ticks {t['skipped']}, watchdog "
                f"trips {t['trips']}; host loop: {t['host']}; device thread: {t['device']}; "
                f"emulator missed {t['emulator_missed']} ticks",
                flush=True,
            )


if __name__ == "__main__":
    main()
