"""Run the default commands and compare their results between two versions of the package.

A refactoring must not change a result. This script runs the commands whose outputs are the
project's results, on their defaults, and writes each output under one folder:

* ``benchmark/results.json``: ``frictiongym benchmark`` (the default groups);
* ``identify-rotary/friction.json`` and ``identify-altino/friction.json``: ``frictiongym
  identify`` on each env;
* ``tune/tune.json``: ``frictiongym tune``;
* ``residual/results.json``: ``frictiongym benchmark --group residual`` with the shipped
  policies in ``models/residual/``.

``compare`` then reads two such folders and reports every value that differs. Keys that record
when, where or how fast a run went (wall time, software version, paths) are left out; every
other value, floats included, must be equal bit for bit.

Usage::

    python scripts/compare_outputs.py run OUT [--source TREE]   # TREE: a checkout (default: .)
    python scripts/compare_outputs.py compare BEFORE AFTER

For example, to check a change against ``main``::

    git worktree add /tmp/base main
    python scripts/compare_outputs.py run /tmp/out-base --source /tmp/base
    python scripts/compare_outputs.py run /tmp/out-new
    python scripts/compare_outputs.py compare /tmp/out-base /tmp/out-new
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent

#: Folder -> (command arguments, output file). Model paths are relative to the source tree.
RUNS: dict[str, tuple[list[str], str]] = {
    "benchmark": (["benchmark", "--no-figures", "--quiet"], "results.json"),
    "identify-rotary": (
        ["identify", "--env", "frictiongym/RotaryServo-v1", "--no-figures", "--quiet"],
        "friction.json",
    ),
    "identify-altino": (
        ["identify", "--env", "frictiongym/AltinoDistance-v1", "--no-figures", "--quiet"],
        "friction.json",
    ),
    "tune": (["tune", "--no-figures", "--quiet"], "tune.json"),
    "residual": (
        [
            "benchmark",
            "--group",
            "residual",
            "--residual",
            "rotary={models}/rotary.zip",
            "--residual",
            "altino={models}/altino.zip",
            "--no-figures",
            "--quiet",
        ],
        "results.json",
    ),
}

#: Keys whose values describe the run rather than its result (``seconds``: identification's
#: run time; ``command``: the command line, which names the output folder).
VOLATILE = {
    "wall_time",
    "wall_time_s",
    "version",
    "software_version",
    "created",
    "command",
    "seconds",
}
#: Keys whose string values are paths into the checkout: compared by file name.
PATHS = {"model"}


def run(out: Path, source: Path) -> None:
    """Run every command of :data:`RUNS` with the package of ``source``; outputs under ``out``."""
    env = dict(os.environ, PYTHONPATH=str(source))
    models = source / "models" / "residual"
    for name, (args, _) in RUNS.items():
        folder = out / name
        argv = [a.format(models=models) for a in args] + ["--out", str(folder), "--overwrite"]
        start = time.perf_counter()
        code = "import sys; from frictiongym.cli import main; sys.exit(main(sys.argv[1:]))"
        subprocess.run([sys.executable, "-c", code, *argv], env=env, cwd=out, check=True)
        print(f"{name}: {time.perf_counter() - start:.1f} s", flush=True)


def differences(before: Any, after: Any, where: str = "") -> Iterator[str]:
    """Yield a line for each value that differs between two parsed JSON documents."""
    if isinstance(before, dict) and isinstance(after, dict):
        for key in sorted(set(before) | set(after)):
            if key in VOLATILE:
                continue
            if key not in before or key not in after:
                yield f"{where}/{key}: only in {'after' if key not in before else 'before'}"
            elif key in PATHS and isinstance(before[key], str) and isinstance(after[key], str):
                if Path(before[key]).name != Path(after[key]).name:
                    yield f"{where}/{key}: {before[key]!r} before, {after[key]!r} after"
            else:
                yield from differences(before[key], after[key], f"{where}/{key}")
    elif isinstance(before, list) and isinstance(after, list):
        if len(before) != len(after):
            yield f"{where}: {len(before)} items before, {len(after)} after"
        for index, (old, new) in enumerate(zip(before, after, strict=False)):
            yield from differences(old, new, f"{where}[{index}]")
    elif not same(before, after):
        yield f"{where}: {before!r} before, {after!r} after"


def same(before: Any, after: Any) -> bool:
    """Whether two JSON scalars are equal (NaN equals NaN; 1 and 1.0 differ)."""
    if isinstance(before, float) and isinstance(after, float):
        return before == after or (math.isnan(before) and math.isnan(after))
    return type(before) is type(after) and before == after


def compare(before: Path, after: Path) -> int:
    """Compare the outputs of two :func:`run` folders; return the number of differences."""
    total = 0
    for name, (_, filename) in RUNS.items():
        old = json.loads((before / name / filename).read_text())
        new = json.loads((after / name / filename).read_text())
        found = list(differences(old, new))
        total += len(found)
        print(f"{name}/{filename}: {'identical' if not found else f'{len(found)} differences'}")
        for line in found[:20]:
            print(f"  {line}")
    return total


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run_parser = commands.add_parser("run", help="run the default commands into OUT")
    run_parser.add_argument("out", type=Path)
    run_parser.add_argument("--source", type=Path, default=REPO, help="checkout to run")
    compare_parser = commands.add_parser("compare", help="compare two run folders")
    compare_parser.add_argument("before", type=Path)
    compare_parser.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.command == "run":
        args.out.mkdir(parents=True, exist_ok=True)
        run(args.out.resolve(), args.source.resolve())
        return 0
    return 1 if compare(args.before, args.after) else 0


if __name__ == "__main__":
    sys.exit(main())
