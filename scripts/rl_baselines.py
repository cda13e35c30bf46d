"""Baselines of the v1 envs: PPO and SAC from scratch beside the PID, the compensated PID and
the residual, on the same episode and reward.

Each RL run trains the shipped hyperparameters (``frictiongym/hyperparams/<algo>.yml``, the
RL Zoo's format) with ``frictiongym.zoo.train`` on the native vector env, then scores its
deterministic policy on one episode of the env as registered (the default task: the servo's
1 rad step, the Altino from 30 cm to 5 cm), the env's v1 reward summed. The controllers are
scored on the same episode: the paper's PID and compensated PID, and the shipped residual
policies (``models/residual``) on the compensated PID. Writes ``baselines.json`` and
``baselines.md`` (mean ± std over the seeds) to ``--out``.

Usage::

    python scripts/rl_baselines.py --out baselines [--algos ppo sac] [--seeds 0 1 2]
        [--envs frictiongym/AltinoDistance-v1 ...] [--steps N]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym import devices, zoo
from frictiongym._io import write_json_atomic, write_text_atomic
from frictiongym.controllers import PID, PIDGains, ResidualController
from frictiongym.controllers.residual_core import make_base

ENVS = ("frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1")
MODELS = Path(__file__).resolve().parent.parent / "models" / "residual"


def controllers(env_id: str) -> dict[str, Any]:
    """The fixed controllers of ``env_id``, each a factory ``env -> controller``."""
    device = devices.get(env_id)
    model = MODELS / f"{device.kind}.zip"
    return {
        "PID (paper gains)": lambda env: PID.for_env(env, PIDGains(**device.paper_gains["pid"])),
        "compensated PID (paper)": make_base,
        f"residual ({model.name}, shipped)": lambda env: ResidualController.load(model, env),
    }


def score_controller(env_id: str, build: Any) -> float:
    """The episode return of a controller built for the env."""
    env = gym.make(env_id)
    controller = build(env)
    controller.reset()
    env.close()
    return zoo.episode_return(env_id, controller)


def run_rl(env_id: str, algo: str, seed: int, steps: int | None) -> dict[str, Any]:
    """Train one seed from scratch and score it."""
    settings = zoo.load(algo, env_id)
    start = time.perf_counter()
    model, env = zoo.train(settings, seed, steps)
    seconds = time.perf_counter() - start
    act = zoo.policy_controller(model, env, settings)
    score = zoo.episode_return(env_id, act, rescale=settings.rescale)
    trained = int(model.num_timesteps)
    print(
        f"  {algo} seed {seed}: return {score:.1f} ({trained} steps, {seconds:.0f} s)", flush=True
    )
    return {"seed": seed, "return": score, "steps": trained, "seconds": round(seconds, 1)}


def table(results: dict[str, Any]) -> str:
    """The markdown table of the results."""
    lines = []
    for env_id, rows in results.items():
        lines += [f"### {env_id}", "", "| controller | episode return | runs |", "|---|---|---|"]
        for name, runs in rows.items():
            values = [r["return"] for r in runs]
            spread = f" ± {statistics.stdev(values):.1f}" if len(values) > 1 else ""
            lines.append(f"| {name} | {statistics.mean(values):.1f}{spread} | {len(values)} |")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="folder of the results")
    parser.add_argument("--envs", nargs="+", default=list(ENVS))
    parser.add_argument("--algos", nargs="+", default=["ppo", "sac"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--steps", type=int, help="env-steps per run (default: the YAML's)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    results: dict[str, Any] = {}
    for env_id in args.envs:
        print(env_id, flush=True)
        rows: dict[str, Any] = {}
        for name, build in controllers(env_id).items():
            rows[name] = [{"return": score_controller(env_id, build)}]
            print(f"  {name}: {rows[name][0]['return']:.1f}", flush=True)
        for algo in args.algos:
            runs = [run_rl(env_id, algo, seed, args.steps) for seed in args.seeds]
            rows[f"{algo.upper()} from scratch"] = runs
        results[env_id] = rows
    command = "python scripts/rl_baselines.py " + " ".join(
        f"--{k} {' '.join(map(str, v)) if isinstance(v, list) else v}"
        for k, v in vars(args).items()
        if v is not None
    )
    write_json_atomic(args.out / "baselines.json", {"command": command, "results": results})
    write_text_atomic(args.out / "baselines.md", f"`{command}`\n\n{table(results)}")
    print(table(results))


if __name__ == "__main__":
    main()
