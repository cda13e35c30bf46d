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

from frictiongym import devices, envs
from frictiongym._cluster import ClusterError, ordered_map, ray_session
from frictiongym._io import OutputDir, add_output_arguments, write_json_atomic
from frictiongym._validation import check_seed
from frictiongym.params import load_params
from frictiongym.tuning.evaluate import PAPER_GAINS, TuningModel
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
from frictiongym.tuning.specs import GainBounds, StepSpecs

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

--device FILE tunes another device (an encoder device's description file, docs/devices.md): its
plant, period and demo step, with the specs and gain bounds of the file's [tuning] table or
of --rise-time/--peak-time/--settling-time/--overshoot and --kp/--ki/--kd (without either, the
paper's specs and bounds of 0 to 5 times the file's PID gains); its PID is evaluated beside.

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
        default=None,
        metavar="SECONDS",
        help=f"simulated time per candidate, longer than the settling spec (default: "
        f"{DEFAULT_HORIZON:g}, or twice the settling spec if longer)",
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
    parser.add_argument(
        "--device",
        default="rotary",
        metavar="ID|FILE",
        help="the device: rotary (default, the paper's servo) or a description file",
    )
    for name, unit, meaning in SPEC_OPTIONS:
        parser.add_argument(
            f"--{name.replace('_', '-').removesuffix('-pct')}",
            dest=name,
            type=float,
            metavar=unit,
            help=f"{meaning} limit (default: the file's [tuning] or the paper's)",
        )
    for gain in ("kp", "ki", "kd"):
        parser.add_argument(
            f"--{gain}",
            nargs=2,
            type=float,
            metavar=("LOW", "HIGH"),
            help=f"bounds of {gain.capitalize()} (default: the file's or the paper's)",
        )
    parser.add_argument("--no-figures", action="store_true", help="skip tune.png")
    parser.add_argument("--quiet", action="store_true", help="no progress bar, no summary")


#: Spec options: StepSpecs field, metavar, meaning.
SPEC_OPTIONS = (
    ("rise_time", "S", "rise-time (10-90 %%)"),
    ("peak_time", "S", "peak-time"),
    ("settling_time", "S", "settling-time (2 %% band)"),
    ("overshoot_pct", "PCT", "overshoot"),
)


def _model(args: argparse.Namespace, device: devices.Device) -> TuningModel:
    """Build the model chosen by --device/--model/--params (ValueError with the reason)."""
    if args.params is None:
        return TuningModel.for_device(device, with_friction=args.model == "friction")
    params = load_params(args.params)  # ParamsFileError (a ValueError) names the file
    if params.device not in (None, device.name):
        raise ValueError(
            f"{args.params}: identified on {params.device}, not on {device.name}; give "
            "--device the file of that device"
        )
    model = TuningModel.for_device(device).with_params(params, args.model != "nominal")
    return dataclasses.replace(model, source=str(args.params))


def _specs_and_bounds(
    args: argparse.Namespace, device: devices.Device
) -> tuple[StepSpecs, GainBounds]:
    """Return the specs and gain bounds: the options', else the file's, else the defaults."""
    table = device.tuning
    specs = {name: table[name] for name, _, _ in SPEC_OPTIONS if name in table}
    specs |= {n: getattr(args, n) for n, _, _ in SPEC_OPTIONS if getattr(args, n) is not None}
    bounds = {gain: tuple(table[gain]) for gain in ("kp", "ki", "kd") if gain in table}
    for gain in ("kp", "ki", "kd"):
        if getattr(args, gain) is not None:
            bounds[gain] = tuple(getattr(args, gain))
    if device.name != devices.ROTARY.name:
        pid = device.paper_gains["pid"]
        for gain in ("kp", "ki", "kd"):
            if gain not in bounds and pid[gain] <= 0:
                raise ValueError(
                    f"{device.name}'s PID has {gain} = 0: give its bounds (--{gain} LOW HIGH "
                    "or the file's [tuning] table)"
                )
            bounds.setdefault(gain, (0.0, 5.0 * pid[gain]))
    try:
        return StepSpecs(**specs), GainBounds(**bounds)
    except (TypeError, ValueError) as error:
        raise ValueError(f"the specs or bounds: {error}") from None


def check_args(args: argparse.Namespace) -> tuple[TuningModel, StepSpecs, GainBounds]:
    """Validate the options and build the model, specs and bounds; raise ValueError if not."""
    if args.samples < 1:
        raise ValueError(f"--samples must be at least 1, got {args.samples}")
    check_seed(args.seed)
    if args.chunk < 1:
        raise ValueError(f"--chunk must be at least 1, got {args.chunk}")
    device = envs.checked_device(args.device)
    specs, bounds = _specs_and_bounds(args, device)
    if args.horizon is None:
        args.horizon = max(DEFAULT_HORIZON, 2.0 * specs.settling_time)
    if not (math.isfinite(args.horizon) and args.horizon > specs.settling_time):
        raise ValueError(
            f"--horizon must be a number of seconds longer than the {specs.settling_time:g} s "
            f"settling-time spec (so settling can be judged), got {args.horizon}"
        )
    return dataclasses.replace(_model(args, device), velocity=args.velocity), specs, bounds


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
    baseline = "paper" if result.model.baseline == PAPER_GAINS else "device's PID"
    rows.append((baseline, {**p, **p["metrics"]}, verdict))
    for label, c, ok in rows:
        lines.append(
            f"{label:<18}{c['kp']:>9.4g}{c['ki']:>9.4g}{c['kd']:>9.4g}"
            f"{_fmt(c['rise_time']):>8}{_fmt(c['peak_time']):>8}{_fmt(c['settling_time']):>9}"
            f"{c['overshoot_pct']:>7.2f}  {ok}"
        )
    paper = (result.model.device, result.specs, result.bounds) == (
        devices.ROTARY.name,
        StepSpecs(),
        GainBounds(),
    )
    found = "; the paper found 328" if paper else ""
    head = f"{f} of {n} candidates feasible ({100 * f / n:.2f} %{found})"
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
        model, specs, bounds = check_args(args)
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
                    specs,
                    bounds,
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
