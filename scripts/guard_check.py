"""How close the Altino's distance guard lets the emulated car come to the wall.

Drives the lock-step emulator (the firmware's rules around the env's own plant) from rest at
several starts with constant commands until the guard ends the episode, then keeps e-stopping
until the car is at rest, and prints the closest true distance to the wall. Then runs the
paper's gains for 400 steps and prints their closest predicted stop (they must not trip it).
``scripts/guard_scan.py`` is the full scan: every plausible car, friction law and start.

Usage: python scripts/guard_check.py
"""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

import frictiongym  # noqa: F401
from frictiongym.controllers import PID, FrictionCompensator, PIDGains
from frictiongym.hardware import guard
from frictiongym.hardware.protocol import Status
from frictiongym.plants.presets import (
    ALTINO_PAPER_GAINS_COMPENSATED,
    ALTINO_PAPER_GAINS_KI10,
    ALTINO_PAPER_GAINS_KI20,
)

ALTINO = "frictiongym/AltinoDistance-v1"
STARTS = (2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 15.0, 30.0)
COMMANDS = (300.0, 600.0, 1000.0)


def closest(start: float, command: float) -> float:
    env = gym.make(ALTINO, backend="emulator://altino?lockstep=1", log=False)
    emulator = env.unwrapped.sim.backend.emulator
    env.reset(seed=0, options={"position": start})
    for _ in range(400):
        if env.step(np.array([command]))[2]:
            break
    backend, ticks = env.unwrapped.sim.backend, emulator.stats().ticks
    for _ in range(20):  # each e-stop is one more period of device time in lock-step
        backend.stop()
    deadline = time.monotonic() + 5.0
    while emulator.stats().ticks < ticks + 40 and time.monotonic() < deadline:
        time.sleep(0.002)
    nearest = min(tick.position for tick in emulator.history)
    env.close()
    return nearest


def paper_gains() -> None:
    cases = [
        ("PID Kp=25 Ki=10 Kd=12", ALTINO_PAPER_GAINS_KI10, False),
        ("PID Kp=25 Ki=20 Kd=12", ALTINO_PAPER_GAINS_KI20, False),
        ("compensated Kp=25 Ki=0.5 Kd=7", ALTINO_PAPER_GAINS_COMPENSATED, True),
    ]
    for name, gains, compensated in cases:
        env = gym.make(ALTINO, backend="emulator://altino?lockstep=1", log=False)
        pid = PID.for_env(env, PIDGains(**gains))
        controller = FrictionCompensator(pid) if compensated else pid
        obs, _ = env.reset(seed=0)
        watch = guard.DistanceGuard(env.unwrapped.dt)
        lowest, tripped, held = np.inf, False, 0.0
        for _ in range(400):
            action = controller(obs)
            watch.update(float(obs[0]), held)
            if obs[0] > 0:
                lowest = min(lowest, watch.predicted_stop(float(action[0])))
            obs, _, terminated, _, _ = env.step(action)
            held = float(np.clip(action[0], -1000.0, 1000.0))
            tripped |= bool(env.unwrapped.sim.last_sample.status & Status.LIMIT)
            if terminated:
                break
        env.close()
        print(f"{name}: closest predicted stop {lowest:.2f} cm, guard tripped: {tripped}")


def main() -> None:
    print("closest true distance to the wall, cm (start x constant command, from rest)")
    print("| command | " + " | ".join(f"{s:g} cm" for s in STARTS) + " |")
    print("|---|" + "---:|" * len(STARTS))
    for command in COMMANDS:
        row = [f"{closest(s, command):.2f}" for s in STARTS]
        print(f"| +{command:g} | " + " | ".join(row) + " |")
    paper_gains()


if __name__ == "__main__":
    main()
