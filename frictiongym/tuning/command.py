"""``frictiongym tune``: arguments, progress, output files and summary (``scripts/tune.py``)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import math
import sys
from collections.abc import Iterator
from pathlib import Path

from frictiongym._cluster import ClusterError, ordered_map, ray_session
from frictiongym._io import OutputDir, add_output_arguments, write_json_atomic
from frictiongym._validation import check_seed
from frictiongym.devices import ROTARY
from frictiongym.params import load_params
from frictiongym.tuning.evaluate import TuningModel
from frictiongym.tuning.figures import plot_feasible_set
from frictiongym.tuning.search import (
    DEFAULT_CHUNK,
    DEFAULT_HORIZON,
    DEFAULT_SAMPLES,
    RULES,
    ChunkMap,
    TuneResult,
    random_search,
)

DESCRIPTION = f"""\
The paper's random-search PID tuning for the QUBE-Servo 2 (section 3.1): draw --samples gain
triples uniformly from 0 < Kp < 10, 0 < Ki < 5, 0 < Kd < 0.5, simulate each unit step on the
batched plant (2 ms sampled-data loop: exact ZOH plant, the PID class with derivative on the
true velocity and clamping anti-windup at +-10 V), keep those with rise time < 0.05 s, peak
time < 0.1 s, settling time (2 % band) < 1.5 s and overshoot < 20 %, and choose one by --rule.
The paper's gains (7.8, 1.5, 0.275) are evaluated in the same model.

Models: nominal (default; Eq. (2) without friction, as the paper tuned), friction (the paper's
identified stiction/Coulomb law in the plant), or --params PATH (J, B and friction of a
friction.json written by `frictiongym identify`; with --model nominal its J and B only).
--velocity filtered feeds the D term the QUBE's filtered angle derivative instead of the true
velocity, as the envs and the benchmark do (a much larger feasible set; docs/tuning.md).

Rules: {"; ".join(f"{k}: {v}" for k, v in RULES.items())}.

Writes to --out: tune.json (n_samples, n_feasible, every feasible candidate with its metrics,
the chosen gains and rule, the paper's gains, specs, bounds, model, seed, dt, horizon,
software version, wall time) and tune.png (the feasible set in the three gain planes and the
feasible step responses). {DEFAULT_SAMPLES} samples take about a second on 2 cores. An --out
holding an earlier run's results is refused unless --overwrite replaces them (both); an error
or a Ctrl-C leaves --out as it was.

--ray [ADDRESS] runs the chunks of --chunk candidates as Ray tasks: on a local Ray started for
the command (shut down after), or on the cluster at ADDRESS. The result is the serial run's
(tune.json equal but for its timing and provenance: wall_time_s, command, ray). Needs the
cluster extra: pip install "frictiongym[cluster]" (docs/cluster.md).
"""


#: What a run may write into --out.
OUTPUTS = ("tune.json", "tune.png")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the tuner's options to ``parser``."""
    parser.add_argument(
        "--samples",
        type=int,
        default=DEFAULT_SAMPLES,
        metavar="N",
        help=f"gain triples to draw (default: {DEFAULT_SAMPLES}, about a second)",
    )
    parser.add_argument(
        "--seed", type=int, default=0, metavar="S", help="seed of numpy's default_rng (default: 0)"
    )
    add_output_arguments(parser, "tune-results", "tune.json and tune.png")
    parser.add_argument(
        "--model",
        choices=("nominal", "friction"),
        default=None,
        help="nominal: no friction (default without --params); friction: the paper's friction "
        "law in the plant (default with --params: the file's law)",
    )
    parser.add_argument(
        "--params",
        type=Path,
        metavar="PATH",
        help="a friction.json (or its directory) from `frictiongym identify`: tune on its J, B "
        "and friction",
    )
    parser.add_argument(
        "--velocity",
        choices=("ideal", "filtered"),
        default="ideal",
        help="the D term's velocity: ideal (the plant's true velocity, an ideal tachometer; "
        "default) or filtered (the QUBE's 50 s/(s+50) estimate of the angle, as the env "
        "observes it)",
    )
    parser.add_argument(
        "--rule",
        choices=tuple(RULES),
        default="itae",
        help="how to choose among the feasible candidates (default: itae)",
    )
    parser.add_argument(
        "--horizon",
        type=float,
        default=DEFAULT_HORIZON,
        metavar="SECONDS",
        help=f"simulated time per candidate, longer than the 1.5 s settling spec (default: "
        f"{DEFAULT_HORIZON:g})",
    )
    parser.add_argument(
        "--chunk",
        type=int,
        default=DEFAULT_CHUNK,
        metavar="N",
        help=f"candidates simulated at once; memory only, not results (default: {DEFAULT_CHUNK})",
    )
    parser.add_argument(
        "--full",
        action="store_true",
        help="simulate every candidate to the horizon instead of dropping those that have "
        "provably failed (same feasible set, about 50x slower; gives every candidate's "
        "per-spec failures in tune.json)",
    )
    parser.add_argument(
        "--ray",
        nargs="?",
        const="",
        default=None,
        metavar="ADDRESS",
        help="run the chunks as Ray tasks: on a local Ray (no ADDRESS) or the cluster at "
        "ADDRESS (HOST:PORT, ray://HOST:PORT or auto); same result as without",
    )
    parser.add_argument("--no-figures", action="store_true", help="skip tune.png")
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no summary")


def _model(args: argparse.Namespace) -> TuningModel:
    """Build the model chosen by --model/--params (ValueError with the reason)."""
    if args.params is None:
        return TuningModel.paper(with_friction=args.model == "friction")
    params = load_params(args.params)  # ParamsFileError (a ValueError) names the file
    if params.device not in (None, ROTARY.name):
        raise ValueError(
            f"{args.params}: identified on {params.device}; tune works on the QUBE-Servo 2 "
            "(RotaryServo) only, the paper's specs are for it"
        )
    return TuningModel.from_params(params, args.model != "nominal", source=str(args.params))


def check_args(args: argparse.Namespace) -> TuningModel:
    """Validate the options and build the model; raise ValueError saying what to change."""
    if args.samples < 1:
        raise ValueError(f"--samples must be at least 1, got {args.samples}")
    check_seed(args.seed)
    if args.chunk < 1:
        raise ValueError(f"--chunk must be at least 1, got {args.chunk}")
    if not (math.isfinite(args.horizon) and args.horizon > 1.5):
        raise ValueError(
            f"--horizon must be a number of seconds longer than the 1.5 s settling-time spec "
            f"(so settling can be judged), got {args.horizon}"
        )
    return dataclasses.replace(_model(args), velocity=args.velocity)


def _fmt(value: float | None, spec: str = ".3f") -> str:
    return "never" if value is None else format(value, spec)


def summary(result: TuneResult) -> str:
    """Return the terminal summary: counts, chosen gains, the paper's gains."""
    rec = result.record()
    n, f = rec["n_samples"], rec["n_feasible"]
    law = rec["model"]["friction"]["law"]
    law = "no" if law == "none" else f"'{law}'"
    lines = [
        f"model {rec['model']['name']} ({law} friction, {rec['model']['velocity']} velocity), "
        f"seed {rec['seed']}, horizon {rec['horizon']:g} s, dt {rec['dt'] * 1e3:g} ms",
        f"{'':<18}{'Kp':>9}{'Ki':>9}{'Kd':>9}{'rise s':>8}{'peak s':>8}{'settle s':>9}"
        f"{'OS %':>7}{'feasible':>10}",
    ]
    rows = []
    if rec["chosen"] is not None:
        rows.append((f"chosen ({result.rule})", rec["chosen"], "yes"))
    p = rec["paper_gains"]
    verdict = "yes" if p["feasible"] else "no: " + ", ".join(p["failing_specs"])
    rows.append(("paper", {**p, **p["metrics"]}, verdict))
    for label, c, ok in rows:
        lines.append(
            f"{label:<18}{c['kp']:>9.4g}{c['ki']:>9.4g}{c['kd']:>9.4g}"
            f"{_fmt(c['rise_time']):>8}{_fmt(c['peak_time']):>8}{_fmt(c['settling_time']):>9}"
            f"{c['overshoot_pct']:>7.2f}  {ok}"
        )
    head = f"{f} of {n} candidates feasible ({100 * f / n:.2f} %; the paper found 328)"
    if rec["chosen"] is None:
        head += "; none to choose: try more --samples"
    return "\n".join([head, *lines])


@contextlib.contextmanager
def _chunk_map(address: str | None) -> Iterator[tuple[ChunkMap | None, dict[str, object]]]:
    """Yield how the chunks run (None: here, one after the other) and its record for tune.json.

    With ``address`` (``""``: a local Ray), a Ray session for the command's duration.
    """
    if address is None:
        yield None, {}
        return
    with ray_session("frictiongym tune --ray", address or None, option="--ray") as ray:
        cpus = int(ray.cluster_resources().get("CPU", 0))
        yield functools.partial(ordered_map, ray), {"address": address or "local", "cpus": cpus}


def run(args: argparse.Namespace, command_line: str = "frictiongym tune") -> int:
    """Run the tuner for parsed ``args``; return the exit status."""
    try:
        model = check_args(args)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    from tqdm import tqdm  # only when running: keeps every `frictiongym` start-up lean

    try:
        with (
            OutputDir(args.out, OUTPUTS, overwrite=args.overwrite) as out,
            _chunk_map(args.ray) as (map_chunks, ray_record),
        ):
            with tqdm(
                total=args.samples,
                desc="tune",
                unit="cand",
                unit_scale=True,
                disable=args.quiet,
                file=sys.stderr,
            ) as bar:
                result = random_search(
                    args.samples,
                    args.seed,
                    model,
                    horizon=args.horizon,
                    rule=args.rule,
                    chunk=args.chunk,
                    early_stop=not args.full,
                    progress=bar.update,
                    map_chunks=map_chunks,
                )
            result.extra["command"] = command_line
            if ray_record:
                result.extra["ray"] = ray_record
            write_json_atomic(out.path / "tune.json", result.record(), indent=1, allow_nan=False)
            if not args.no_figures:
                plot_feasible_set(result, out.path / "tune.png")
            written = out.commit()
    except ClusterError as error:  # before any work: --out is left as it was
        print(f"error: {error}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(summary(result))
        print(
            f"\n{result.n_samples} candidates in {result.wall_time:.1f} s "
            f"({result.n_samples / result.wall_time:,.0f}/s); written to {args.out}/: "
            + "  ".join(p.name for p in written)
        )
    return 0
