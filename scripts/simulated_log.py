"""Write a log of time, command and measured position from the simulated servo, as a user's
controller would record one, for ``frictiongym identify --from-log`` (docs/identification.md).

The log holds constant commands of 1.1, 1.4, 2 and 3 times the break-away level in each
direction, 1.2 s each, each after 0.3 s of zero command (a start from rest), or with
``--no-rest`` back to back (the body reverses and never rests)::

    python scripts/simulated_log.py servo_log.csv --noise
    frictiongym identify --env frictiongym/RotaryServo-v1 --from-log servo_log.csv --out results/
"""

from __future__ import annotations

import argparse
import csv

import gymnasium as gym
import numpy as np

from frictiongym import devices

ENV_ID = "frictiongym/RotaryServo-v1"
MULTIPLES = (1.1, 1.4, 2.0, 3.0)
HOLD = 1.2  #: s
REST = 0.3  #: s


def main(argv: list[str] | None = None) -> int:
    """Write the log; return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="the CSV file to write")
    parser.add_argument("--noise", action="store_true", help="the encoder's noise on")
    parser.add_argument("--no-rest", action="store_true", help="no zero command between holds")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulator (default: 0)")
    args = parser.parse_args(argv)
    device = devices.get(ENV_ID)
    us = device.paper_friction.us_pos
    rest = 0.0 if args.no_rest else REST
    commands: list[float] = []
    for level in (sign * m * us for m in MULTIPLES for sign in (1.0, -1.0)):
        commands += [0.0] * round(rest / device.dt) + [level] * round(HOLD / device.dt)
    env = gym.make(ENV_ID, sensor_noise=args.noise, max_episode_steps=len(commands) + 1)
    obs, _ = env.reset(seed=args.seed)
    with open(args.out, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(("time", "command", "position"))
        for k, u in enumerate(commands):
            writer.writerow((f"{k * device.dt:.6f}", f"{u:.9g}", f"{float(obs[0]):.9g}"))
            obs, *_ = env.step(np.array([u], dtype=np.float32))
    print(f"wrote {args.out}: {len(commands)} samples, {len(commands) * device.dt:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
