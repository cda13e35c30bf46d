"""Benchmark: env-steps/s of two plain PPO training loops on frictiongym's envs and on gymnasium's.

What a new user tries first, timed on ``frictiongym/RotaryServo-v1``,
``frictiongym/AltinoDistance-v1``, ``CartPole-v1`` and ``Pendulum-v1`` in the same rounds:

* **sb3**: Stable-Baselines3 ``PPO("MlpPolicy", gym.make(id))`` with its defaults (2 048-step
  rollouts, 10 epochs of batch 64, torch's default threads); one cycle is
  ``model.learn(2048)``: a rollout and an update.
* **cleanrl-style**: a PPO loop written here in the shape of CleanRL's
  ``ppo_continuous_action.py`` (no code taken from it): one env in a ``SyncVectorEnv`` with
  the usual wrappers (episode statistics; for Box actions, action clipping and observation and
  reward normalisation with clipping to ±10), a 64-64 tanh actor and critic, 2 048-step
  rollouts with a forward pass per step, then GAE (0.99, 0.95) and 10 epochs of 32 minibatches
  of clipped-objective updates with Adam (3e-4) and gradient clipping at 0.5. CartPole gets a
  categorical actor and no normalisation, as CleanRL's discrete ``ppo.py``.

The figure is env-steps/s of whole cycles (rollout and update, as the user sees it), and the
ratios are ours / ``CartPole-v1`` and ours / ``Pendulum-v1`` per round. Loads (``--loads``):
``quiet`` and ``learner`` (a torch process on 2 threads beside the run; scripts/_load.py).
Timing: a burn-in cycle of every variant, then ``--repeats`` rounds of one cycle of every
variant, in an order rotated every round; medians with [min, max]. Torch runs on
``--torch-threads`` (default 1) in every loop, set before every cycle.

Run ``python scripts/bench_rl_loops.py --help`` for the options.
"""

from __future__ import annotations

import argparse
import datetime
import shlex
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import _load
import gymnasium as gym
import numpy as np
from _bench import Runner, machine_line, paired_ratios, ratio_stats, source_revision, stats, timed

import frictiongym  # noqa: F401  (registers the frictiongym ids)

OURS = ("frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1")
REFERENCES = ("CartPole-v1", "Pendulum-v1")
ENVS = OURS + REFERENCES
LOOPS = ("sb3", "cleanrl-style")
LOADS = ("quiet", "learner")


@dataclass
class Variant:
    """One loop on one env: a runner of whole cycles and the rates it measured."""

    loop: str
    env: str
    run: Runner
    batch: int  #: env-steps per cycle
    rates: list[float] = field(default_factory=list)


def sb3_runner(env_id: str, rollout: int, seed: int, threads: int) -> Runner:
    """SB3 PPO with its defaults on ``gym.make(env_id)``; a cycle is ``learn(rollout)``."""
    import torch
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", gym.make(env_id), n_steps=rollout, seed=seed, device="cpu")

    def run(cycles: int) -> None:
        torch.set_num_threads(threads)  # numba's OpenMP start may have changed it
        model.learn(cycles * rollout, reset_num_timesteps=False)

    return run


def make_env(env_id: str, gamma: float) -> gym.Env[Any, Any]:
    """One env with the wrappers of a CleanRL-style script."""
    env: gym.Env[Any, Any] = gym.wrappers.RecordEpisodeStatistics(gym.make(env_id))
    if isinstance(env.action_space, gym.spaces.Box):
        env = gym.wrappers.ClipAction(env)
        env = gym.wrappers.NormalizeObservation(env)
        env = gym.wrappers.TransformObservation(
            env, lambda obs: np.clip(obs, -10.0, 10.0), env.observation_space
        )
        env = gym.wrappers.NormalizeReward(env, gamma=gamma)
        env = gym.wrappers.TransformReward(env, lambda r: float(np.clip(r, -10.0, 10.0)))
    return env


class PPOLoop:
    """A minimal CleanRL-shaped PPO on one env: rollout of ``steps``, then the update."""

    gamma, lam, clip, epochs, minibatches = 0.99, 0.95, 0.2, 10, 32

    def __init__(self, env_id: str, steps: int, seed: int, threads: int) -> None:
        import torch
        from torch import nn

        self.torch, self.steps, self.threads = torch, steps, threads
        torch.manual_seed(seed)
        self.envs = gym.vector.SyncVectorEnv([lambda: make_env(env_id, self.gamma)])
        space = self.envs.single_action_space
        self.discrete = isinstance(space, gym.spaces.Discrete)
        obs_size = int(np.prod(self.envs.single_observation_space.shape))
        out = int(space.n) if self.discrete else int(np.prod(space.shape))

        def mlp(last: int, scale: float) -> nn.Sequential:
            net = nn.Sequential(
                nn.Linear(obs_size, 64),
                nn.Tanh(),
                nn.Linear(64, 64),
                nn.Tanh(),
                nn.Linear(64, last),
            )
            for layer in net[::2]:
                nn.init.orthogonal_(layer.weight, np.sqrt(2.0))
                nn.init.zeros_(layer.bias)
            nn.init.orthogonal_(net[-1].weight, scale)
            return net

        self.critic, self.actor = mlp(1, 1.0), mlp(out, 0.01)
        self.log_std = nn.Parameter(torch.zeros(1, out))
        parameters = [*self.critic.parameters(), *self.actor.parameters(), self.log_std]
        self.parameters = parameters
        self.optimizer = torch.optim.Adam(parameters, lr=3e-4, eps=1e-5)
        self.obs = torch.zeros((steps, 1, obs_size))
        self.actions = torch.zeros((steps, 1) + (() if self.discrete else (out,)))
        self.logprobs, self.rewards, self.dones, self.values = (
            torch.zeros((steps, 1)) for _ in range(4)
        )
        next_obs, _ = self.envs.reset(seed=seed)
        self.next_obs = torch.as_tensor(next_obs, dtype=torch.float32)
        self.next_done = torch.zeros(1)

    def policy(self, obs: Any, action: Any = None) -> tuple[Any, Any, Any, Any]:
        """Action (sampled if not given), its log-probability, the entropy and the value."""
        torch = self.torch
        out = self.actor(obs)
        if self.discrete:
            dist: Any = torch.distributions.Categorical(logits=out)
        else:
            dist = torch.distributions.Normal(out, self.log_std.expand_as(out).exp())
        if action is None:
            action = dist.sample()
        logprob, entropy = dist.log_prob(action), dist.entropy()
        if not self.discrete:
            logprob, entropy = logprob.sum(1), entropy.sum(1)
        return action, logprob, entropy, self.critic(obs).flatten()

    def __call__(self, cycles: int) -> None:
        self.torch.set_num_threads(self.threads)  # numba's OpenMP start may have changed it
        for _ in range(cycles):
            self.rollout()
            self.update()

    def rollout(self) -> None:
        """Collect ``steps`` env-steps with a forward pass per step."""
        torch = self.torch
        for t in range(self.steps):
            self.obs[t], self.dones[t] = self.next_obs, self.next_done
            with torch.no_grad():
                action, logprob, _, value = self.policy(self.next_obs)
            self.values[t], self.actions[t], self.logprobs[t] = value, action, logprob
            obs, reward, terminated, truncated, _ = self.envs.step(action.numpy())
            self.rewards[t] = torch.as_tensor(reward, dtype=torch.float32)
            self.next_obs = torch.as_tensor(obs, dtype=torch.float32)
            self.next_done = torch.as_tensor(terminated | truncated, dtype=torch.float32)

    def update(self) -> None:
        """GAE, then clipped-objective epochs over minibatches."""
        torch = self.torch
        with torch.no_grad():
            next_value = self.critic(self.next_obs).flatten()
            advantages = torch.zeros_like(self.rewards)
            last = torch.zeros(1)
            for t in reversed(range(self.steps)):
                done = self.next_done if t == self.steps - 1 else self.dones[t + 1]
                value = next_value if t == self.steps - 1 else self.values[t + 1]
                delta = self.rewards[t] + self.gamma * value * (1 - done) - self.values[t]
                last = delta + self.gamma * self.lam * (1 - done) * last
                advantages[t] = last
            returns = advantages + self.values
        obs, actions = self.obs.flatten(0, 1), self.actions.flatten(0, 1)
        logprobs, adv, ret = (x.flatten() for x in (self.logprobs, advantages, returns))
        size = self.steps // self.minibatches
        for _ in range(self.epochs):
            order = torch.randperm(self.steps)
            for start in range(0, self.steps, size):
                idx = order[start : start + size]
                _, new_logprob, _entropy, value = self.policy(obs[idx], actions[idx])
                ratio = (new_logprob - logprobs[idx]).exp()
                a = adv[idx]
                a = (a - a.mean()) / (a.std() + 1e-8)
                policy_loss = torch.max(
                    -a * ratio, -a * ratio.clamp(1 - self.clip, 1 + self.clip)
                ).mean()
                loss = policy_loss + 0.5 * ((value - ret[idx]) ** 2).mean()
                self.optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(self.parameters, 0.5)
                self.optimizer.step()


def build_parser() -> argparse.ArgumentParser:
    """Command-line options."""
    parser = argparse.ArgumentParser(
        prog="bench_rl_loops.py",
        description=(
            "Env-steps/s of SB3 PPO and of a CleanRL-style PPO loop (rollout and update) on "
            "frictiongym's two envs against CartPole-v1 and Pendulum-v1, timed interleaved in "
            "one process, quiet and beside a torch learner process; ratios ours / reference "
            "per round."
        ),
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="timed rounds per load (default: 3; with --quick: 1)",
    )
    parser.add_argument(
        "--rollout",
        type=int,
        default=None,
        help="env-steps per cycle (rollout, then update) (default: 2048; with --quick: 256)",
    )
    parser.add_argument(
        "--loads",
        nargs="+",
        choices=LOADS,
        default=list(LOADS),
        help=f"competing load: quiet: {_load.LOAD_NOTES['quiet']}; learner: "
        f"{_load.LOAD_NOTES['learner']} (default: both)",
    )
    parser.add_argument(
        "--loops", nargs="+", choices=LOOPS, default=list(LOOPS), help="loops (default: both)"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run (about a minute): smaller defaults for --repeats and --rollout (explicit "
        "values still win); the figures are then too noisy to quote",
    )
    parser.add_argument(
        "--torch-threads",
        type=int,
        default=1,
        metavar="N",
        help="torch's threads in the loops, set before every cycle (default: 1, as frictiongym "
        "train for PPO; with torch's default of one per core every loop, ours and gymnasium's "
        "alike, ran 20-45 times slower beside the learner process)",
    )
    parser.add_argument("--markdown", action="store_true", help="also print markdown tables")
    parser.add_argument("--seed", type=int, default=0, help="seed of the runs (default: 0)")
    return parser


def variants_for(loops: Sequence[str], rollout: int, seed: int, threads: int) -> list[Variant]:
    """Every loop on every env, fresh."""
    out = []
    for loop in loops:
        for env_id in ENVS:
            run = (
                sb3_runner(env_id, rollout, seed, threads)
                if loop == "sb3"
                else PPOLoop(env_id, rollout, seed, threads)
            )
            out.append(Variant(loop, env_id, run, rollout))
    return out


def rounds(variants: Sequence[Variant], repeats: int) -> None:
    """A burn-in cycle of each variant, then ``repeats`` rounds of one timed cycle each."""
    for variant in variants:
        variant.run(1)
    for r in range(repeats):
        shift = r % len(variants)
        for variant in [*variants[shift:], *variants[:shift]]:
            variant.rates.append(variant.batch / timed(variant.run, 1))


def find(variants: Sequence[Variant], loop: str, env_id: str) -> Variant:
    """The variant of ``loop`` on ``env_id``."""
    return next(v for v in variants if v.loop == loop and v.env == env_id)


def report(load: str, variants: Sequence[Variant]) -> list[str]:
    """Print and return the markdown rows of one load."""
    rows = []
    for v in variants:
        cells = []
        for ref in REFERENCES:
            cells.append(
                "1 (reference)"
                if v.env == ref
                else ratio_stats(paired_ratios(v, find(variants, v.loop, ref)))
            )
        print(
            f"  {load:8s} {v.loop:14s} {v.env:30s} {stats(v.rates):24s} "
            f"x CartPole {cells[0]:22s} x Pendulum {cells[1]}"
        )
        rows.append(
            f"| {load} | {v.loop} | `{v.env}` | {stats(v.rates)} | {cells[0]} | {cells[1]} |"
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the results; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    repeats = args.repeats or (1 if args.quick else 3)
    rollout = args.rollout or (256 if args.quick else 2048)
    if repeats < 1 or rollout < 64 or rollout % PPOLoop.minibatches:
        parser.error(f"repeats must be >= 1 and rollout a multiple of {PPOLoop.minibatches} >= 64")
    if not _load.import_torch_first():
        parser.error("this benchmark needs torch and stable-baselines3 (pip install -e '.[test]')")
    shown_argv = sys.argv[1:] if argv is None else argv
    print(f"command: {shlex.join(['python', 'scripts/bench_rl_loops.py', *shown_argv])}")
    print(f"date:    {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}")
    print(f"machine: {machine_line()}")
    print(f"source:  frictiongym {source_revision()}")
    import stable_baselines3
    import torch

    print(
        f"torch {torch.__version__} ({args.torch_threads} threads), stable-baselines3 "
        f"{stable_baselines3.__version__}; {repeats} rounds of one {rollout}-step cycle per "
        "variant; env-steps/s, median [min, max]"
    )
    warnings.filterwarnings("ignore", category=UserWarning)  # SB3's and gymnasium's advice
    start = time.perf_counter()
    rows = []
    for load in args.loads:
        with _load.competing(load):
            variants = variants_for(args.loops, rollout, args.seed, args.torch_threads)
            rounds(variants, repeats)
            rows += report(load, variants)
    print(f"\nwall time of the benchmark: {time.perf_counter() - start:.0f} s")
    if args.markdown:
        print()
        print(
            f"| load | loop | env | env-steps/s, median [min, max] of {repeats} | "
            "ratio to CartPole-v1 | ratio to Pendulum-v1 |"
        )
        print("|---|---|---|---|---|---|")
        print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
