"""``frictiongym benchmark``: arguments, progress, terminal summary (``scripts/benchmark.py``)."""

from __future__ import annotations

import argparse
import dataclasses
import fnmatch
import sys
import time
from collections.abc import Sequence
from functools import partial

from frictiongym import devices, envs
from frictiongym._io import OutputDir, add_output_arguments
from frictiongym._validation import check_seed
from frictiongym.benchmark.figures import figure_names, write_figures
from frictiongym.benchmark.report import (
    format_metric,
    paper_claims,
    residual_markdown,
    write_reports,
)
from frictiongym.benchmark.run import Result, run_benchmark
from frictiongym.benchmark.scenarios import (
    GROUPS,
    HELDOUT_PLANTS,
    HELDOUT_SEED,
    NOISE_SEEDS,
    Scenario,
    all_scenarios,
    model_scenarios,
)

DESCRIPTION = """\
Run the paper's experiments (PID vs PID + friction compensator, with the paper's gains) and
the robustness grids around them on the simulated QUBE-Servo 2 and Altino, then write
results.json (one record per run), results.csv, results.md (tables and the paper check) and
PNG figures into --out. An --out holding an earlier run's results is refused unless
--overwrite replaces them (all of them: no figure of the earlier run stays beside the new
results); an error or a Ctrl-C leaves --out as it was.

Groups: paper (the named scenarios: paper-rotary-pid, paper-rotary-compensated,
paper-altino-pid-ki10, paper-altino-pid-ki20, paper-altino-compensated, and the servo PID on
the nominal model), mismatch (every compensator variant with its model's friction levels
x0.5, x0.8, x1, x1.2, x1.5), noise (sensor noise off, on over several seeds, and an ideal
sensor without quantisation), friction (each friction law in the plant), drivetrain (an
actuator dead zone of 0.25, 0.5 and 1 times the break-away level, with the compensator
modelling friction only, or the zone too). The default run takes well under 2 minutes on 2
cores.

--residual DEVICE=MODEL (a model.zip of `frictiongym train`, DEVICE its device's kind) adds
the group residual: the compensated PID and the residual controller on the paper's step, on
the nominal plant and on --heldout randomised plants (seeds from --heldout-seed, factors
drawn from the training ranges, the same plants for both), and a table of ITAE, SSE,
terminations and limit cycles of the residual against the compensated PID in results.md.
It needs Stable-Baselines3 and torch.

--device ID|FILE runs one device's scenarios only: a built-in one (rotary, altino) or any
device from its description file (docs/devices.md), whose paper group is its PID and its
compensated PID (the file's gains) on its default step.
"""


#: What a run may write into --out: the results and every figure (write_figures).
OUTPUTS = ("results.json", "results.csv", "results.md", *figure_names())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the benchmark's options to ``parser``."""
    add_output_arguments(parser, "benchmark-results", "results.json/.csv/.md and the figures")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a fast subset: the paper's scenarios and the 'command' compensator at x0.5 and "
        "x1.5 mismatch (a few seconds; what CI runs)",
    )
    parser.add_argument(
        "--group",
        action="append",
        choices=GROUPS,
        help="run only this group of scenarios (repeatable; default: all)",
    )
    parser.add_argument(
        "--scenario",
        action="append",
        metavar="PATTERN",
        help="run only scenarios whose name matches this shell pattern, e.g. 'paper-altino-*' "
        "(repeatable)",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=len(NOISE_SEEDS),
        metavar="N",
        help=f"seeds of the noisy scenarios, 0..N-1 (default: {len(NOISE_SEEDS)}); the "
        "noiseless ones are deterministic and run once",
    )
    parser.add_argument(
        "--residual",
        action="append",
        default=[],
        metavar="DEVICE=MODEL",
        help=f"add residual scenarios for DEVICE ({', '.join(d.kind for d in devices.DEVICES)}, "
        "or with --device FILE its kind) with the model zip MODEL from frictiongym train "
        "(repeatable, once per device)",
    )
    parser.add_argument(
        "--heldout",
        type=int,
        default=None,
        metavar="N",
        help=f"held-out randomised plants per residual device (default {HELDOUT_PLANTS}, "
        "4 with --quick)",
    )
    parser.add_argument(
        "--heldout-seed",
        type=int,
        default=HELDOUT_SEED,
        metavar="S",
        help=f"seed of the first held-out plant (default {HELDOUT_SEED}; keep clear of the "
        "training seeds)",
    )
    parser.add_argument(
        "--device",
        metavar="ID|FILE",
        help="only this device's scenarios: rotary, altino or a description file (default: "
        "the two built-in devices)",
    )
    parser.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    parser.add_argument("--list", action="store_true", help="list the scenarios and exit")
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no summary")


def select(args: argparse.Namespace) -> list[Scenario]:
    """Return the scenarios chosen by the command line."""
    if args.seeds < 1:
        raise ValueError(f"--seeds must be at least 1, got {args.seeds}")
    seeds = tuple(range(args.seeds))
    chosen = []
    device = None if args.device is None else envs.checked_device(args.device)
    for s in all_scenarios(quick=args.quick, device=device) + _residual(args):
        if args.group and s.group not in args.group:
            continue
        if args.scenario and not any(fnmatch.fnmatchcase(s.name, p) for p in args.scenario):
            continue
        if len(s.seeds) > 1 and s.group != "residual":  # held-out plants keep their seeds
            s = dataclasses.replace(s, seeds=seeds)
        chosen.append(s)
    if not chosen:
        names = ", ".join(s.name for s in all_scenarios(args.quick, device)[:6])
        raise ValueError(
            "no scenario matches --group/--scenario; see `frictiongym benchmark --list` "
            f"(e.g. {names}, ...)"
        )
    return chosen


def _residual(args: argparse.Namespace) -> list[Scenario]:
    """Return the residual scenarios of ``--residual DEVICE=MODEL`` (ValueError if malformed)."""
    plants = args.heldout if args.heldout is not None else (4 if args.quick else HELDOUT_PLANTS)
    if plants < 1:
        raise ValueError(f"--heldout must be at least 1, got {plants}")
    models: dict[str, str] = {}
    among = devices.DEVICES if args.device is None else (devices.get(args.device),)
    for spec in args.residual:
        device, sep, path = spec.partition("=")
        if not sep or device not in (d.kind for d in among) or not path:
            takes = " or ".join(f"{d.kind}=MODEL" for d in among)
            hint = "" if args.device else " (a described device's kind needs --device FILE)"
            raise ValueError(f"--residual takes {takes}, got {spec!r}{hint}")
        if device in models:
            raise ValueError(f"--residual {device}= given twice; give one model per device")
        models[device] = path
    out = []
    for device, path in models.items():
        check_seed(args.heldout_seed, "--heldout-seed")
        # FileNotFoundError / ValueError with a message
        out += model_scenarios(device, path, plants, args.heldout_seed)
    return out


def _summary(results: Sequence[Result]) -> None:
    runs = [r for r in results if r.scenario.group == "paper"]
    if runs:
        print(f"\n{'scenario':<28}{'rise s':>8}{'settle s':>10}{'OS %':>8}{'SSE %':>8}{'cycle':>8}")
        for r in runs:
            m = r.metrics
            print(
                f"{r.scenario.name:<28}{format_metric(m.rise_time, '.3f'):>8}"
                f"{format_metric(m.settling_time, '.3f'):>10}{m.overshoot_pct:>8.2f}"
                f"{m.steady_state_error_pct:>8.2f}{m.limit_cycle_amplitude:>8.3g}"
            )
    for c in paper_claims(results):
        print(
            f"\n[{'agrees' if c.agrees else 'differs'}] {c.claim}\n  paper: {c.paper}"
            f"\n  ours:  {c.ours}"
        )
    table = residual_markdown(results)
    if table:
        print("\n" + "\n".join(table[4:]))


def run(args: argparse.Namespace, command: str = "frictiongym benchmark") -> int:
    """Run the benchmark for parsed ``args``; return the exit status."""
    try:
        scenarios = select(args)
    except (ValueError, FileNotFoundError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.list:
        for s in scenarios:
            seeds = f" (seeds {s.seeds[0]}..{s.seeds[-1]})" if len(s.seeds) > 1 else ""
            print(f"{s.name:<36} {s.group:<9} {s.description}{seeds}")
        return 0
    from tqdm import tqdm  # only when running: keeps every `frictiongym` start-up lean

    start = time.perf_counter()
    among = devices.DEVICES if args.device is None else (devices.get(args.device),)
    outputs = (*OUTPUTS[:3], *figure_names(among))
    with OutputDir(args.out, outputs, overwrite=args.overwrite) as out:
        with tqdm(
            total=len(scenarios),
            desc="benchmark",
            unit="scenario",
            disable=args.quiet,
            file=sys.stderr,
        ) as bar:
            results = run_benchmark(scenarios, progress=lambda s: bar.update())
        figures = write_figures if args.device is None else partial(write_figures, among=among)
        write_reports(results, out.path, command, None if args.no_figures else figures)
        written = out.commit()
    if not args.quiet:
        _summary(results)
        print(
            f"\n{len(results)} runs of {len(scenarios)} scenarios in "
            f"{time.perf_counter() - start:.1f} s; written to {args.out}/:"
        )
        print("  " + "  ".join(p.name for p in written))
    return 0
