"""``frictiongym sim2real``: one controller on a device and in simulation, and the gap."""

from __future__ import annotations

import argparse
import sys
from datetime import datetime, timezone
from pathlib import Path

from frictiongym import devices
from frictiongym._io import OutputDir, add_output_arguments
from frictiongym.controllers import PIDGains
from frictiongym.hardware import SIM
from frictiongym.hardware.errors import HardwareError
from frictiongym.params import ParamsFileError
from frictiongym.sim2real.report import runs_text, stops, summary, write_report
from frictiongym.sim2real.run import CONTROLLERS, run_sim2real

DESCRIPTION = """\
Run the same controller and reference on a device (repeated, to measure the device's own
spread) and on simulated models of it: the nominal plant without friction, the nominal
plant with the paper's friction and, with --params, an identified friction.json.
Then compare what the controller saw (measured output, estimated velocity, applied command):
RMSE and NRMSE fit per signal, differences of rise time, settling time, overshoot and
steady-state error, and the timing of the device loop. The paper's claim is that friction
modelling closes most of the gap; the report says how much.

A device run can end early: the device's watchdog stops the motor when the host loop stalls
for longer than its watchdog time (100 ms on the servo), the link when no state frame comes in
time (or one too old), and the env's safety limit ends a run that goes beyond it. Such a run
is listed in the report with how and when it ended, left out of the comparison, and the other
runs go on (a device that goes away ends the runs); with no complete run the command exits 1.
A --reference beyond the safety limit, or on the Altino beyond its IR sensor's range, is
refused before the device moves. The device runs take real-time priority (SCHED_FIFO) where
the system permits it; the report says what they got.

Writes to --out: report.md, sim2real.json, overlay.png, timing.png; the device run's log
(steps.csv + meta.json) goes to a new --out/device-logs/<UTC time>/, so a rerun into the
same --out keeps the earlier logs. An --out holding an earlier report is refused unless
--overwrite replaces it (the report and its figures; the device logs stay); an error or a
Ctrl-C leaves the report as it was (the device log of the interrupted run stays).

Try it without hardware:  frictiongym sim2real --env frictiongym/RotaryServo-v1 \\
    --backend emulator://rotary --out sim2real-results
(the emulator's plant has the paper's friction, so the friction model should close almost
all of the gap; give the emulator other parameters with emulator://rotary?params=FILE).
"""


def _gains(text: str) -> PIDGains:
    try:
        kp, ki, kd = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--gains takes KP,KI,KD (three numbers), got {text!r}"
        ) from None
    return PIDGains(kp, ki, kd)


#: What a run may write into --out besides its device log (device-logs/ is never replaced).
OUTPUTS = ("report.md", "sim2real.json", "overlay.png", "timing.png")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the command's options to ``parser``."""
    parser.add_argument(
        "--env",
        "--device",
        dest="env",
        required=True,
        metavar="ID|FILE",
        help=", ".join(d.env_id for d in devices.DEVICES) + " or a device description file",
    )
    parser.add_argument(
        "--backend",
        required=True,
        metavar="URI",
        help="the device: serial:///dev/ttyACM0?baud=1000000, socket://HOST:PORT, "
        "altino-stock:///dev/rfcomm0, quanser-hil://qube_servo2_usb/0, or "
        f"emulator://{'|'.join(d.kind for d in devices.DEVICES)} (an emulator in this process)",
    )
    parser.add_argument(
        "--controller",
        choices=CONTROLLERS,
        default="pid",
        help="the paper's PID (default) or PID + friction compensator",
    )
    parser.add_argument(
        "--gains",
        type=_gains,
        metavar="KP,KI,KD",
        help="PID gains (default: the paper's for this device and controller)",
    )
    parser.add_argument(
        "--params",
        metavar="FILE",
        help="an identified friction.json: the compensator's model and the "
        "'identified' simulated model",
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=5,
        metavar="N",
        help="device runs (default 5; their spread is the noise floor)",
    )
    parser.add_argument(
        "--steps", type=int, metavar="N", help="steps per run (default: the env's episode length)"
    )
    parser.add_argument(
        "--reference",
        type=float,
        metavar="VALUE",
        help="step target, in the device's position unit (default: the env's step)",
    )
    add_output_arguments(parser, "sim2real-results", "the report and the device logs")
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    parser.add_argument("--quiet", action="store_true", help="print only errors")


def _log_directory(out: Path) -> Path:
    """Return a new directory for this run's device log under ``out/device-logs``."""
    stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
    path, n = out / "device-logs" / stamp, 1
    while path.exists():
        n += 1
        path = out / "device-logs" / f"{stamp}-{n}"
    return path


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run the comparison; return the exit status."""
    if args.repeats < 1 or (args.steps is not None and args.steps < 1):
        print("error: --repeats and --steps must be positive", file=sys.stderr)
        return 2
    if args.backend in SIM:
        print(
            f"error: --backend {args.backend} is the simulator; sim2real compares a device "
            "with it: give a device URI, e.g. emulator://rotary",
            file=sys.stderr,
        )
        return 2
    say = (lambda _: None) if args.quiet else (lambda text: print(text, file=sys.stderr))
    with OutputDir(args.out, OUTPUTS, overwrite=args.overwrite) as out:  # before the device
        try:
            result = run_sim2real(
                args.env,
                args.backend,
                controller=args.controller,
                gains=args.gains,
                params=args.params,
                repeats=args.repeats,
                steps=args.steps,
                reference=args.reference,
                log=_log_directory(args.out),
                progress=say,
            )
        except (HardwareError, ParamsFileError, ValueError, FileExistsError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        path = out.final(write_report(result, out.path, command_line, figures=not args.no_figures))
        out.commit()
    if not result.device:
        print(
            f"error: no device run completed ({stops(result)}): "
            f"nothing to compare; {path} says how each ended",
            file=sys.stderr,
        )
        return 1
    if not args.quiet:
        data = summary(result)
        if result.stopped:
            print(
                f"note: {len(result.stopped)} of {runs_text(data['repeats'])} on the device "
                f"ended early ({stops(result)}); the comparison uses the "
                f"{runs_text(data['complete_runs'])} that completed",
                file=sys.stderr,
            )
        for name in result.models:
            gap = data["gap"][name]["output"]
            print(f"{name:>12}: output RMSE {gap['rmse']:.4g}, fit {gap['fit_pct']:.3g} %")
        print(f"{'device':>12}: spread {data['device_spread']['output']:.4g}")
        print(f"report: {path}")
    return 0
