"""``frictiongym identify --from-log``: the options and the run for recorded data."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

from frictiongym import devices
from frictiongym._io import OutputDir
from frictiongym._validation import real_number
from frictiongym.identification.estimates import IdentificationError
from frictiongym.identification.fit import LAWS
from frictiongym.identification.from_log import LogFileError, identify_map, read_map
from frictiongym.identification.from_trace import RUN_LOG, identify_trace, read_trace
from frictiongym.identification.identify import Identification

#: Writes the outputs of a result: ``write(result, args, out, metadata, truth)``.
Writer = Callable[[Identification, argparse.Namespace, OutputDir, dict[str, Any], None], None]


def add_log_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``--from-log`` options to ``identify``'s parser."""
    logs = parser.add_argument_group(
        "recorded data",
        "--from-log FILE fits the laws to data recorded elsewhere instead of running "
        "experiments: a CSV with a header line holding either a friction map (a steady speed "
        "and the command that holds it per row, signed) or a log of time, command and position "
        "(frictiongym's own run log, steps.csv, is read by its column names). From a map, u_s "
        "is the law's extrapolation to zero speed and J is --inertia or the device preset's; "
        "from a log, J and B come from its transients and u_s only from a start from rest. "
        "The summary and friction.json's metadata say what could not be identified.",
    )
    logs.add_argument("--from-log", metavar="FILE", default=None, help="the CSV file")
    for name, default, what in (
        ("velocity", "velocity", "a map's speed"),
        ("force", "force", "a map's command"),
        ("time", "time", "a log's time"),
        ("command", "command", "a log's command"),
        ("position", "position", "a log's position"),
    ):
        logs.add_argument(
            f"--{name}-column", default=default, help=f"{what} column (default: {default})"
        )
    logs.add_argument(
        "--velocity-unit",
        default=None,
        help="a map's speeds, per s of the device's unit or another of its dimension (m, cm, "
        "mm, um, in; rad, deg, rev; and rpm), e.g. deg/s for a servo in rad; default: the "
        "device's",
    )
    logs.add_argument(
        "--force-unit",
        default=None,
        help="the commands (a map's or a log's): the device's unit or another of its "
        "dimension (V, mV; A, mA; N, kN); default: the device's",
    )
    logs.add_argument(
        "--position-unit",
        default=None,
        help="a log's positions: the device's unit or another of its dimension (m, cm, mm, um, "
        "in; rad, deg, rev); default: the device's",
    )
    logs.add_argument("--time-unit", default="s", help="a log's times: s or ms (default: s)")
    logs.add_argument(
        "--inertia",
        type=float,
        default=None,
        metavar="J",
        help="with a map: J if known, command units per acceleration unit (default: the "
        "device preset's, reported as not identified)",
    )


def run_from_log(
    args: argparse.Namespace, command_line: str, write: Writer, outputs: tuple[str, ...]
) -> int:
    """Fit the laws to ``args.from_log`` and write ``outputs`` by ``write``; return the status."""
    experiments = {
        "--backend": args.backend not in ("sim", "sim://"),
        "--noise": args.noise,
        "--friction": args.friction != "paper",
        "--backlash": args.backlash,
        "--dead-zone": args.dead_zone,
        "--true-backlash": args.true_backlash is not None,
        "--true-dead-zone": args.true_dead_zone is not None,
        "--max-backlash": args.max_backlash is not None,
    }
    given = [flag for flag, on in experiments.items() if on]
    if given:
        print(
            f"error: --from-log fits recorded data and runs no experiment: drop {', '.join(given)}",
            file=sys.stderr,
        )
        return 2
    try:
        device = devices.get(args.env)
        result = _fit(args, device)
    except (LogFileError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except IdentificationError as exc:
        print(f"error: identification failed: {exc}", file=sys.stderr)
        return 1
    with OutputDir(args.out, outputs, overwrite=args.overwrite) as out:
        write(result, args, out, {"command": command_line}, None)
        written = out.commit()
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def _fit(args: argparse.Namespace, device: devices.Device) -> Identification:
    """Return the map's or the log's identification, by the file's header."""
    if _is_map(args):
        inertia = None if args.inertia is None else real_number("--inertia", args.inertia, "> 0")
        points = read_map(
            args.from_log,
            device,
            velocity=args.velocity_column,
            force=args.force_column,
            velocity_unit=args.velocity_unit,
            force_unit=args.force_unit,
        )
        laws = tuple(LAWS) if args.law in ("best", "paper") else ("paper", args.law)
        return identify_map(points, device, inertia=inertia, laws=laws, source=args.from_log)
    if args.inertia is not None:
        raise ValueError("--inertia applies to a map; a log's transients give J")
    if args.law != "paper":
        raise ValueError(
            f"a log is fitted with the paper law by its output error; drop --law {args.law}"
        )
    if not args.quiet:
        print("fitting every sample of the log (a minute for a long one) ...", file=sys.stderr)
    runs, dt = read_trace(
        args.from_log,
        device,
        time_column=args.time_column,
        command=args.command_column,
        position=args.position_column,
        time_unit=args.time_unit,
        position_unit=args.position_unit,
        command_unit=args.force_unit,
    )
    return identify_trace(runs, device, dt, source=args.from_log)


def _is_map(args: argparse.Namespace) -> bool:
    """Whether the file's header names the map's columns (else it is read as a log)."""
    try:
        with open(args.from_log, encoding="utf-8-sig", errors="replace") as handle:
            header = {cell.strip() for cell in handle.readline().split(",")}
    except OSError as exc:
        raise LogFileError(f"{args.from_log}: cannot read it: {exc}") from None
    if not header - {""}:
        raise LogFileError(f"{args.from_log}: empty; the first line must name the columns")
    if {args.velocity_column, args.force_column} <= header:
        return True
    log = {args.time_column, args.command_column, args.position_column}
    if log <= header or {RUN_LOG["command"], RUN_LOG["position"]} <= header:
        return False
    raise LogFileError(
        f"{args.from_log}: its columns ({', '.join(sorted(header))}) are neither a map's "
        f"({args.velocity_column!r}, {args.force_column!r}) nor a log's ({args.time_column!r}, "
        f"{args.command_column!r}, {args.position_column!r}); name yours with the column options"
    )
