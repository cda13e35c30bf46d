"""Train a residual policy with Stable-Baselines3 on randomised frictiongym plants.

``train(TrainSettings(...))`` is what ``frictiongym train`` runs. Stable-Baselines3 and torch
are imported inside :func:`train` only.
"""

from __future__ import annotations

import importlib.util
import inspect
import json
import math
import os
import platform
import re
import sys
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from frictiongym import __version__, devices, envs
from frictiongym._io import OutputDir, sigint_held, write_file_atomic, write_json_atomic
from frictiongym._validation import MAX_SEED
from frictiongym.controllers.residual import ALGORITHMS, METADATA_ATTRIBUTE, read_metadata
from frictiongym.controllers.residual_core import ResidualConfig
from frictiongym.residual.selection import (
    METRICS,
    VALIDATION_PLANTS,
    VALIDATION_SEED,
    Validation,
)
from frictiongym.residual.vector_env import make_residual_vec

#: Training rewards: the env's own, or ResidualEnv's logarithmic one at the device's
#: ``training_precision`` (one step of the sensor at the target, so an error of one count
#: costs log 2 per step).
REWARDS = ("env", "precision")

#: Steps of ``--quick`` per algorithm (a smoke run of well under a minute).
QUICK_STEPS = {"ppo": 2048, "sac": 300, "td3": 300}
#: Time a ``--max-time`` run keeps for saving its model at the end (about 0.1 s measured; the
#: rest is margin for a busy machine), s.
SAVE_SECONDS = 1.0
#: ``--steps`` when only ``--max-time`` bounds a run.
UNBOUNDED = 10**12
#: Checkpoint file names: ``checkpoints/model_<steps>_steps.zip`` (SB3's CheckpointCallback).
CHECKPOINT_PREFIX = "model"
_CHECKPOINT = re.compile(rf"{CHECKPOINT_PREFIX}_(\d+)_steps\.zip")
#: What a run may write into ``out``: an earlier run's are refused, or replaced with
#: ``overwrite``, all of them (a new run never appends to an old validation.csv).
OUTPUTS = (
    "model.zip",
    "train.json",
    "replay_buffer.pkl",
    "best.zip",
    "validation.csv",
    "checkpoints",
    "tb",
    "logs",
)
#: SB3 constructor arguments that ``train`` sets itself (``--sb3`` may not).
_OWN_ARGUMENTS = {"policy": None, "env": "--env", "seed": "--seed", "device": None, "verbose": None}


class TrainingError(Exception):
    """A user error in the training settings; the message says what to do."""


@dataclass
class TrainSettings:
    """Settings of :func:`train` (``frictiongym train``'s options).

    ``steps`` is the total number of env-steps of the model; a resumed run trains what is
    missing to reach it. ``resume`` is ``None``, ``"latest"`` (the most trained of
    ``out/checkpoints/*`` and ``out/model.zip``) or the path of a model zip; it continues
    the run in ``out`` in place. Otherwise ``out`` must hold no earlier run's outputs
    (:data:`OUTPUTS`), unless ``overwrite`` replaces them.
    """

    env_id: str
    algo: str = "ppo"
    steps: int | None = None
    seed: int = 0
    out: Path = Path("residual-results")
    randomize: str = "default"
    quick: bool = False
    resume: str | None = None
    n_envs: int | None = None  # envs of the native vector env; default_envs(algo) if None
    max_time: float | None = None  # seconds of wall time for the training; None: no budget
    checkpoint_every: int = 50_000
    scale: float | None = None  # fraction of the action limit; the device's default if None
    reward: str = "precision"  # ResidualEnv's logarithmic tracking reward; "env": the env's
    residual_cost: float = 0.0
    threads: int | None = None  # torch threads; default_threads(algo) if None
    #: env-steps between validations; None: no validation; "auto": default_validation(n_envs)
    validate_every: int | str | None = "auto"
    validation_plants: int = VALIDATION_PLANTS
    quiet: bool = False
    overwrite: bool = False
    command_line: str = ""
    hyperparameters: dict[str, Any] = field(default_factory=dict)


def check_settings(settings: TrainSettings) -> None:
    """Raise :class:`TrainingError` for settings that cannot work, before anything is built."""
    if settings.algo not in ALGORITHMS:
        raise TrainingError(f"unknown --algo {settings.algo!r}; use one of {', '.join(ALGORITHMS)}")
    ids = sorted(n for n in gym.registry if n.startswith("frictiongym/") and n != envs.AXIS_ID)
    if settings.env_id not in ids:
        try:  # a device description file
            described = envs.device_of_id(settings.env_id, ids, "--env")
        except ValueError as error:
            raise TrainingError(str(error)) from None
        if not described.residual:
            raise TrainingError(
                f"{described.source}: [residual] missing: train needs the residual policy's "
                "scale, error_scale, fine_error, velocity_scale and reference_scale "
                "(docs/devices.md)"
            )
    if not 0 <= settings.seed <= MAX_SEED:
        raise TrainingError(
            f"--seed must be a whole number from 0 to {MAX_SEED}, got {settings.seed}"
        )
    if settings.overwrite and settings.resume is not None:
        raise TrainingError(
            "--overwrite replaces an earlier run and --resume continues it: give one of them"
        )
    if settings.randomize not in ("none", "default"):
        raise TrainingError(f"--randomize must be 'none' or 'default', got {settings.randomize!r}")
    if settings.reward not in REWARDS:
        raise TrainingError(
            f"--reward must be one of {', '.join(REWARDS)}, got {settings.reward!r}"
        )
    if not (math.isfinite(settings.residual_cost) and settings.residual_cost >= 0.0):
        raise TrainingError(f"--residual-cost must be >= 0, got {settings.residual_cost}")
    for name in (
        "steps",
        "n_envs",
        "checkpoint_every",
        "validation_plants",
        "threads",
    ):
        value = getattr(settings, name)
        if value is not None and value < 1:
            raise TrainingError(
                f"--{name.replace('_', '-')} must be a positive number, got {value}"
            )
    every = settings.validate_every
    if every != "auto" and every is not None and (not isinstance(every, int) or every < 1):
        raise TrainingError(f"--validate-every must be a positive number or 0, got {every}")
    if settings.max_time is not None and not (
        math.isfinite(settings.max_time) and settings.max_time > 0.0
    ):
        raise TrainingError(f"--max-time is a number of seconds > 0, got {settings.max_time}")
    if settings.scale is not None and not (0.0 < settings.scale <= 1.0):
        raise TrainingError(
            f"--scale is a fraction of the action limit in (0, 1], got {settings.scale}"
        )
    own = sorted(set(settings.hyperparameters) & set(_OWN_ARGUMENTS))
    if own:
        raise TrainingError(
            f"--sb3 {own[0]}: frictiongym train sets it"
            + (f"; use {_OWN_ARGUMENTS[own[0]]}" if _OWN_ARGUMENTS[own[0]] else "")
        )


def env_kwargs(env_id: str, randomize: str) -> dict[str, Any]:
    """Return the ``gym.make`` arguments of the training env of ``env_id``."""
    device = devices.get(env_id)
    kwargs = dict(device.training_env)
    if randomize == "default":
        kwargs["randomize"] = dict(device.randomization)
    return kwargs


def hyperparameters(
    algo: str, steps: int, n_envs: int, quick: bool, device: devices.Device
) -> dict[str, Any]:
    """SB3 constructor arguments: the library's defaults except as commented here.

    All: the discount of the device (``training_gamma``). PPO: rollouts of about 2048 env-steps
    over all envs (512 with ``quick``, so a smoke run still makes several updates), minibatches
    of 64 env-steps per env up to 256 (SB3's 64 with one env; with 32 envs, 256 trains 2.3x
    faster than 64 and reaches a better validation score in a minute: docs/residual.md), and
    an initial action std of ``exp(-2) = 0.14`` of the bound instead of 1: the exploration
    noise of an untrained policy is then below the servo's break-away voltage (0.14 V
    against 0.21 V), where a std of 1 dithers the disk loose and the policy learns under
    noise what it cannot do without (docs/residual.md). SAC and TD3: a replay buffer no
    larger than the run, learning from step 1000 (100 with ``quick``).
    """
    if algo == "ppo":
        return {
            "n_steps": max(64, (512 if quick else 2048) // n_envs),
            "batch_size": min(256, 64 * n_envs),
            "gamma": device.training_gamma,
            "policy_kwargs": {"log_std_init": -2.0},
        }
    return {
        "buffer_size": int(min(steps, 1_000_000)),
        "learning_starts": 100 if quick else 1000,
        "gamma": device.training_gamma,
    }


def saved_steps(path: Path, key: str = "num_timesteps") -> int:
    """Return the env-steps a saved SB3 model zip was trained for (-1 if unreadable).

    ``key="n_envs"`` reads the number of envs it was trained with instead.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            return int(json.loads(archive.read("data")).get(key, -1))
    except (OSError, zipfile.BadZipFile, KeyError, ValueError, TypeError):
        return -1


def latest_checkpoint(out: Path) -> Path | None:
    """Return the most trained of ``out/checkpoints/*`` and ``out/model.zip`` (None if none).

    A tie goes to ``model.zip``, which has the final replay buffer.
    """
    found = [
        (saved_steps(p), 0, p)
        for p in (out / "checkpoints").glob(f"{CHECKPOINT_PREFIX}_*_steps.zip")
        if _CHECKPOINT.fullmatch(p.name)
    ]
    final = out / "model.zip"
    if final.is_file():
        found.append((saved_steps(final), 1, final))
    return max(found)[2] if found else None


def _replay_buffer_of(model_path: Path) -> Path:
    """Where the replay buffer saved with a checkpoint or final model lies."""
    m = _CHECKPOINT.fullmatch(model_path.name)
    if m:
        return model_path.with_name(f"{CHECKPOINT_PREFIX}_replay_buffer_{m.group(1)}_steps.pkl")
    return model_path.with_name("replay_buffer.pkl")


def _versions() -> dict[str, str]:
    import stable_baselines3  # the rl extra: imported once training runs
    import torch

    return {
        "frictiongym": __version__,
        "stable_baselines3": stable_baselines3.__version__,
        "torch": torch.__version__,
        "gymnasium": gym.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }


def _progress_callback(total: int | None, disable: bool) -> Any:
    """Return an SB3 callback drawing a tqdm bar of ``total`` env-steps (or a count) on stderr."""
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    class ProgressBar(BaseCallback):
        def _on_training_start(self) -> None:
            self.bar = tqdm(
                total=total, unit="step", disable=disable, file=sys.stderr, dynamic_ncols=True
            )

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            return True

        def _on_training_end(self) -> None:
            self.close()

        def close(self) -> None:
            if hasattr(self, "bar"):
                self.bar.close()

    return ProgressBar()


def default_envs(algo: str) -> int:
    """Return the envs of ``algo`` when ``--n-envs`` is not given.

    PPO: 32, one native vector env of 32 stepped in one call: with minibatches of 256
    (:func:`hyperparameters`) it trains 4-6x faster per second than one env and reached a
    validation score below 1 in under 10 s on both devices (docs/residual.md). SAC and TD3:
    1, as before: they take one gradient step per vector step, so 32 envs would learn from
    32 times fewer updates per env-step.
    """
    return 32 if algo == "ppo" else 1


def default_validation(n_envs: int) -> int:
    """Return the env-steps between validations when ``--validate-every`` is not given.

    10 000 with fewer than 8 envs; 30 000 from 8. A servo validation takes about 3 s, as long
    as 20 000 env-steps of PPO's training with 32 envs: every 10 000 steps, validation took
    36 s of a 60 s run and one of three seeds did not beat the compensated PID; every 30 000,
    22 s, and all three did (docs/residual.md).
    """
    return 10_000 if n_envs < 8 else 30_000


def default_threads(algo: str) -> int:
    """Return the torch threads of ``algo`` when ``--threads`` is not given.

    PPO: 1. Its updates (batch 64 through two layers of 64) are too small to gain from a
    second thread: one is 1.13x faster alone and 4.6x faster with another process on a core
    (``scripts/bench_training.py``, docs/benchmarks.md). SAC and TD3 (batch 256 through two
    layers of 256): every core, 1.3x faster than one alone on this 2-core machine
    (docs/residual.md). Give ``--threads 1`` to run trainings side by side.
    """
    return 1 if algo == "ppo" else max(os.cpu_count() or 1, 1)


def _threads_callback(threads: int) -> Any:
    """Return an SB3 callback that holds torch at ``threads`` threads before every update.

    The envs' numba kernels start numba's OpenMP threading layer at their first step, and
    that sets the process's OpenMP thread count (shared with torch) to numba's, overriding
    ``torch.set_num_threads`` and ``OMP_NUM_THREADS`` (docs/benchmarks.md).
    """
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    class Threads(BaseCallback):
        def _on_training_start(self) -> None:
            torch.set_num_threads(threads)

        def _on_rollout_end(self) -> None:
            torch.set_num_threads(threads)

        def _on_step(self) -> bool:
            return True

    return Threads()


def _validation_callback(
    validation: Validation, every: int, out: Path, say: Callable[[str], None], started: float
) -> Any:
    """Return an SB3 callback that scores the policy every ``every`` env-steps and at the end.

    Appends each score to ``out/validation.csv`` (with the seconds since ``started``, the
    run's start, when it was scored) and saves the best-scoring policy so far as
    ``out/best.zip`` (whole or not at all: :func:`save_model`). A resumed run keeps the best
    score of the CSV it continues.
    """
    from stable_baselines3.common.callbacks import BaseCallback

    table = out / "validation.csv"
    names = [f"{plants}/{metric}" for plants in ("nominal", "randomised") for metric in METRICS]

    class Validate(BaseCallback):
        def _on_training_start(self) -> None:
            rows = _validation_rows(table)
            self.best = min((float(row[1]) for row in rows), default=math.inf)
            self.seconds = self.longest = 0.0
            if not table.is_file():
                header = ["steps", "score", *names, "terminated", "time_s"]
                table.write_text(",".join(header) + "\n")
            done = self.num_timesteps
            self.due = max(-(-done // every) * every, every)
            if self.due == done:  # resumed on a validation step
                self.due += every
                if done not in {int(float(row[0])) for row in rows}:  # a Ctrl-C came during it
                    self.validate()

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.due:
                self.due += every
                self.validate()
            return True

        def _on_training_end(self) -> None:
            if self.num_timesteps != self.due - every:
                self.validate()

        def validate(self) -> None:
            start = time.perf_counter()
            result = validation(self.model)
            took = time.perf_counter() - start
            self.seconds += took
            self.longest = max(self.longest, took)
            for name in names:
                self.logger.record(f"validation/{name}", result.ratios[name])
            self.logger.record("validation/score", result.score)
            row = [self.num_timesteps, result.score, *(result.ratios[n] for n in names)]
            with table.open("a") as file:
                elapsed = time.perf_counter() - started
                file.write(
                    ",".join(f"{v:.6g}" for v in row) + f",{result.terminated},{elapsed:.1f}\n"
                )
            if result.score < self.best:
                self.best = result.score
                save_model(self.model, out / "best.zip")
                say(f"validation at {self.num_timesteps} steps: score {result.score:.3f} (best)")

    return Validate()


def _budget_callback(deadline: float, validate: Any) -> Any:
    """Return an SB3 callback that ends training when the time left only fits what follows.

    What follows is the final validation (1.5 times the longest so far) and saving
    (:data:`SAVE_SECONDS`): a run given ``--max-time`` ends within it, ``best.zip`` scored.
    """
    from stable_baselines3.common.callbacks import BaseCallback

    class Budget(BaseCallback):
        stopped = False

        def _on_step(self) -> bool:
            reserve = 1.5 * validate.longest if validate is not None else 0.0
            self.stopped = time.perf_counter() + reserve + SAVE_SECONDS >= deadline
            return not self.stopped

    return Budget()


def save_model(model: Any, path: Path, replay_buffer: Path | None = None) -> None:
    """Save an SB3 model (and its replay buffer) whole: an interruption never leaves half."""
    write_file_atomic(path, model.save)
    if replay_buffer is not None:
        write_file_atomic(replay_buffer, model.save_replay_buffer)


def _checkpoint_on_interrupt(model: Any, out: Path, algo: str) -> str:
    """Save the model interrupted at ``model.num_timesteps`` as a checkpoint; say where.

    ``--resume`` picks it up (:func:`latest_checkpoint`). Ctrl-C is held meanwhile.
    """
    with sigint_held():
        steps = int(model.num_timesteps)
        path = out / "checkpoints" / f"{CHECKPOINT_PREFIX}_{steps}_steps.zip"
        path.parent.mkdir(exist_ok=True)
        save_model(model, path, None if algo == "ppo" else _replay_buffer_of(path))
        model.logger.close()  # flush the TensorBoard/CSV logs
    return f"checkpoint of {steps} steps saved as {path}; continue with --resume"


def _validation_rows(table: Path) -> list[list[str]]:
    """Return the rows of a validation CSV (none if there is no file)."""
    if not table.is_file():
        return []
    return [line.split(",") for line in table.read_text().splitlines()[1:] if line]


def train(settings: TrainSettings, say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Train (or continue training) a residual policy; write ``settings.out``.

    Writes ``model.zip`` (with the residual metadata that
    :meth:`~frictiongym.controllers.residual.ResidualController.load` reads),
    ``checkpoints/``, TensorBoard logs in ``tb/`` (CSV in ``logs/`` when tensorboard is not
    installed), ``replay_buffer.pkl`` for SAC and TD3, and ``train.json``.

    Returns
    -------
    dict
        The content of ``train.json``.

    Raises
    ------
    TrainingError
        For bad settings or a missing Stable-Baselines3 (the message says what to do).
    """
    say = say or (lambda _: None)
    check_settings(settings)
    output = OutputDir(
        settings.out,
        OUTPUTS,
        overwrite=settings.overwrite,
        staged=False,
        continuing=settings.resume is not None,
        resumable=True,
    )
    with output:  # checked before the work; removed again if the run writes nothing
        summary = _train(settings, say, output)
        output.commit()
    return summary


def _train(
    settings: TrainSettings, say: Callable[[str], None], output: OutputDir
) -> dict[str, Any]:
    """:func:`train` once ``output`` is checked."""
    algo, out = settings.algo, settings.out
    try:
        import stable_baselines3
        import torch  # noqa: F401
        from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback
        from stable_baselines3.common.logger import configure
        from stable_baselines3.common.vec_env import VecMonitor

        from frictiongym.sb3 import FrictionVecEnv
    except ImportError as exc:
        raise TrainingError(
            f'training needs Stable-Baselines3 and torch: pip install "frictiongym[rl]" ({exc})'
        ) from None
    start = time.perf_counter()
    steps = settings.steps or (
        QUICK_STEPS[algo] if settings.quick else UNBOUNDED if settings.max_time else 200_000
    )
    kwargs = env_kwargs(settings.env_id, settings.randomize)
    try:
        probe = envs.make(settings.env_id, **kwargs)
    except (TypeError, ValueError) as error:  # a description file's [training_env]
        raise TrainingError(f"{settings.env_id}: training_env: {error}") from None
    device = devices.device_of(probe)
    limit = ResidualConfig.for_env(probe).limit
    config = ResidualConfig.for_env(
        probe, None if settings.scale is None else settings.scale * limit
    )
    probe.close()
    meta = {
        "env_id": settings.env_id,
        "algo": algo,
        "config": config.to_dict(),
        "base": {"kind": "compensated", "gains": dict(device.paper_gains["compensated"])},
        "env_kwargs": kwargs,
        "objective": {"reward": settings.reward, "residual_cost": settings.residual_cost},
    }

    resumed_from: Path | None = None
    if settings.resume is not None:
        resumed_from = (
            latest_checkpoint(out) if settings.resume == "latest" else Path(settings.resume)
        )
        if resumed_from is None:
            raise TrainingError(
                f"--resume: no checkpoint in {out / 'checkpoints'} and no {out / 'model.zip'}; "
                "give the model zip to continue (--resume PATH) or drop --resume"
            )
        try:
            saved = read_metadata(resumed_from)
        except (FileNotFoundError, ValueError) as exc:
            raise TrainingError(f"--resume: {exc}") from None
        if (saved["env_id"], saved["algo"]) != (settings.env_id, algo):
            raise TrainingError(
                f"--resume: {resumed_from} is {saved['algo']} on {saved['env_id']}; give "
                f"--env {saved['env_id']} --algo {saved['algo']}"
            )
        objective = saved.get("objective", meta["objective"])  # older models: not recorded
        if objective != meta["objective"]:
            raise TrainingError(
                f"--resume: {resumed_from} was trained with --reward {objective['reward']} "
                f"--residual-cost {objective['residual_cost']:g}; give the same to continue it"
            )
        config = ResidualConfig.from_dict(saved["config"])  # the policy's own inputs
        meta = {**saved, "env_kwargs": kwargs}

    # A resumed run keeps the envs it was trained with unless --n-envs says otherwise.
    saved_envs = saved_steps(resumed_from, "n_envs") if resumed_from is not None else -1
    n_envs = settings.n_envs or (saved_envs if saved_envs > 0 else default_envs(algo))
    precision = device.training_precision if settings.reward == "precision" else None

    residual = make_residual_vec(
        settings.env_id,
        n_envs,
        config=config,
        residual_cost=settings.residual_cost,
        precision=precision,
        **kwargs,
    )
    vec = VecMonitor(FrictionVecEnv(residual))
    vec.seed(settings.seed)
    algorithm = getattr(stable_baselines3, ALGORITHMS[algo])
    if resumed_from is not None:
        model = algorithm.load(str(resumed_from), env=vec, device="cpu")
        buffer = _replay_buffer_of(resumed_from)
        if algo != "ppo" and buffer.is_file():
            model.load_replay_buffer(str(buffer))
        say(f"resuming from {resumed_from} at {model.num_timesteps} steps")
    else:
        params = {
            **hyperparameters(algo, steps, n_envs, settings.quick, device),
            **settings.hyperparameters,
        }
        model = _construct(algorithm, vec, settings, params)
    setattr(model, METADATA_ATTRIBUTE, meta)
    done_before = int(model.num_timesteps)
    remaining = steps - done_before
    if remaining <= 0:
        raise TrainingError(
            f"the model has {done_before} steps already, --steps {steps} asks for no more: "
            "give a larger --steps to continue"
        )

    output.replace_earlier()  # --overwrite: only now that the new run is set up
    if importlib.util.find_spec("tensorboard") is not None:
        log_dir, formats = out / "tb", ["tensorboard", "csv"]
    else:
        log_dir, formats = out / "logs", ["csv"]
        say("tensorboard is not installed: logging to CSV in logs/ (pip install tensorboard)")
    run = 1
    while (log_dir / f"{algo}_{run}").exists():
        run += 1
    model.set_logger(configure(str(log_dir / f"{algo}_{run}"), formats))
    checkpoints = CheckpointCallback(
        max(settings.checkpoint_every // n_envs, 1),
        str(out / "checkpoints"),
        CHECKPOINT_PREFIX,
        save_replay_buffer=algo != "ppo",
    )
    bar = _progress_callback(None if steps == UNBOUNDED else remaining, settings.quiet)
    threads = settings.threads or default_threads(algo)
    callbacks = [_threads_callback(threads), checkpoints, bar]
    validate = None
    every = settings.validate_every
    if every == "auto":
        every = default_validation(n_envs)
    if every is not None:
        validation = Validation(
            device.name,
            kwargs.get("randomize", device.randomization),
            config,
            settings.validation_plants,
        )
        validate = _validation_callback(validation, int(every), out, say, start)
        callbacks.append(validate)
    budget = None
    if settings.max_time is not None:
        budget = _budget_callback(start + settings.max_time, validate)
        callbacks.append(budget)
    length = f"{remaining} steps" if steps != UNBOUNDED else "as many steps as fit"
    if settings.max_time is not None:
        length += f" in {settings.max_time:g} s"
    say(f"training {algo.upper()} on {settings.env_id} for {length} -> {out}")
    learn_start = time.perf_counter()
    try:
        model.learn(
            remaining,
            callback=CallbackList(callbacks),
            reset_num_timesteps=resumed_from is None,
        )
    except KeyboardInterrupt as interrupt:  # a Ctrl-C, or the CLI's SIGTERM (a subclass)
        bar.close()
        interrupt.args = (_checkpoint_on_interrupt(model, out, algo),)
        raise interrupt.with_traceback(None) from None
    learn_time = time.perf_counter() - learn_start
    training_time = learn_time - (validate.seconds if validate is not None else 0.0)
    save_model(model, out / "model.zip", None if algo == "ppo" else out / "replay_buffer.pkl")
    vec.close()
    trained = int(model.num_timesteps) - done_before
    summary = {
        "env_id": settings.env_id,
        "device": device.name,
        "algo": algo,
        "steps": int(model.num_timesteps),
        "steps_this_run": trained,
        "seed": settings.seed,
        "n_envs": n_envs,
        "threads": threads,
        "randomize": settings.randomize,
        "env_kwargs": kwargs,
        "scale": config.scale,
        "scale_fraction": config.scale / config.limit,
        "config": config.to_dict(),
        "base": meta["base"],
        "hyperparameters": {
            k: repr(v) if not isinstance(v, (int, float, str)) else v
            for k, v in model_hyperparameters(model, algo).items()
        },
        "reward": settings.reward,
        "precision": precision,
        "residual_cost": settings.residual_cost,
        "validation": None
        if validate is None
        else {
            "every": every,
            "plants": settings.validation_plants,
            "first_seed": VALIDATION_SEED,
            "best_score": validate.best if math.isfinite(validate.best) else None,
            "seconds": round(validate.seconds, 3),
        },
        "resumed_from": None if resumed_from is None else str(resumed_from),
        "best_score": None
        if validate is None or not math.isfinite(validate.best)
        else validate.best,
        "max_time": settings.max_time,
        "stopped_by": "max_time" if budget is not None and budget.stopped else "steps",
        "learn_time_s": round(learn_time, 3),
        "wall_time_s": round(time.perf_counter() - start, 3),
        "env_steps_per_s": round(trained / training_time, 1) if training_time > 0 else math.nan,
        "logs": {"dir": str(log_dir / f"{algo}_{run}"), "formats": formats},
        "versions": _versions(),
        "command_line": settings.command_line,
    }
    write_json_atomic(out / "train.json", summary)
    return summary


def _construct(algorithm: Any, vec: Any, settings: TrainSettings, params: dict[str, Any]) -> Any:
    """Build a new SB3 model; a ``--sb3`` argument it does not take is a :class:`TrainingError`."""
    accepted = inspect.signature(algorithm.__init__).parameters
    unknown = sorted(set(settings.hyperparameters) - set(accepted) - {"self"})
    if unknown:
        known = ", ".join(sorted(n for n in accepted if n[0] != "_" and n not in _OWN_ARGUMENTS))
        raise TrainingError(
            f"--sb3 {unknown[0]}: {algorithm.__name__} takes no such argument; it takes {known}"
        )
    try:
        return algorithm("MlpPolicy", vec, seed=settings.seed, device="cpu", verbose=0, **params)
    except (TypeError, ValueError, AssertionError) as exc:
        if not settings.hyperparameters:
            raise  # not the user's arguments: a bug to see in full
        given = " ".join(f"{k}={v!r}" for k, v in settings.hyperparameters.items())
        raise TrainingError(f"--sb3 {given}: {algorithm.__name__} refused them: {exc}") from None


def model_hyperparameters(model: Any, algo: str) -> dict[str, Any]:
    """Return the main hyperparameters of an SB3 model, for ``train.json``."""
    names = ["learning_rate", "gamma", "batch_size"]
    names += (
        ["n_steps", "n_epochs", "gae_lambda", "clip_range", "ent_coef"]
        if algo == "ppo"
        else ["buffer_size", "learning_starts", "tau", "train_freq", "gradient_steps"]
    )
    values = {name: getattr(model, name) for name in names if hasattr(model, name)}
    values["policy_kwargs"] = model.policy_kwargs
    return values
