"""PPO's update on the residual env with 1 and 2 torch threads, after the env's first step.

The env's numba kernels start numba's OpenMP threading layer at their first step, which sets
the OpenMP thread count that torch shares to numba's (2 here), whatever
``torch.set_num_threads`` or ``OMP_NUM_THREADS`` said before. ``frictiongym train`` therefore
sets torch's threads again before every update (``--threads``, default 1). This script
shows why: it collects one 2048-step rollout of PPO on the servo's residual env, then times
``PPO.train()`` (10 epochs of batch 64 on that rollout) from the same saved weights,
alternating 1 and 2 threads, in one process. It also reports what numba's first step did to
torch's thread count. ``--busy 1`` runs the timings while another process spins on one core,
as a second training side by side would.

Usage: python scripts/bench_training.py [--repeats 4] [--busy 0]
"""

from __future__ import annotations

import argparse
import copy
import statistics
import subprocess
import sys
import time

import gymnasium as gym
import torch
from stable_baselines3 import PPO

import frictiongym  # noqa: F401
from frictiongym.residual import ResidualEnv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=4, help="timings per thread count")
    parser.add_argument("--busy", type=int, default=0, help="spinning processes alongside")
    args = parser.parse_args()
    spinners = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)
    ]
    try:
        measure(args.repeats)
    finally:
        for spinner in spinners:
            spinner.kill()
            spinner.wait()


def measure(repeats: int) -> None:
    """Print torch's threads after the first env step and the PPO update timings."""
    torch.set_num_threads(1)
    env = ResidualEnv(gym.make("frictiongym/RotaryServo-v1", reference="random_steps"))
    before = torch.get_num_threads()
    env.reset(seed=0)
    env.step([0.0])  # the first numba call
    after = torch.get_num_threads()
    print(f"torch threads: {before} set, {after} after the env's first step")

    model = PPO("MlpPolicy", env, n_steps=2048, batch_size=64, seed=0, device="cpu")
    model.learn(2048)  # one rollout, one update; the buffer keeps the rollout
    weights = copy.deepcopy(model.policy.state_dict())
    optimizer = copy.deepcopy(model.policy.optimizer.state_dict())
    times: dict[int, list[float]] = {1: [], 2: []}
    for _ in range(repeats):
        for threads in times:
            torch.set_num_threads(threads)
            model.policy.load_state_dict(weights)
            model.policy.optimizer.load_state_dict(optimizer)
            start = time.perf_counter()
            model.train()
            times[threads].append(time.perf_counter() - start)
    one, two = statistics.median(times[1]), statistics.median(times[2])
    print(f"PPO.train() median over {repeats}: 1 thread {one:.2f} s, 2 threads {two:.2f} s")
    print(f"ratio 2 threads / 1 thread: {two / one:.2f}")


if __name__ == "__main__":
    main()
