"""Write a log of time, command and measured position from a simulated device, as a user's
controller would record one, for ``frictiongym identify --from-log`` (docs/identification.md).

The servo's log (the default) holds constant commands of 1.1, 1.4, 2 and 3 times the
break-away level in each direction, 1.2 s each, each after 0.3 s of zero command (a start from
rest), or with ``--no-rest`` back to back (the body reverses and never rests)::

    python scripts/simulated_log.py servo_log.csv --noise
    frictiongym identify --env frictiongym/RotaryServo-v1 --from-log servo_log.csv --out results/

The Altino's (``--device altino``) is a relay controller's: from 12 cm, each level of 1.05 to
2.5 times break-away drives toward the wall until the IR distance reads 6 cm, then away until
it reads 16 cm, twice, with 0.5 s of zero command before each level (a start from rest). Its
position is the IR's distance estimate. Any other device (``--device FILE``) gets the servo's
holds; ``--levels`` and ``--hold`` change them, and a log that would leave the device's safety
limit is refused.
"""

from __future__ import annotations

import argparse
import csv

import numpy as np

from frictiongym import devices
from frictiongym.envs import make

MULTIPLES = (1.1, 1.4, 2.0, 3.0)
HOLD = 1.2  #: s
REST = 0.3  #: s
#: The IR device's relay: levels, band (cm from the wall), round trips per level, rest (s).
RELAY_MULTIPLES = (1.05, 1.2, 1.5, 2.0, 2.5)
RELAY_BAND = (6.0, 16.0)
RELAY_TRIPS = 2
RELAY_REST = 0.5
RELAY_START = 12.0


def main(argv: list[str] | None = None) -> int:
    """Write the log; return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="the CSV file to write")
    parser.add_argument("--device", default="rotary", help="rotary (default), altino or a file")
    parser.add_argument("--noise", action="store_true", help="the sensor's noise on")
    parser.add_argument("--no-rest", action="store_true", help="no zero command between holds")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulator (default: 0)")
    parser.add_argument(
        "--levels",
        type=lambda text: tuple(float(x) for x in text.split(",")),
        metavar="M,M,...",
        help="levels, multiples of break-away (default: the holds' "
        + ",".join(f"{m:g}" for m in MULTIPLES)
        + ", the IR device's relay "
        + ",".join(f"{m:g}" for m in RELAY_MULTIPLES)
        + ")",
    )
    parser.add_argument(
        "--hold", type=float, default=HOLD, metavar="S", help=f"each hold, s (default {HOLD:g})"
    )
    args = parser.parse_args(argv)
    device = devices.get(args.device)
    rows = _relay(device, args) if device.counts_per_rev == 0 else _holds(device, args)
    with open(args.out, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(("time", "command", "position"))
        for k, (u, y) in enumerate(rows):
            writer.writerow((f"{k * device.dt:.6f}", f"{u:.9g}", f"{y:.9g}"))
    print(f"wrote {args.out}: {len(rows)} samples, {len(rows) * device.dt:.1f} s")
    return 0


def _holds(device: devices.Device, args: argparse.Namespace) -> list[tuple[float, float]]:
    """Constant commands in both directions, each after a rest (an encoder device)."""
    us = device.paper_friction.us_pos
    rest = 0.0 if args.no_rest else REST
    commands: list[float] = []
    for level in (sign * m * us for m in args.levels or MULTIPLES for sign in (1.0, -1.0)):
        commands += [0.0] * round(rest / device.dt) + [level] * round(args.hold / device.dt)
    env = make(device, sensor_noise=args.noise, max_episode_steps=len(commands) + 1)
    obs, _ = env.reset(seed=args.seed)
    output = device.observation_names.index(device.output)
    rows = []
    for k, u in enumerate(commands):
        rows.append((u, float(obs[output])))
        obs, _, terminated, *_ = env.step(np.array([u], dtype=np.float32))
        if terminated:
            raise SystemExit(
                f"error: the log left {device.name}'s safety limit ±{device.limit:g} "
                f"{device.position_unit} at {k * device.dt:.2f} s: give lower --levels or a "
                "shorter --hold"
            )
    return rows


def _relay(device: devices.Device, args: argparse.Namespace) -> list[tuple[float, float]]:
    """A relay across the IR band at each level, after a rest (the Altino)."""
    near, far = RELAY_BAND
    env = make(device, sensor_noise=args.noise, max_episode_steps=10**6)
    obs, _ = env.reset(seed=args.seed, options={"position": RELAY_START})
    output = device.observation_names.index(device.output)
    rows = []

    def hold(u: float) -> None:
        nonlocal obs
        rows.append((u, float(obs[output])))
        obs, *_ = env.step(np.array([u], dtype=np.float32))

    toward = device.direction  # a positive command drives toward the wall: the distance falls
    for multiple in args.levels or RELAY_MULTIPLES:
        for _ in range(0 if args.no_rest else round(RELAY_REST / device.dt)):
            hold(0.0)
        for _ in range(RELAY_TRIPS):
            level = multiple * device.paper_friction.us_pos
            while not float(obs[output]) <= near:
                hold(-toward * level)
            level = multiple * device.paper_friction.us_neg
            while not float(obs[output]) >= far:
                hold(toward * level)
    return rows


if __name__ == "__main__":
    raise SystemExit(main())
