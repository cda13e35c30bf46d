"""``frictiongym sweep``: seeds x hyperparameter grids of ``train`` as Ray Tune trials."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from frictiongym._cluster import ClusterError, import_ray, ray_session
from frictiongym._io import OutputDir, add_output_arguments, write_json_atomic
from frictiongym._validation import MAX_SEED
from frictiongym.benchmark.scenarios import HELDOUT_PLANTS, HELDOUT_SEED
from frictiongym.residual.command import (
    add_training_arguments,
    positive_count,
    settings_from_args,
)
from frictiongym.sweep.grid import SweepError, Trial, check_grid, expand, parse_grid
from frictiongym.sweep.report import collect, ranked, write_reports
from frictiongym.sweep.run import TUNE_FOLDER, run_trials

DESCRIPTION = """\
Train a residual policy for every seed (--seeds) and every combination of the --grid values,
each trial a `frictiongym train` run with the other options given here, as Ray Tune trials:
on a local Ray started for the command (and shut down after), or on the cluster at --address.
A trial gets --cpus-per-trial CPUs (and as many torch threads unless --threads or the grid
says), trains into --out/trials/NAME, and its best policy (best.zip, chosen on the validation
plants) is then evaluated as `frictiongym benchmark --group residual --residual
DEVICE=best.zip` does, on --heldout held-out plants.

--grid KEY=V1,V2,... (repeatable) takes a train option (steps, n_envs, scale, max_time,
algo, reward, residual_cost, randomize, validate_every, validation_plants, threads,
checkpoint_every, quick) or an argument of the SB3 algorithm (as --sb3), values in JSON:
--grid learning_rate=0.0003,0.001 --grid n_envs=8,32 --grid 'policy_kwargs={"net_arch":
[64,64]},{"net_arch":[256,256]}' --grid 'reward="env","precision"'.

The same seed and settings train the same policy as `frictiongym train`: each trial's
train.json holds the train command line that does (its command_line).

Writes to --out: sweep.json (the trials), trials/NAME/ (each trial's train outputs and
heldout.json), tune/ (Ray Tune's state), and at the end sweep.csv and sweep.md (the trials
ranked by validation score, with their held-out ITAE and SSE ratios to the compensated PID)
and best/ (the best trial's policy, train.json and heldout.json). A Ctrl-C stops the trials;
--resume (with the same options) restores the sweep: finished trials stay, the others
continue from their last checkpoint (--checkpoint-every). An --out holding a sweep is refused
unless --overwrite replaces it or --resume continues it. Exit status 1 if a trial failed.

Needs the cluster and rl extras: pip install "frictiongym[cluster,rl]". Running on a
cluster, and how the package reaches its workers: docs/cluster.md.
"""

#: What a sweep writes into --out.
OUTPUTS = ("sweep.json", "sweep.csv", "sweep.md", "best", "trials", TUNE_FOLDER)
#: sweep.json's format.
FORMAT = "frictiongym.sweep/1"


def _grid(text: str) -> tuple[str, list[Any]]:
    try:
        return parse_grid(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _runtime_env(text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except json.JSONDecodeError:
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the sweep's options (and train's, but for --seed) to ``parser``."""
    parser.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[0],
        metavar="S",
        help=f"seeds, each trained with every grid combination (0 to {MAX_SEED}; default 0)",
    )
    parser.add_argument(
        "--grid",
        action="append",
        default=[],
        type=_grid,
        metavar="KEY=V1,V2,...",
        help="values of a train option or SB3 argument to sweep, in JSON (repeatable)",
    )
    add_training_arguments(parser)
    add_output_arguments(parser, "sweep-results", "the trials, sweep.csv/.md and best/")
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue the sweep in --out (given the same options): Tune's saved state, and "
        "each unfinished trial from its last checkpoint",
    )
    parser.add_argument(
        "--address",
        metavar="ADDRESS",
        help="an existing Ray cluster (HOST:PORT, ray://HOST:PORT or auto); default: a local "
        "Ray started for the command",
    )
    parser.add_argument(
        "--cpus-per-trial",
        type=positive_count,
        default=1,
        metavar="N",
        help="CPUs Ray gives each trial, and its torch threads unless --threads (default 1)",
    )
    parser.add_argument(
        "--retries",
        type=int,
        default=0,
        metavar="N",
        help="run a failed trial again up to N times, from its last checkpoint (default 0)",
    )
    parser.add_argument(
        "--heldout",
        type=positive_count,
        default=HELDOUT_PLANTS,
        metavar="N",
        help=f"held-out plants of each trial's evaluation (default {HELDOUT_PLANTS}, as the "
        "benchmark's)",
    )
    parser.add_argument(
        "--heldout-seed",
        type=int,
        default=HELDOUT_SEED,
        metavar="S",
        help=f"seed of the first held-out plant (default {HELDOUT_SEED})",
    )
    parser.add_argument(
        "--runtime-env",
        type=_runtime_env,
        metavar="JSON",
        help='Ray\'s runtime_env for the workers, e.g. \'{"pip": ["frictiongym[rl]"]}\' '
        "(docs/cluster.md)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no summary")


def plan(args: argparse.Namespace, command_line: str) -> list[Trial]:
    """Return the trials of the command line (:class:`SweepError` saying what is wrong)."""
    if args.retries < 0:
        raise SweepError(f"--retries must be 0 or more, got {args.retries}")
    if not 0 <= args.heldout_seed <= MAX_SEED:
        raise SweepError(f"--heldout-seed must be from 0 to {MAX_SEED}, got {args.heldout_seed}")
    if args.overwrite and args.resume:
        raise SweepError(
            "--overwrite replaces an earlier sweep and --resume continues it: give one of them"
        )
    base = settings_from_args(args, quiet=True, command_line=command_line)
    if Path(base.env_id).suffix.lower() in (".toml", ".json"):  # a device description file:
        base.env_id = str(Path(base.env_id).resolve())  # a worker's folder is not this one
    if base.threads is None:
        base.threads = args.cpus_per_trial
    check_grid(args.grid, base)
    heldout = {"plants": args.heldout, "first_seed": args.heldout_seed}
    # Absolute: a Ray worker's working folder is not this one.
    return expand(base, args.seeds, args.grid, args.out.resolve(), heldout)


def _record(args: argparse.Namespace, trials: list[Trial], command_line: str) -> dict[str, Any]:
    """Return ``sweep.json``: what identifies the sweep (its trials) and how it was run."""
    return {
        "format": FORMAT,
        "command_line": command_line,
        "seeds": args.seeds,
        "grid": dict(args.grid),
        "cpus_per_trial": args.cpus_per_trial,
        "heldout": trials[0].heldout,
        "trials": [
            {k: v for k, v in t.config().items() if k != "settings"}
            | {"command_line": t.settings.command_line}
            for t in trials
        ],
    }


def _check_resume(out: Path, record: dict[str, Any]) -> None:
    """Raise :class:`SweepError` unless ``out`` holds a sweep of the same trials."""
    saved_file = out / "sweep.json"
    if not saved_file.is_file():
        raise SweepError(f"--resume: {out} holds no sweep (no sweep.json); drop --resume")
    saved = json.loads(saved_file.read_text())
    for key in ("trials", "heldout"):
        if saved.get(key) != record[key]:
            raise SweepError(
                f"--resume: the sweep in {out} has other {key} ({saved_file}); give the options "
                "it was started with, or another --out"
            )


def _summary(trials: list[Trial], errors: dict[str, str]) -> str:
    """Return the terminal summary: the top trials and where the results are."""
    order = ranked(collect(trials, errors))
    lines = [f"{'rank':<5}{'validation':>11}{'held-out ITAE':>15}{'SSE':>8}  trial"]
    for rank, o in enumerate(order[:5], 1):
        if o.status != "done":
            break
        lines.append(
            f"{rank:<5}{o.score:>11.3f}{o.ratio('heldout', 'itae_ratio'):>15.3f}"
            f"{o.ratio('heldout', 'sse_ratio'):>8.3f}  {o.trial.name}"
        )
    done = sum(o.status == "done" for o in order)
    lines.append(f"{done} of {len(trials)} trials finished, {len(errors)} failed")
    return "\n".join(lines)


def run(args: argparse.Namespace, command_line: str = "frictiongym sweep") -> int:
    """Run the sweep for parsed ``args``; return the exit status."""
    try:
        import_ray("frictiongym sweep")
        trials = plan(args, command_line)
    except (ClusterError, SweepError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    record = _record(args, trials, command_line)
    output = OutputDir(
        args.out,
        OUTPUTS,
        overwrite=args.overwrite,
        staged=False,
        continuing=args.resume,
        resumable=True,
    )
    try:
        with output:  # trials stay on an error or a Ctrl-C, for --resume
            if args.resume:
                _check_resume(args.out, record)
            try:
                with ray_session("frictiongym sweep", args.address, args.runtime_env):
                    output.replace_earlier()
                    if not args.resume:
                        write_json_atomic(args.out / "sweep.json", record)
                    errors = run_trials(
                        trials,
                        args.out,
                        args.cpus_per_trial,
                        args.retries,
                        args.resume,
                        args.quiet,
                    )
            except KeyboardInterrupt as interrupt:  # the trials stay: say so, not "as it was"
                if not interrupt.args and (args.out / "sweep.json").is_file():
                    interrupt.args = (f"the trials so far are in {args.out}; --resume continues",)
                raise
            written = write_reports(
                collect(trials, errors), args.out, command_line, record["heldout"]
            )
            output.commit()
    except (ClusterError, SweepError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(_summary(trials, errors))
        print(f"written to {args.out}/: " + "  ".join(p.name for p in written))
    return 1 if errors else 0
