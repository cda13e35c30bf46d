"""Candidates per second of `frictiongym tune` vs python-control on the same candidates.

python scripts/bench_tune.py --continuous 2000

The reference is what a python-control user would run per candidate: build the tuner's
closed loop (frictiongym.tuning.reference.sampled_data_loop: c2d ZOH plant + the PID as our
PID computes it) and call step_info (which calls step_response) on the same 2 ms grid. It
runs on a subsample of the tuner's candidates (it is slow); the tuner runs on all of them,
in chunks as `tune` does, on the nominal model (the reference's model) and, for itself only,
on the friction model, with the filtered velocity and without early stopping. Rounds
interleave the variants; each ratio is the median of the per-round ratios to python-control
timed in the same round.

With --continuous N, python-control also judges N candidates of the same seed on the two
continuous-time loops (derivative on the velocity, derivative on the error as MATLAB's pid)
to show how much the loop structure moves the feasible fraction (not timed).
"""

from __future__ import annotations

import os

# python-control's small matrix products run faster on one BLAS thread (6.9 instead of 10-14 ms
# per candidate here, and no spinning BLAS threads to slow the numba kernel that follows).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import _bench  # the scripts' folder is first on sys.path (python scripts/bench_tune.py)
import numpy as np

from frictiongym.tuning import GainBounds, StepSpecs, TuningModel, simulate
from frictiongym.tuning import reference as ref
from frictiongym.tuning.evaluate import horizon_steps
from frictiongym.tuning.search import DEFAULT_CHUNK, DEFAULT_HORIZON

#: A box around the nominal model's feasible set (docs/tuning.md): most draws lie near a spec.
NEAR = GainBounds(kp=(8.5, 10.0), ki=(0.0, 5.0), kd=(0.17, 0.27))


@dataclass
class Variant:
    name: str
    batch: int
    run: object
    rates: list[float] = field(default_factory=list)


def tuner(gains: np.ndarray, model: TuningModel, specs: StepSpecs, early_stop: bool):
    def run() -> None:
        for lo in range(0, gains.shape[0], DEFAULT_CHUNK):
            simulate(
                gains[lo : lo + DEFAULT_CHUNK], model, specs, DEFAULT_HORIZON, early_stop=early_stop
            )

    return run


def python_control(gains: np.ndarray, model: TuningModel, specs: StepSpecs):
    t = np.arange(horizon_steps(DEFAULT_HORIZON, model.dt) + 1) * model.dt

    def run() -> None:
        systems = [ref.sampled_data_loop(tuple(g), model.plant, model.dt) for g in gains]
        ref.step_info_metrics(systems, t, specs)

    return run


def agreement(gains: np.ndarray, specs: StepSpecs) -> str:
    """Feasibility and metrics of the tuner vs python-control on ``gains`` (linear loop)."""
    model = TuningModel()
    ours = simulate(gains, model, specs, DEFAULT_HORIZON, early_stop=False)
    systems = [ref.sampled_data_loop(tuple(g), model.plant, model.dt) for g in gains]
    theirs = ref.step_info_metrics(systems, ours.t, specs)
    feasible = specs.feasible(theirs)
    linear = ours.peak_command < model.plant.command_limit  # the reference has no saturation
    both = (ours.feasible | feasible) & linear
    diffs = {
        name: float(
            np.max(
                np.abs(getattr(ours.metrics, name)[both] - getattr(theirs, name)[both]), initial=0.0
            )
        )
        for name in ("rise_time", "peak_time", "settling_time", "overshoot_pct")
    }
    return (
        f"{int(np.sum((ours.feasible == feasible) & linear))} of {int(linear.sum())} verdicts "
        f"agree (feasible: tuner {int(ours.feasible[linear].sum())}, python-control "
        f"{int(feasible[linear].sum())}; {len(gains) - int(linear.sum())} candidates that reach "
        "the ±10 V limit, which the linear reference lacks, left out); largest difference on "
        "the candidates feasible in either: " + ", ".join(f"{k} {v:.3g}" for k, v in diffs.items())
    )


def continuous(n: int, seed: int, specs: StepSpecs) -> list[str]:
    gains = GainBounds().sample(np.random.default_rng(seed), n)
    model = TuningModel()
    t = np.arange(horizon_steps(DEFAULT_HORIZON, model.dt) + 1) * model.dt
    lines = [f"Feasible fraction of {n} candidates (seed {seed}) by loop structure:", ""]
    lines += ["| loop | feasible | fraction |", "|---|---:|---:|"]
    for label, velocity in (("the tuner's default", "ideal"), ("the env's loop", "filtered")):
        ours = simulate(gains, model.replace(velocity=velocity), specs, DEFAULT_HORIZON).feasible
        lines.append(
            f"| sampled-data, D on {velocity} velocity ({label}) | {int(ours.sum())} | "
            f"{ours.mean():.2%} |"
        )
    for label, build in (
        ("continuous, D on velocity", ref.continuous_loop),
        ("continuous, D on error (MATLAB pid)", ref.continuous_error_derivative_loop),
    ):
        ok = specs.feasible(
            ref.step_info_metrics([build(tuple(g), model.plant) for g in gains], t, specs)
        )
        lines.append(f"| {label} | {int(ok.sum())} | {ok.mean():.2%} |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--samples",
        type=int,
        default=100_000,
        help="candidates for the tuner (default: 100000, as tune)",
    )
    parser.add_argument(
        "--reference-samples",
        type=int,
        default=200,
        help="of them, candidates for python-control (default: 200)",
    )
    parser.add_argument("--repeats", type=int, default=5, help="rounds (default: 5)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the candidates (default: 0)")
    parser.add_argument(
        "--continuous",
        type=int,
        default=0,
        metavar="N",
        help="also judge N candidates on the continuous loops (slow: ~5 ms each)",
    )
    parser.add_argument(
        "--agreement",
        type=int,
        default=500,
        metavar="N",
        help="also compare verdicts on N candidates drawn near the feasible "
        "set (default: 500; 0: skip)",
    )
    parser.add_argument("--json", type=Path, metavar="PATH", help="also write the rates here")
    args = parser.parse_args()
    if min(args.samples, args.reference_samples, args.repeats) < 1:
        parser.error("--samples, --reference-samples and --repeats must be at least 1")

    specs = StepSpecs()
    gains = GainBounds().sample(np.random.default_rng(args.seed), args.samples)
    pick = np.random.default_rng(args.seed + 1).choice(
        args.samples, min(args.reference_samples, args.samples), replace=False
    )
    sub = gains[np.sort(pick)]
    nominal, friction = TuningModel(), TuningModel.paper(with_friction=True)
    full = gains[: max(1, args.samples // 10)]
    variants = [
        Variant(
            "python-control step_info (sampled-data loop)",
            len(sub),
            python_control(sub, nominal, specs),
        ),
        Variant("tune, nominal", len(gains), tuner(gains, nominal, specs, True)),
        Variant("tune, friction", len(gains), tuner(gains, friction, specs, True)),
        Variant(
            "tune, nominal, filtered velocity",
            len(gains),
            tuner(gains, nominal.replace(velocity="filtered"), specs, True),
        ),
        Variant("tune, nominal, no early stop", len(full), tuner(full, nominal, specs, False)),
    ]
    start = time.perf_counter()
    for v in variants:  # warm-up: numba's cache, thread pool, python-control imports
        v.run()  # type: ignore[operator]
    for r in range(args.repeats):
        order = variants[r % len(variants) :] + variants[: r % len(variants)]
        for v in order:
            tic = time.perf_counter()
            v.run()  # type: ignore[operator]
            v.rates.append(v.batch / (time.perf_counter() - tic))
    reference = variants[0]

    print(f"- **Command:** python scripts/bench_tune.py {' '.join(sys.argv[1:])}".rstrip())
    print(f"- **Date:** {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    print(f"- **Machine:** {_bench.machine_line()}")
    print(f"- **Source:** frictiongym {_bench.source_revision()}")
    print(
        f"- **Candidates:** {args.samples} (seed {args.seed}), python-control on "
        f"{len(sub)} of them; horizon {DEFAULT_HORIZON:g} s, dt 2 ms, chunks of "
        f"{DEFAULT_CHUNK}"
    )
    print(f"- **Agreement on the python-control subsample:** {agreement(sub, specs)}")
    if args.agreement:
        near = NEAR.sample(np.random.default_rng(args.seed + 2), args.agreement)
        print(
            f"- **Agreement on {args.agreement} candidates near the feasible set** "
            f"(Kp {NEAR.kp}, Ki {NEAR.ki}, Kd {NEAR.kd}): {agreement(near, specs)}"
        )
    print("")
    print(
        f"| variant | candidates | candidates/s, median [min, max] of {args.repeats} | "
        "ratio to python-control, median [min, max] |"
    )
    print("|---|---:|---|---|")
    out = {}
    for v in variants:
        ratios = _bench.paired_ratios(v, reference)
        rr = "1 (reference)" if v is reference else _bench.ratio_stats(ratios)
        print(f"| {v.name} | {_bench.thousands(v.batch)} | {_bench.stats(v.rates)} | {rr} |")
        out[v.name] = {
            "candidates": v.batch,
            "rates": v.rates,
            "ratios": ratios,
            "median_ratio": statistics.median(ratios),
        }
    if args.continuous:
        print("")
        print("\n".join(continuous(args.continuous, args.seed, specs)))
    print(f"\n(total {time.perf_counter() - start:.0f} s)")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    headline = statistics.median(_bench.paired_ratios(variants[1], reference))
    print(
        f"\ntune / python-control, nominal: {headline:.3g}x (goal >= 100x: "
        f"{'meets' if headline >= 100 else 'misses'})"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
