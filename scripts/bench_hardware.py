"""Timing of the device path against the emulator, and the protocol decoder's throughput.

1. Loop: the paper's PID drives ``frictiongym emulate --device rotary`` (a separate process on
   a pseudo-terminal, paced by its own 500 Hz clock) through ``gym.make(..., backend=PORT)``
   for ``--seconds`` (default 10 s); we report the achieved rate, the period error
   |host period - 2 ms| p50/p99/max, late commands and skipped device ticks.
2. Decoder: ``FrameDecoder`` on a stream of State frames fed in 4 KiB reads, in frames per
   second, and as a ratio to a bare ``struct.unpack`` of the same payloads (no COBS, no CRC)
   in the same process.

Usage: python scripts/bench_hardware.py [--seconds 10] [--frames 50000]
"""

from __future__ import annotations

import argparse
import os
import signal
import struct
import subprocess
import sys
import time

import gymnasium as gym
import numpy as np

import frictiongym  # noqa: F401
from frictiongym.controllers import PID, PIDGains
from frictiongym.hardware import protocol as p
from frictiongym.plants.presets import ROTARY_PAPER_GAINS


def loop_timing(seconds: float) -> dict[str, float]:
    emulator = subprocess.Popen(
        [sys.executable, "-m", "frictiongym.cli", "emulate", "--device", "rotary", "--quiet"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert emulator.stdout is not None
        port = emulator.stdout.readline().strip()
        env = gym.make(
            "frictiongym/RotaryServo-v0", backend=port, log=False, max_episode_steps=-1,
            reference="step_sequence",
        )  # fmt: skip
        pid = PID.for_env(env, PIDGains(**ROTARY_PAPER_GAINS))
        obs, _ = env.reset(seed=0)
        steps = round(seconds / env.unwrapped.dt)
        for _ in range(steps):
            obs, *_ = env.step(pid(obs))
        timing = env.unwrapped.sim.timing()
        env.close()
    finally:
        emulator.send_signal(signal.SIGINT)
        emulator.wait(timeout=10)
    return {
        "steps": timing.steps,
        "duration_s": timing.duration,
        "rate_hz": timing.rate_hz,
        "p50_ms": 1e3 * timing.period_p50,
        "p99_ms": 1e3 * timing.period_p99,
        "max_ms": 1e3 * timing.period_max,
        "late": timing.late,
        "skipped": timing.skipped,
    }


def decoder_throughput(frames: int) -> dict[str, float]:
    rng = np.random.default_rng(0)
    states = [
        p.State(p.Status(0), k & 0xFFFF, (2000 * k) & 0xFFFFFFFF, k & 0xFFFF,
                int(rng.integers(-10000, 10000)), int(rng.integers(-(2**23), 2**23)), 0)
        for k in range(frames)
    ]  # fmt: skip
    stream = b"".join(p.encode(s) for s in states)
    chunks = [stream[i : i + 4096] for i in range(0, len(stream), 4096)]
    payloads = [p.pack(s) for s in states]
    fmt = p.State.FORMAT

    best_decode = best_unpack = float("inf")
    for _ in range(3):
        decoder = p.FrameDecoder()
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
    parser.add_argument("--frames", type=int, default=50_000)
    args = parser.parse_args()
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores")
    d = decoder_throughput(args.frames)
    print(
        f"decoder: {d['decode_per_s']:,.0f} State frames/s ({d['bytes_per_frame']:.0f} B each, "
        f"fed in 4 KiB reads); bare struct.unpack of the payloads: {d['unpack_per_s']:,.0f}/s; "
        f"decoding costs {d['cost_vs_unpack']:.1f}x the unpack"
    )
    t = loop_timing(args.seconds)
    print(
        f"loop: {t['steps']} steps in {t['duration_s']:.3f} s = {t['rate_hz']:.2f} Hz "
        f"(target 500 Hz); |period - 2 ms| p50 {t['p50_ms']:.3f} ms, p99 {t['p99_ms']:.3f} ms, "
        f"max {t['max_ms']:.3f} ms; late commands {t['late']}, skipped device ticks "
        f"{t['skipped']}"
    )


if __name__ == "__main__":
    main()
