"""One trial of a sweep, as a Ray Tune worker runs it: train, then the held-out evaluation.

:func:`run_trial` is the Tune trainable. It calls :func:`frictiongym.residual.train.train`
with the trial's settings, so a trial trains the policy ``frictiongym train`` trains with the
same settings and seed. Run again on a trial folder (a sweep resumed, a trial retried), it
continues what is there: training from the newest checkpoint (train's ``--resume``), and the
evaluation unless ``heldout.json`` holds it. Ray is imported here only when a trial reports.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from typing import Any

from frictiongym import devices
from frictiongym._io import write_json_atomic
from frictiongym.benchmark.report import Comparison, residual_comparisons
from frictiongym.benchmark.run import run_benchmark
from frictiongym.benchmark.scenarios import model_scenarios
from frictiongym.residual.train import (
    OUTPUTS,
    QUICK_STEPS,
    UNBOUNDED,
    TrainSettings,
    latest_checkpoint,
    saved_steps,
    train,
)
from frictiongym.sweep.grid import Trial

#: A trial's held-out evaluation, written once it is complete (and the mark of a done trial).
HELDOUT_FILE = "heldout.json"
#: ``train``'s steps without ``--steps`` and ``--max-time`` (``frictiongym train --help``).
_DEFAULT_STEPS = 200_000


def _target_steps(settings: TrainSettings) -> int:
    """Return the env-steps ``train`` trains ``settings`` to (as :func:`train` chooses)."""
    if settings.steps:
        return settings.steps
    if settings.quick:
        return QUICK_STEPS[settings.algo]
    return UNBOUNDED if settings.max_time else _DEFAULT_STEPS


def train_trial(settings: TrainSettings) -> dict[str, Any]:
    """Train a trial, or continue it in its folder; return its ``train.json``.

    A ``train.json`` in the folder means the training finished (``train`` writes it last). A
    checkpoint short of the steps is continued (``--resume``); anything else an earlier
    attempt left (an interruption before the first checkpoint, or after the last one) is
    replaced by a fresh run of the same seed.
    """
    out = settings.out
    summary_file = out / "train.json"
    if summary_file.is_file():
        summary: dict[str, Any] = json.loads(summary_file.read_text())
        return summary
    checkpoint = latest_checkpoint(out)
    if checkpoint is not None and saved_steps(checkpoint) < _target_steps(settings):
        return train(dataclasses.replace(settings, resume="latest"))
    earlier = any(os.path.lexists(out / name) for name in OUTPUTS)
    return train(dataclasses.replace(settings, overwrite=earlier))


def _comparison_record(c: Comparison) -> dict[str, Any]:
    """Return one device and plant set of the held-out evaluation as JSON-ready data."""
    return {
        "runs": c.runs,
        "itae": {"compensated": c.itae[0], "residual": c.itae[1]},
        "sse": {"compensated": c.sse[0], "residual": c.sse[1]},
        "itae_ratio": c.itae[1] / max(c.itae[0], 1e-12),
        "sse_ratio": c.sse[1] / max(c.sse[0], 1e-12),
        "itae_wins": c.itae_wins,
        "sse_wins": c.sse_wins,
        "terminated": {"compensated": c.terminated[0], "residual": c.terminated[1]},
        "cycles": {"compensated": c.cycles[0], "residual": c.cycles[1]},
    }


def evaluate_trial(trial: Trial) -> dict[str, Any]:
    """Run the benchmark's held-out evaluation of the trial's policy; write ``heldout.json``.

    The policy is ``best.zip`` (``model.zip`` when the trial did not validate). The runs are
    those of ``frictiongym benchmark --group residual --residual DEVICE=POLICY --heldout N
    --heldout-seed S``; the ratios are the residual's mean ITAE and SSE over those of the
    compensated PID (below 1: the residual is better).
    """
    out = trial.settings.out
    done = out / HELDOUT_FILE
    if done.is_file():
        record: dict[str, Any] = json.loads(done.read_text())
        return record
    policy = out / "best.zip"
    if not policy.is_file():
        policy = out / "model.zip"
    device = devices.get(trial.settings.env_id).kind
    plants, first_seed = trial.heldout["plants"], trial.heldout["first_seed"]
    results = run_benchmark(model_scenarios(device, str(policy), plants, first_seed))
    record = {
        "policy": policy.name,
        "device": device,
        "plants": plants,
        "first_seed": first_seed,
        "command_line": (
            f"frictiongym benchmark --group residual --residual {device}={policy} "
            f"--heldout {plants} --heldout-seed {first_seed}"
        ),
        **{c.plants: _comparison_record(c) for c in residual_comparisons(results)},
    }
    write_json_atomic(done, record, allow_nan=False)
    return record


def trial_metrics(summary: dict[str, Any], heldout: dict[str, Any]) -> dict[str, Any]:
    """Return what a trial reports to Tune: the validation score and the held-out ratios."""
    score = summary.get("best_score")
    metrics = {
        "best_score": math.inf if score is None else float(score),
        "steps": summary["steps"],
        "wall_time_s": summary["wall_time_s"],
    }
    for plants in ("nominal", "heldout"):
        for ratio in ("itae_ratio", "sse_ratio"):
            metrics[f"{plants}_{ratio}"] = heldout[plants][ratio]
    return metrics


def run_trial(config: dict[str, Any]) -> None:
    """Run one trial (Tune's function trainable): train, evaluate, report the metrics."""
    from ray import tune  # in a Ray worker: Ray is there

    trial = Trial.from_config(config["trial"])
    summary = train_trial(trial.settings)
    tune.report(trial_metrics(summary, evaluate_trial(trial)))
