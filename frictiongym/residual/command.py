"""``frictiongym train``: train a residual policy on top of the compensated PID."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from frictiongym._io import add_output_arguments
from frictiongym.residual.selection import VALIDATION_PLANTS
from frictiongym.residual.train import QUICK_STEPS, REWARDS, TrainingError, TrainSettings, train

DESCRIPTION = f"""\
Train a residual policy with Stable-Baselines3 (SAC, TD3 or PPO): the applied command is
the paper's friction-compensated PID plus a learned correction bounded by --scale times the
action limit (default 10 % for the servo, 20 % for the Altino). Training runs on random
set-point steps, on plants whose friction, inertia, damping and sensor gain are drawn anew
at every episode (--randomize default), K envs of the native vector env stepped in one
compiled call (seeds S+i; K = 32 for PPO, 1 for SAC and TD3 by default). --max-time SECONDS
stops the run in time for a last validation and keeps the best policy.

Writes to --out: model.zip (load it with
frictiongym.controllers.ResidualController.load(PATH, env)), train.json (settings, wall
time, steps/s, versions), checkpoints/ every --checkpoint-every steps, TensorBoard logs in
tb/ (tensorboard --logdir DIR/tb; CSV in logs/ without tensorboard), and for SAC and TD3
the replay buffer. --resume continues from the newest checkpoint, or from a given zip, up
to --steps in total, in place. Otherwise an --out holding an earlier run's outputs is
refused unless --overwrite replaces them (all of them: no old validation.csv row or best.zip
stays). Ctrl-C saves a checkpoint of the steps so far, which --resume continues.

Every --validate-every steps the policy runs the benchmark's step on validation plants
(seeds 500 and up; the benchmark holds out 1000 and up) next to the compensated PID; the
best-scoring policy is saved as best.zip and every score goes to validation.csv.

Needs the rl extra: pip install "frictiongym[rl]". Training speeds and the time a residual
takes to beat the compensated PID are in docs/residual.md.

Smoke run (under a minute):  frictiongym train --env frictiongym/RotaryServo-v1 --quick
(--quick: {QUICK_STEPS["ppo"]} PPO steps or {QUICK_STEPS["sac"]} SAC/TD3 steps unless --steps says).
"""


def positive_count(text: str) -> int:
    """Argparse type of a count: a whole number >= 1, or a one-line error."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _hyperparameter(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep or not key.isidentifier():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        raise argparse.ArgumentTypeError(
            f'the value of {key} is not JSON: {value!r} (strings need quotes: {key}="...")'
        ) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the command's options to ``parser``."""
    add_training_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="seed (default 0)")
    add_output_arguments(parser, "residual-results", "the model, logs and checkpoints")
    parser.add_argument(
        "--resume",
        nargs="?",
        const="latest",
        metavar="PATH",
        help="continue training: from the newest checkpoint in --out (no PATH) or a model zip",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar; only errors")


def add_training_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options that say what is trained (all but seed, output, resume and quiet).

    ``frictiongym sweep`` takes them too, for every trial (:func:`settings_from_args`).
    """
    parser.add_argument(
        "--env",
        "--device",
        dest="env",
        required=True,
        metavar="ID|FILE",
        help="a frictiongym id (frictiongym/RotaryServo-v1, frictiongym/AltinoDistance-v1) or "
        "a device description file (docs/devices.md)",
    )
    parser.add_argument(
        "--algo", choices=("ppo", "sac", "td3"), default="ppo", help="SB3 algorithm (default ppo)"
    )
    parser.add_argument(
        "--steps",
        type=positive_count,
        metavar="N",
        help="total env-steps of the model (default 200000; with --quick see above)",
    )
    parser.add_argument(
        "--randomize",
        choices=("none", "default"),
        default="default",
        help="domain randomisation of friction, inertia, damping and sensor gain at every "
        "episode (default) or the nominal plant only (none)",
    )
    parser.add_argument(
        "--scale",
        type=float,
        metavar="FRACTION",
        help="residual bound as a fraction of the action limit (default 0.1 servo, 0.2 Altino)",
    )
    parser.add_argument("--quick", action="store_true", help="a smoke run of under a minute")
    parser.add_argument(
        "--n-envs",
        type=positive_count,
        metavar="K",
        help="envs of the native vector env, stepped in one compiled call (default 32 for PPO, "
        "1 for SAC and TD3)",
    )
    parser.add_argument(
        "--max-time",
        type=float,
        metavar="SECONDS",
        help="wall-time budget of the run: training stops in time for a last validation and "
        "the saves, best.zip kept (without --steps, the budget alone bounds the run)",
    )
    parser.add_argument(
        "--checkpoint-every",
        type=positive_count,
        default=50_000,
        metavar="N",
        help="save a checkpoint every N env-steps (default 50000)",
    )
    parser.add_argument(
        "--reward",
        choices=REWARDS,
        default="precision",
        help="training reward: precision (default): the env's linear tracking term replaced "
        "by -log(1 + |e| / one sensor step), which weighs the few counts friction leaves "
        "about as much as a transient; or env: the env's own (docs/residual.md)",
    )
    parser.add_argument(
        "--residual-cost",
        type=float,
        default=0.0,
        metavar="W",
        help="subtract W (residual / bound)^2 from each step's reward (default 0)",
    )
    parser.add_argument(
        "--sb3",
        action="append",
        default=[],
        type=_hyperparameter,
        metavar="KEY=VALUE",
        help="an SB3 constructor argument, VALUE in JSON (repeatable), e.g. --sb3 gamma=0.995 "
        "--sb3 use_sde=true --sb3 'policy_kwargs={\"log_std_init\": -2}'",
    )
    parser.add_argument(
        "--validate-every",
        type=int,
        metavar="N",
        help="score the policy on validation plants every N env-steps and keep the best as "
        "best.zip (default 10000 with fewer than 8 envs, 30000 from 8; 0: never)",
    )
    parser.add_argument(
        "--validation-plants",
        type=positive_count,
        default=VALIDATION_PLANTS,
        metavar="V",
        help=f"randomised validation plants besides the nominal one (default {VALIDATION_PLANTS})",
    )
    parser.add_argument(
        "--threads",
        type=positive_count,
        metavar="N",
        help="torch threads (default 1 for PPO, whose networks are too small to gain from "
        "more; every core for SAC and TD3). Give 1 to run trainings side by side",
    )


def settings_from_args(args: argparse.Namespace, **given: Any) -> TrainSettings:
    """Return the :class:`TrainSettings` of the options of :func:`add_training_arguments`.

    ``given`` sets the other fields (``seed``, ``out``, ``resume``...).
    """
    return TrainSettings(
        env_id=args.env,
        algo=args.algo,
        steps=args.steps,
        randomize=args.randomize,
        quick=args.quick,
        n_envs=args.n_envs,
        max_time=args.max_time,
        checkpoint_every=args.checkpoint_every,
        scale=args.scale,
        reward=args.reward,
        residual_cost=args.residual_cost,
        hyperparameters=dict(args.sb3),
        validate_every="auto" if args.validate_every is None else args.validate_every or None,
        validation_plants=args.validation_plants,
        threads=args.threads,
        **given,
    )


def run(args: argparse.Namespace, command_line: str) -> int:
    """Train; return the exit status (2 for bad input)."""
    settings = settings_from_args(
        args,
        seed=args.seed,
        out=args.out,
        resume=args.resume,
        quiet=args.quiet,
        overwrite=args.overwrite,
        command_line=command_line,
    )
    say = (lambda _: None) if args.quiet else (lambda text: print(text, file=sys.stderr))
    try:
        summary = train(settings, say)
    except TrainingError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(
            f"trained {summary['algo'].upper()} to {summary['steps']} steps in "
            f"{summary['learn_time_s']:.1f} s ({summary['env_steps_per_s']:.0f} env-steps/s); "
            f"model: {args.out / 'model.zip'}"
        )
    return 0
