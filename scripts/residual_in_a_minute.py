"""Residual policies trained in a minute each, and the benchmark's held-out evaluation of them.

For each device and seed, ``frictiongym train --max-time SECONDS`` (the defaults otherwise:
PPO on 32 envs of the native vector env), one run at a time; then the benchmark's residual
group on each seed's ``best.zip`` and on the shipped policies (``models/residual``), on the
nominal plant and ``--heldout`` held-out plants (seeds from 2000, as docs/results.md). Writes
``summary.md`` to ``--out`` with, per run, the validation score of ``best.zip``, when it first
beat the compensated PID (``best_score < 1``), the training speed, and the held-out means
against the compensated PID.

Usage: python scripts/residual_in_a_minute.py --out runs/minute [--seconds 60] [--seeds 0 1 2]
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import Any

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.cli import main as cli
from frictiongym.residual.train import TrainSettings, train

DEVICES = {"rotary": "frictiongym/RotaryServo-v1", "altino": "frictiongym/AltinoDistance-v1"}
SHIPPED = Path(__file__).resolve().parent.parent / "models" / "residual"


def first_win(run: Path) -> str:
    """When the validation score first fell below 1: seconds and steps, or "never"."""
    with (run / "validation.csv").open() as file:
        for row in csv.DictReader(file):
            if float(row["score"]) < 1.0:
                return f"{float(row['time_s']):.0f} s ({int(float(row['steps'])):,} steps)"
    return "never"


def heldout(results: Path, device: str) -> dict[str, Any]:
    """Means over the held-out plants of ITAE and SSE, each controller, and the residual's wins."""
    records = json.loads(results.read_text())
    runs: dict[str, dict[int, dict[str, Any]]] = {"compensated": {}, "residual": {}}
    for r in records:
        name = r["scenario"]
        if name.startswith(f"residual-{device}-heldout-"):
            runs[name.rsplit("-", 1)[1]][r["seed"]] = r
    seeds = sorted(runs["residual"])
    out: dict[str, Any] = {"plants": len(seeds)}
    for metric in ("itae", "steady_state_error"):
        pairs = [
            (runs["compensated"][s]["metrics"][metric], runs["residual"][s]["metrics"][metric])
            for s in seeds
        ]
        out[metric] = (sum(c for c, _ in pairs) / len(pairs), sum(r for _, r in pairs) / len(pairs))
        out[f"{metric}_wins"] = sum(r < c for c, r in pairs)
    out["terminated"] = sum(runs["residual"][s]["terminated"] for s in seeds)
    return out


def benchmark(models: dict[str, Path], out: Path, plants: int) -> Path:
    """Run the benchmark's residual group on ``models``; return its results.json."""
    args = ["benchmark", "--group", "residual", "--heldout", str(plants), "--heldout-seed", "2000"]
    for device, model in models.items():
        args += ["--residual", f"{device}={model}"]
    status = cli([*args, "--out", str(out), "--no-figures", "--quiet", "--overwrite"])
    if status != 0:
        raise SystemExit(f"the benchmark failed with status {status}")
    return out / "results.json"


def row(label: str, summary: dict[str, Any] | None, run: Path | None, held: dict[str, Any]) -> str:
    itae, sse = held["itae"], held["steady_state_error"]
    trained = (
        f"{summary['best_score']:.3f} | {first_win(run)} | {summary['steps']:,} | "
        f"{summary['env_steps_per_s']:,.0f} | {summary['wall_time_s']:.0f} s"
        if summary is not None and run is not None
        else "| | | |"
    )
    n = held["plants"]
    return (
        f"| {label} | {trained} | {itae[0]:.4g} → {itae[1]:.4g} | {held['itae_wins']}/{n} | "
        f"{sse[0]:.4g} → {sse[1]:.4g} | {held['steady_state_error_wins']}/{n} | "
        f"{held['terminated']} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--seconds", type=float, default=60.0, help="each training's budget")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--heldout", type=int, default=50, help="held-out plants")
    args = parser.parse_args()
    summaries: dict[tuple[str, int], dict[str, Any]] = {}
    for device, env_id in DEVICES.items():
        for seed in args.seeds:
            run = args.out / f"{device}-s{seed}"
            settings = TrainSettings(
                env_id=env_id, seed=seed, max_time=args.seconds, out=run, overwrite=True, quiet=True
            )
            summaries[device, seed] = train(settings)
            print(f"{device} seed {seed}: best {summaries[device, seed]['best_score']}", flush=True)
    lines = [
        f"`python scripts/residual_in_a_minute.py --out {args.out} --seconds {args.seconds:g} "
        f"--seeds {' '.join(map(str, args.seeds))} --heldout {args.heldout}`",
        "",
        "| policy | best validation score | first below 1 | steps | env-steps/s | wall time "
        "| ITAE comp. → resid. | wins | SSE comp. → resid. | wins | terminated |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for seed in args.seeds:
        models = {d: args.out / f"{d}-s{seed}" / "best.zip" for d in DEVICES}
        results = benchmark(models, args.out / f"bench-s{seed}", args.heldout)
        for device in DEVICES:
            run = args.out / f"{device}-s{seed}"
            lines.append(
                row(f"{device} seed {seed}", summaries[device, seed], run, heldout(results, device))
            )
    shipped = benchmark(
        {d: SHIPPED / f"{d}.zip" for d in DEVICES}, args.out / "bench-shipped", args.heldout
    )
    for device in DEVICES:
        lines.append(row(f"{device} shipped (300 000 steps)", None, None, heldout(shipped, device)))
    text = "\n".join(lines) + "\n"
    (args.out / "summary.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
