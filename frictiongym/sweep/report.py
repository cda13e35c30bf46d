"""A sweep's results: the trials ranked in ``sweep.csv`` and ``sweep.md``, the best one copied.

Everything is read from the trial folders (``train.json``, ``heldout.json``), which hold the
trials of earlier, interrupted runs of the sweep too.
"""

from __future__ import annotations

import functools
import json
import math
import secrets
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from frictiongym._io import csv_text, sigint_held, write_file_atomic, write_text_atomic
from frictiongym.sweep.grid import Trial
from frictiongym.sweep.trial import HELDOUT_FILE

#: The held-out columns: (plants, ratio) -> header.
RATIOS = {
    ("nominal", "itae_ratio"): "nominal ITAE",
    ("nominal", "sse_ratio"): "nominal SSE",
    ("heldout", "itae_ratio"): "held-out ITAE",
    ("heldout", "sse_ratio"): "held-out SSE",
}


@dataclass(frozen=True)
class Outcome:
    """A trial and what it left: its ``train.json`` and ``heldout.json``, or its error."""

    trial: Trial
    summary: dict[str, Any] | None
    heldout: dict[str, Any] | None
    error: str = ""

    @property
    def status(self) -> str:
        """``done``, ``error`` or ``unfinished``."""
        if self.heldout is not None and self.summary is not None:
            return "done"
        return "error" if self.error else "unfinished"

    @property
    def score(self) -> float:
        """The validation score of the trial's best policy (infinite if none)."""
        score = None if self.summary is None else self.summary.get("best_score")
        return math.inf if score is None else float(score)

    def ratio(self, plants: str, name: str) -> float:
        """Return a held-out ratio of the residual to the compensated PID (NaN if not evaluated)."""
        return math.nan if self.heldout is None else float(self.heldout[plants][name])


def _read(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    data: dict[str, Any] = json.loads(path.read_text())
    return data


def collect(trials: Sequence[Trial], errors: dict[str, str]) -> list[Outcome]:
    """Return each trial's outcome from its folder (``errors``: trial name -> error)."""
    return [
        Outcome(
            t,
            _read(t.settings.out / "train.json"),
            _read(t.settings.out / HELDOUT_FILE),
            errors.get(t.name, ""),
        )
        for t in trials
    ]


def ranked(outcomes: Sequence[Outcome]) -> list[Outcome]:
    """Return the finished trials by validation score (then held-out ITAE), then the others."""
    done = [o for o in outcomes if o.status == "done"]
    done.sort(key=lambda o: (o.score, o.ratio("heldout", "itae_ratio"), o.trial.name))
    return done + [o for o in outcomes if o.status != "done"]


def _number(value: float, spec: str = ".4g") -> str:
    return "" if math.isnan(value) else "inf" if math.isinf(value) else format(value, spec)


def csv_rows(outcomes: Sequence[Outcome]) -> list[list[object]]:
    """Return the rows of ``sweep.csv`` (a header, then the trials as :func:`ranked` orders)."""
    keys = list(outcomes[0].trial.values) if outcomes else []
    head: list[object] = ["rank", "trial", "seed", *keys, "status", "best_score"]
    head += [f"{p}_{r}" for p, r in RATIOS]
    head += ["heldout_itae_wins", "heldout_sse_wins", "heldout_runs", "heldout_terminated"]
    head += ["steps", "wall_time_s", "policy", "command_line", "error"]
    rows = [head]
    for rank, o in enumerate(ranked(outcomes), 1):
        held = (o.heldout or {}).get("heldout", {})
        s = o.summary or {}
        rows.append(
            [
                rank if o.status == "done" else "",
                o.trial.name,
                o.trial.seed,
                *(json.dumps(o.trial.values[k]) for k in keys),
                o.status,
                _number(o.score, ".6g") if o.summary else "",
                *(_number(o.ratio(p, r), ".6g") for p, r in RATIOS),
                held.get("itae_wins", ""),
                held.get("sse_wins", ""),
                held.get("runs", ""),
                held.get("terminated", {}).get("residual", ""),
                s.get("steps", ""),
                s.get("wall_time_s", ""),
                (o.heldout or {}).get("policy", ""),
                o.trial.settings.command_line,
                o.error,
            ]
        )
    return rows


def markdown(outcomes: Sequence[Outcome], command_line: str, heldout: dict[str, int]) -> str:
    """Return ``sweep.md``: the trials ranked, with their held-out ratios."""
    order = ranked(outcomes)
    keys = list(outcomes[0].trial.values) if outcomes else []
    lines = ["# frictiongym sweep", ""]
    if command_line:
        lines += [f"Produced by `{command_line}`.", ""]
    lines += [
        "Trials ranked by the validation score of their best policy (`best_score` of train.json: "
        "the worst ratio of the residual's ITAE and SSE to the compensated PID's on the "
        "validation plants; below 1: better on all). The held-out columns are the benchmark's "
        "evaluation of that policy (`frictiongym benchmark --group residual`): mean ITAE and "
        f"SSE of the residual over the compensated PID's, on the nominal plant and on "
        f"{heldout['plants']} held-out plants (seeds {heldout['first_seed']} and up); `wins`: "
        "held-out plants where the residual's ITAE / SSE is lower.",
        "",
    ]
    head = ["rank", "trial", "seed", *keys, "validation", *RATIOS.values(), "wins", "steps", "s"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for rank, o in enumerate(order, 1):
        held = (o.heldout or {}).get("heldout", {})
        s = o.summary or {}
        wins = (
            f"{held['itae_wins']}/{held['runs']}, {held['sse_wins']}/{held['runs']}" if held else ""
        )
        cells = [
            str(rank) if o.status == "done" else o.status,
            f"`{o.trial.name}`",
            str(o.trial.seed),
            *(json.dumps(o.trial.values[k]) for k in keys),
            _number(o.score, ".3f") if o.summary else "",
            *(_number(o.ratio(p, r), ".3f") for p, r in RATIOS),
            wins,
            str(s.get("steps", "")),
            f"{s['wall_time_s']:.0f}" if "wall_time_s" in s else "",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    failed = [o for o in order if o.status == "error"]
    if failed:
        lines += ["", "## Failed trials", ""]
        lines += [f"- `{o.trial.name}`: {o.error}" for o in failed]
    if order and order[0].status == "done":
        best = order[0]
        lines += [
            "",
            f"## Best: `{best.trial.name}`",
            "",
            f"Copied to `best/` ({(best.heldout or {}).get('policy')}, train.json, heldout.json). "
            "The same policy, trained outside the sweep"
            + (
                " (this trial was resumed from a checkpoint: an uninterrupted run may differ):"
                if (best.summary or {}).get("resumed_from")
                else ":"
            ),
            "",
            "```bash",
            best.trial.settings.command_line,
            "```",
        ]
    return "\n".join(lines) + "\n"


def _copy(source: Path, target: Path) -> None:
    shutil.copyfile(source, target)


def write_best(best: Outcome, out: Path) -> Path:
    """Copy the best trial's policy, ``train.json`` and ``heldout.json`` to ``out/best``.

    The files are gathered in a hidden folder first and swapped in whole, so ``best/`` never
    mixes two trials' files.
    """
    source = best.trial.settings.out
    policy = (best.heldout or {}).get("policy", "best.zip")
    staging = out / f".best-partial-{secrets.token_hex(4)}"
    staging.mkdir()
    try:
        for name in (policy, "train.json", HELDOUT_FILE, "validation.csv"):
            if (source / name).is_file():
                write_file_atomic(staging / name, functools.partial(_copy, source / name))
        write_text_atomic(staging / "TRIAL", best.trial.name + "\n")
        target, old = out / "best", out / f".best-old-{secrets.token_hex(4)}"
        with sigint_held():
            if target.exists():
                target.rename(old)
            staging.rename(target)
            shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return target


def write_reports(
    outcomes: Sequence[Outcome], out: Path, command_line: str, heldout: dict[str, int]
) -> list[Path]:
    """Write ``sweep.csv``, ``sweep.md`` and (with a finished trial) ``best/``; return them."""
    written = [out / "sweep.csv", out / "sweep.md"]
    write_text_atomic(written[0], csv_text(csv_rows(outcomes)))
    write_text_atomic(written[1], markdown(outcomes, command_line, heldout))
    order = ranked(outcomes)
    if order and order[0].status == "done":
        written.append(write_best(order[0], out))
    return written
