"""Run a sweep's trials as Ray Tune trials, with a progress bar read from the trial folders.

Tune keeps its experiment state in ``OUT/tune`` (:data:`TUNE_FOLDER`); a sweep run again
with ``--resume`` restores it (``Tuner.restore``): finished trials stay finished, the others
run again and continue from their folders (:mod:`frictiongym.sweep.trial`). Ray and its
Tune are imported inside :func:`run_trials` only.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

from frictiongym.sweep.grid import Trial
from frictiongym.sweep.trial import HELDOUT_FILE, run_trial

#: Tune's experiment folder inside ``--out``.
TUNE_FOLDER = "tune"
#: Seconds between two looks of the progress bar at the trial folders.
POLL_SECONDS = 2.0


def trial_name(trial: Any) -> str:
    """Return the name (and folder name) Tune gives a trial: the sweep's own name for it."""
    name: str = trial.config["trial"]["name"]
    return name


def _best_validation(folder: Path) -> float | None:
    """Return the best score so far in a trial's ``validation.csv`` (None before the first)."""
    try:
        lines = (folder / "validation.csv").read_text().splitlines()[1:]
        scores = [float(line.split(",")[1]) for line in lines if line.count(",") > 1]
    except (OSError, ValueError, IndexError):  # not there yet, or a row being written
        return None
    return min(scores, default=None)


def _finished_line(folder: Path, score: float | None) -> str:
    """Return what a finished trial scored: validation, and held-out ratios to the PID's."""
    try:
        held = json.loads((folder / HELDOUT_FILE).read_text())["heldout"]
    except (OSError, ValueError, KeyError):
        return "held-out evaluation unreadable"
    validation = "no validation" if score is None else f"validation score {score:.3f}"
    return (
        f"{validation}; held-out ITAE x{held['itae_ratio']:.3f}, SSE x{held['sse_ratio']:.3f} "
        "of the compensated PID's"
    )


class Progress:
    """A tqdm bar of finished trials, with the best validation score so far as its postfix.

    A thread reads the trial folders (``heldout.json``: finished; ``validation.csv``: the
    scores so far) every :data:`POLL_SECONDS`, so it works alike for new and restored
    sweeps, and writes a line as each trial finishes.
    """

    def __init__(self, trials: Sequence[Trial], disable: bool) -> None:
        from tqdm import tqdm

        self.trials = trials
        self.bar = tqdm(
            total=len(trials), desc="sweep", unit="trial", disable=disable, file=sys.stderr
        )
        self.finished = {t.name for t in trials if (t.settings.out / HELDOUT_FILE).is_file()}
        self.bar.update(len(self.finished))
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._watch, daemon=True)

    def _watch(self) -> None:
        while not self.stop.wait(POLL_SECONDS):
            self.poll()

    def poll(self) -> None:
        """Look at the trial folders once: count the finished trials, show the best score."""
        best: tuple[float, str] | None = None
        for t in self.trials:
            score = _best_validation(t.settings.out)
            if score is not None and (best is None or score < best[0]):
                best = (score, t.name)
            if t.name not in self.finished and (t.settings.out / HELDOUT_FILE).is_file():
                self.finished.add(t.name)
                self.bar.update(1)
                self.bar.write(f"finished {t.name}: {_finished_line(t.settings.out, score)}")
        if best is not None:
            self.bar.set_postfix_str(f"best validation {best[0]:.3f} ({best[1]})")

    def __enter__(self) -> Progress:
        self.thread.start()
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.stop.set()
        self.thread.join()
        self.poll()
        self.bar.close()


def run_trials(
    trials: Sequence[Trial],
    out: Path,
    cpus_per_trial: int,
    retries: int,
    resume: bool,
    quiet: bool,
) -> dict[str, str]:
    """Run the trials on the connected Ray; return the errors of failed ones by trial name.

    Raises
    ------
    KeyboardInterrupt
        When Tune stopped before every trial finished or failed (a Ctrl-C): its state is
        saved, and ``--resume`` continues.
    """
    # Tune's newer console output prints an experiment table even at verbose=0: the older
    # one prints nothing there, and the Progress bar says what matters.
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    from ray import tune

    storage = out.resolve()
    state = storage / TUNE_FOLDER
    trainable = tune.with_resources(run_trial, {"cpu": cpus_per_trial})
    if resume and tune.Tuner.can_restore(str(state)):
        tuner = tune.Tuner.restore(
            str(state), trainable, resume_unfinished=True, restart_errored=True
        )
    else:
        if state.exists():  # an earlier run stopped before Tune saved its state: start anew
            shutil.rmtree(state)
        tuner = tune.Tuner(
            trainable,
            param_space={"trial": tune.grid_search([t.config() for t in trials])},
            tune_config=tune.TuneConfig(
                metric="best_score",
                mode="min",
                trial_name_creator=trial_name,
                trial_dirname_creator=trial_name,
            ),
            run_config=tune.RunConfig(
                name=TUNE_FOLDER,
                storage_path=str(storage),
                verbose=0,  # the Progress bar instead of Tune's tables
                failure_config=tune.FailureConfig(max_failures=retries),
            ),
        )
    with Progress(trials, disable=quiet):
        grid = tuner.fit()
    errors = {}
    ended = 0
    for i in range(len(grid)):
        result = grid[i]
        name = (result.config or {})["trial"]["name"]
        if result.error is not None:
            text = str(result.error).strip().splitlines()
            errors[name] = text[-1] if text else type(result.error).__name__
        if result.error is not None or (result.metrics or {}).get("best_score") is not None:
            ended += 1
    if ended < len(trials):
        raise KeyboardInterrupt(
            f"{ended} of {len(trials)} trials ended; the others continue with --resume"
        )
    return errors
