"""Fuzz the hardware layer and its untrusted inputs; print what was tried and what held.

Parts (``--part``, default all):

* ``frames``: streams of random and damaged frames (bit flips, truncation, garbage, bad CRC, a
  good CRC over a bad layout, COBS edge cases, delimiters dropped or doubled) through the
  Python decoder (``frictiongym/hardware/protocol.py``), whole and in random pieces, and the C
  decoder (``firmware/common/fg_protocol.c`` in ``firmware/test/host_harness.c``, built with
  the system compiler under AddressSanitizer and UBSan when it has them): no exception but
  ``FrameError``, every accepted frame exactly a valid encoding, C == Python on every stream.
* ``altino``: damaged stock Altino replies through ``parse_sensor_reply`` and the stream
  reader ``take_reply`` (``frictiongym/hardware/altino_frames.py``).
* ``watchdog``: the servo and Altino firmware in C and its Python twin (``firmware.py``),
  armed, then commands at random times, then silence: the motor stops at the first tick past
  the watchdog time, and C and Python agree tick by tick.
* ``actions``: hostile actions (NaN, inf, huge, wrong types and shapes) through device envs on
  the lock-step emulator: refused with ``ValueError``, the motor zeroed after each, never a
  command beyond the limit on the wire, the run log complete.
* ``stock``: the same hostile commands through the stock Altino backend to a fake car on a
  pty: refused, followed by the stop frames, never a wheel value beyond 1000 on the wire.
* ``faults``: the real-time emulator unplugged, frozen, left without commands, behind a link
  that delays its frames, or behind one that damages them: the time to the error, the log
  complete, the motor zeroed, the watchdog's stop in device time, and every sample taken over
  the damaging link equal to the device's own record of its tick.
* ``models``: hostile copies of the shipped residual model through ``load_policy``: nothing
  runs, only ``ValueError``.
* ``params``: mutated ``friction.json`` files through ``load_params``: only
  ``ParamsFileError``, and what loads is in range.

``--cases N`` sets the frame streams and Altino replies; the other parts scale with it
(watchdog timelines and actions N/20, stock Altino commands and model files N/200, params
files N/10, at least a few each; fault rounds ``--fault-rounds``). The default (20 000) takes
about half a minute on two cores; ``--cases 200000`` decodes about 900 000 frames. Every case is
drawn from its own generator seeded by ``--seed``, the part and the case number, so a
reported case of the frames, altino, watchdog, models or params parts replays alone with
``--part P --first K --cases 1`` (the actions and stock parts step one device through all
their cases, so a case there replays only with those before it). Exits 1 if anything
failed, 2 on a usage error.

Usage: python scripts/fuzz_hardware.py [--cases 20000] [--seed 0] [--part frames,actions]
       [--first K] [--fault-rounds 5] [--no-c] [--firmware DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import _fuzz_common as common
import _fuzz_decoders as decoders
import _fuzz_device as device
import _fuzz_faults as faults
import _fuzz_files as files

PARTS = ("frames", "altino", "watchdog", "actions", "stock", "faults", "models", "params")
#: Failures printed per part (the rest are counted).
SHOWN_FAILURES = 20


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Parse the command line (exits 2 on a usage error)."""
    parser = argparse.ArgumentParser(
        description="Fuzz the frame decoders (Python and C), the stock Altino replies, the "
        "firmware watchdog, device-env actions, link faults, model files and params files; "
        "print a summary table and exit 1 if anything failed.",
    )
    parser.add_argument(
        "--cases",
        type=int,
        default=20_000,
        help="frame streams and Altino replies (default 20000); the other parts "
        "scale with it: watchdog timelines and actions N/20, stock Altino "
        "commands and model files N/200, params files N/10",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of every case (default 0)")
    parser.add_argument(
        "--part",
        default=",".join(PARTS),
        help=f"comma-separated parts to run (default all: {','.join(PARTS)})",
    )
    parser.add_argument(
        "--first",
        type=int,
        default=None,
        help="replay: run exactly --cases cases of each chosen part, numbered "
        "from this one (e.g. --part frames --first 3131 --cases 1); the "
        "actions and stock parts carry state from case to case, so their "
        "cases replay only from the start",
    )
    parser.add_argument(
        "--fault-rounds",
        type=int,
        default=5,
        help="rounds of the three real-time faults (default 5)",
    )
    parser.add_argument("--no-c", action="store_true", help="skip the C side (no compiler needed)")
    parser.add_argument(
        "--firmware",
        type=Path,
        default=common.FIRMWARE,
        help="firmware tree to build the C harness from (default: the repository's firmware/)",
    )
    args = parser.parse_args(argv)
    parts = [name.strip() for name in args.part.split(",") if name.strip()]
    unknown = sorted(set(parts) - set(PARTS))
    if unknown:
        parser.error(f"unknown --part {', '.join(unknown)}; choose from {', '.join(PARTS)}")
    if args.cases < 1 or args.fault_rounds < 1 or (args.first is not None and args.first < 0):
        parser.error("--cases and --fault-rounds must be at least 1, --first at least 0")
    if not args.no_c and not (args.firmware / "common" / "fg_protocol.c").is_file():
        parser.error(
            f"--firmware {args.firmware} holds no common/fg_protocol.c; give the "
            "firmware folder of a frictiongym checkout"
        )
    args.parts = parts
    return args


def say(message: str) -> None:
    """Progress, on stderr (the summary goes to stdout)."""
    print(message, file=sys.stderr, flush=True)


def run_parts(args: argparse.Namespace) -> list[tuple[common.Part, float]]:
    """Run the chosen parts; return each with its wall time, s."""
    n, seed = args.cases, args.seed

    def size(share: int, least: int) -> range:
        """The cases of a part: its share of N (at least ``least``), or N from ``--first``."""
        if args.first is None:
            return range(max(least, n // share))
        return range(args.first, args.first + n)

    needs_c = not args.no_c and {"frames", "watchdog"} & set(args.parts)
    harness, folder = common.build_harness(args.firmware if needs_c else None)
    if harness is not None:
        say(f"C harness built{' with ASan+UBSan' if harness.sanitized else ' (no sanitizers)'}")
    runners: dict[str, Callable[[], common.Part]] = {
        "frames": lambda: decoders.fuzz_frames(size(1, 1), seed, harness, say),
        "altino": lambda: decoders.fuzz_altino(size(1, 1), seed, say),
        "watchdog": lambda: device.fuzz_watchdog(size(20, 20), seed, harness, say),
        "actions": lambda: device.fuzz_actions(size(20, 40), seed, say),
        "stock": lambda: device.fuzz_stock(size(200, 10), seed, say),
        "faults": lambda: faults.fuzz_faults(args.fault_rounds, seed, say),
        "models": lambda: files.fuzz_models(size(200, 10), seed, say),
        "params": lambda: files.fuzz_params(size(10, 50), seed, say),
    }
    results = []
    try:
        for name in args.parts:
            started = time.perf_counter()
            results.append((runners[name](), time.perf_counter() - started))
    finally:
        if folder is not None:
            folder.cleanup()
    return results


def summary(results: list[tuple[common.Part, float]]) -> str:
    """The Markdown table of the parts, their notes, and the first failures of each."""
    lines = [
        "| part | cases | what was tried | what had to hold | failures | time |",
        "|---|---:|---|---|---:|---:|",
    ]
    for part, seconds in results:
        lines.append(
            f"| {part.name} | {part.cases} | {part.tried} | {part.held} | "
            f"{len(part.failures)} | {seconds:.0f} s |"
        )
    lines.append("")
    lines += [f"* {note}" for part, _ in results for note in part.notes]
    for part, _ in results:
        if part.failures:
            lines += ["", f"{part.name}: {len(part.failures)} failures"]
            lines += [f"  - {f}" for f in part.failures[:SHOWN_FAILURES]]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the fuzzing; return 0 if everything held, 1 otherwise."""
    args = parse_args(argv)
    command = "python scripts/fuzz_hardware.py " + " ".join(argv or sys.argv[1:])
    try:
        results = run_parts(args)
    except common.HarnessBuildError as exc:  # the firmware does not compile: a failure too
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"\n{command.strip()}\n")
    print(summary(results))
    failed = sum(len(part.failures) for part, _ in results)
    print(f"\n{'FAILED: ' + str(failed) + ' failures' if failed else 'everything held'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
