"""``frictiongym emulate``: run a device emulator on a pseudo-terminal or a TCP port."""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time
from dataclasses import replace
from types import FrameType
from typing import Any

from frictiongym import devices
from frictiongym._validation import check_seed
from frictiongym.hardware import protocol
from frictiongym.hardware.base import KINDS
from frictiongym.hardware.emulator import Emulator, Faults

DESCRIPTION = """\
Emulate a device: run the simulated plant (with its own "true" parameters, which may differ
from the nominal model the envs use) behind our firmware's wire protocol, at the device's
rate (rotary: QUBE-Servo 2, 500 Hz; altino: Altino car, 20 Hz), on a pseudo-terminal or, with
--tcp, on a TCP port for another process or machine. It behaves as the firmware does: boots
with the motor disabled, answers Hello, holds each command over its period, streams one state
frame per tick, zeroes the motor when commands stop for --watchdog ms (latched until re-armed)
and, on the Altino, runs the distance guard: when the car, at the speed the IR readings show
(or the fastest it can be, before two readings in range), could no longer stop 1.5 cm short
of the wall, it brakes at full reverse while the car approaches (even after an e-stop or a
watchdog trip), then refuses forward commands (latched until re-armed; backing away still
works). The guard assumes the worst car it cannot measure: any mass in --guard-mass and the
least friction of the true law (--friction none: none at all, so it refuses fast driving out
of the IR range).

The first line of output is the port to connect to. Connect an env to it:
  gym.make("frictiongym/RotaryServo-v1", backend="serial:///dev/pts/7")
  gym.make("frictiongym/AltinoDistance-v1", backend="socket://127.0.0.1:5000")
(backend URIs: serial://PATH?baud=N, socket://HOST:PORT; a pty ignores the baud rate).
A device from its description file (--device my_stage.toml, docs/devices.md) is connected to
through the env of the same file:
  gym.make("frictiongym/Axis-v0", device="my_stage.toml", backend="serial:///dev/pts/7")
One host at a time, as on a device: a second one that connects to --tcp is disconnected at
once (it then says so instead of timing out), and a pty is opened exclusively.
Unless --quiet, one status line per second goes to stderr. Stop with Ctrl-C, SIGTERM or
--duration.

Fault injection, on what the device sends: --drop P drops each byte with probability P,
--corrupt P flips one bit of a frame with probability P, --delay S and --jitter S hold each
frame S s (plus uniform 0..S) before writing it, --unplug-after S closes the link and
--freeze-after S stops sending after S s of device time (the device keeps running and its
watchdog zeroes the motor). --lockstep ticks once per command received instead of in real
time (exact, for tests).

The device thread runs under SCHED_FIFO where the system permits it (root, CAP_SYS_NICE or an
rtprio limit), so that other busy processes do not make it late; the second status line says
what it got, and --no-realtime keeps it an ordinary thread.
"""


def _endpoint(text: str) -> tuple[str, int]:
    """Parse ``[HOST:]PORT`` (host defaults to 127.0.0.1)."""
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--tcp takes [HOST:]PORT, e.g. 5000 or 0.0.0.0:5000; got {text!r}"
        ) from None
    if not 0 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"port {number} is not in 0..65535 (0: any free port)")
    return host or "127.0.0.1", number


def _mass_range(text: str) -> tuple[float, float]:
    """Parse ``MIN:MAX`` (units·s²/cm) for --guard-mass."""
    low, _, high = text.partition(":")
    try:
        pair = (float(low), float(high))
    except ValueError:
        pair = (math.nan, math.nan)
    if not (all(math.isfinite(m) and m > 0 for m in pair) and pair[0] <= pair[1]):
        raise argparse.ArgumentTypeError(
            f"--guard-mass takes MIN:MAX, two positive masses in units·s²/cm with MIN <= MAX, "
            f"e.g. 1.1:5.5; got {text!r}"
        )
    return pair


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the command's options to ``parser``."""
    parser.add_argument(
        "--device",
        required=True,
        metavar="KIND|FILE",
        help=f"the device to emulate: {', '.join(KINDS)} or a device description file",
    )
    parser.add_argument(
        "--tcp",
        type=_endpoint,
        metavar="[HOST:]PORT",
        help="serve on TCP (host default 127.0.0.1; port 0: any free one) instead of a pty",
    )
    parser.add_argument(
        "--params",
        metavar="FILE",
        help="the plant's true parameters: a friction.json (frictiongym identify) of this device",
    )
    parser.add_argument(
        "--friction",
        default="paper",
        metavar="LAW",
        help="true friction law: paper (default), none, coulomb, stribeck or lugre",
    )
    parser.add_argument(
        "--guard-mass",
        type=_mass_range,
        metavar="MIN:MAX",
        help="Altino: the mass range the distance guard assumes, units·s²/cm (default 1.1:5.5, "
        "widened to the plant's own; its least friction is that of the true law)",
    )
    parser.add_argument("--noise", action="store_true", help="add the env's default sensor noise")
    parser.add_argument(
        "--lockstep", action="store_true", help="one tick per command received (exact timing)"
    )
    parser.add_argument(
        "--watchdog",
        type=int,
        metavar="MS",
        help="watchdog time in ms (default: max(3 periods, 100 ms); 0 turns it off)",
    )
    parser.add_argument(
        "--drop", type=float, default=0.0, metavar="P", help="byte drop probability"
    )
    parser.add_argument(
        "--corrupt", type=float, default=0.0, metavar="P", help="frame bit-flip probability"
    )
    parser.add_argument("--delay", type=float, default=0.0, metavar="S", help="frame latency, s")
    parser.add_argument(
        "--jitter", type=float, default=0.0, metavar="S", help="extra random latency, 0..S s"
    )
    parser.add_argument(
        "--unplug-after", type=float, metavar="S", help="close the link after S s of device time"
    )
    parser.add_argument(
        "--freeze-after", type=float, metavar="S", help="stop sending after S s of device time"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of noise and faults (default 0)")
    parser.add_argument(
        "--no-realtime",
        dest="realtime",
        action="store_false",
        help="keep the device thread an ordinary one (default: SCHED_FIFO where permitted)",
    )
    parser.add_argument(
        "--duration",
        dest="run_for",
        type=float,
        metavar="S",
        help="stop after S s of wall time (default: run until Ctrl-C or SIGTERM)",
    )
    parser.add_argument("--quiet", action="store_true", help="no status lines on stderr")


def _status_line(emu: Any) -> str:
    s = emu.stats(timing=False)  # no percentiles: the device thread must not wait
    bits = "|".join(bit.name or "" for bit in protocol.Status if emu.status & bit) or "OK"
    return (
        f"ticks {s.ticks} (missed {s.missed})  commands {s.commands}  crc errors "
        f"{s.crc_errors}  late {s.late}  motor {emu.motor:+.3f}  status {bits}  "
        f"tick {s.tick_time_mean * 1e6:.0f} us"
    )


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run the command; return the exit status."""
    if args.run_for is not None and not (math.isfinite(args.run_for) and args.run_for > 0):
        print(
            f"error: --duration must be a positive number of seconds, got {args.run_for}",
            file=sys.stderr,
        )
        return 2
    try:
        check_seed(args.seed)
        faults = Faults(
            drop=args.drop,
            corrupt=args.corrupt,
            delay=args.delay,
            jitter=args.jitter,
            unplug_after=args.unplug_after,
            freeze_after=args.freeze_after,
        )
        emu = Emulator(
            devices.get(args.device).kind,  # a file is read here (an error names the field)
            params=args.params,
            friction=args.friction,
            sensor_noise=bool(args.noise),
            lockstep=args.lockstep,
            faults=faults,
            watchdog_ms=args.watchdog,
            seed=args.seed,
            realtime=args.realtime,
        )
        if args.guard_mass is not None and emu.firmware.guard is not None:
            low, high = args.guard_mass
            emu.set_car_bounds(replace(emu.firmware.car_bounds, mass_min=low, mass_max=high))
    except (ValueError, TypeError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            url = emu.serve_tcp(*args.tcp) if args.tcp else emu.serve_pty()
        except OSError as exc:
            print(f"error: could not open the link: {exc}", file=sys.stderr)
            return 2
        print(url, flush=True)
        if not args.quiet:
            print(f"# {command_line}", file=sys.stderr, flush=True)
            print(f"# device thread: {emu.priority}", file=sys.stderr, flush=True)
        end = math.inf if args.run_for is None else time.monotonic() + args.run_for
        while not stop.is_set() and emu.running:
            stop.wait(max(0.0, min(1.0, end - time.monotonic())))
            if time.monotonic() >= end:
                break
            if not args.quiet:
                print(_status_line(emu), file=sys.stderr, flush=True)
        if emu.error is not None:
            print(f"error: the emulator stopped: {emu.error!r}", file=sys.stderr)
            return 1
        return 0
    finally:
        emu.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


__all__ = ["DESCRIPTION", "add_arguments", "run"]
