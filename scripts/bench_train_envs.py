"""Training speed of ``frictiongym train`` with K envs of the native vector env against one.

Runs ``train`` (PPO, the default settings, validation off) on each device for the same wall
time with ``--n-envs 1`` and with each K of ``--n-envs``, alternating them in each round of
one process, and prints the env-steps/s of each and the ratio to ``--n-envs 1`` of the same
round (median and range over the rounds), as markdown for docs/benchmarks.md.

Usage: python scripts/bench_train_envs.py [--seconds 30] [--rounds 2] [--n-envs 8 32]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.residual.train import TrainSettings, train

ENVS = ("frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1")


def rate(env_id: str, n_envs: int, seconds: float, out: Path) -> float:
    """Env-steps/s of one ``train`` run of ``seconds`` (validation off)."""
    settings = TrainSettings(
        env_id=env_id,
        n_envs=n_envs,
        max_time=seconds,
        validate_every=None,
        out=out,
        overwrite=True,
        quiet=True,
    )
    return float(train(settings)["env_steps_per_s"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="budget of each run")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--n-envs", type=int, nargs="+", default=[8, 32])
    args = parser.parse_args()
    lines = [
        f"`python scripts/bench_train_envs.py --seconds {args.seconds:g} --rounds "
        f"{args.rounds} --n-envs {' '.join(map(str, args.n_envs))}`",
        "",
        "| env | --n-envs | env-steps/s, median [min, max] | ratio to --n-envs 1 |",
        "|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as scratch:
        for env_id in ENVS:
            rates: dict[int, list[float]] = {k: [] for k in (1, *args.n_envs)}
            for r in range(args.rounds):
                for k in rates:
                    rates[k].append(rate(env_id, k, args.seconds, Path(scratch) / f"k{k}"))
                    print(f"{env_id} round {r + 1} n_envs {k}: {rates[k][-1]:.0f}", flush=True)
            for k, values in rates.items():
                ratios = [v / one for v, one in zip(values, rates[1], strict=True)]
                lines.append(
                    f"| `{env_id}` | {k} | {statistics.median(values):.0f} [{min(values):.0f}, "
                    f"{max(values):.0f}] | {statistics.median(ratios):.2f} "
                    f"[{min(ratios):.2f}, {max(ratios):.2f}] |"
                )
    print("\n".join(lines))


if __name__ == "__main__":
    main()
