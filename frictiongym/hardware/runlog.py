"""Run logs of device runs: one CSV row per step as it happens, plus JSON metadata.

A run directory holds ``steps.csv`` (a row written and flushed per step, so an interrupted run
loses nothing already recorded) and ``meta.json`` (parameters, controller, software version,
device, and, from :meth:`RunLog.close`, the timing statistics), rewritten atomically whenever it
changes. :func:`read_steps` reads a log back as numpy columns.

No log file is ever written through a link: ``steps.csv`` is created as a new file
(``O_EXCL``, and ``O_NOFOLLOW`` where the platform has it), ``meta.json`` is replaced by a
rename, and :func:`default_directory` creates each run's folder with ``mkdir``, which fails on
an existing name (a link among them) instead of sharing or following it.
"""

from __future__ import annotations

import csv
import math
import os
import platform
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import numpy.typing as npt

from frictiongym import __version__
from frictiongym._io import NEW_FILE_FLAGS, json_value, write_json_atomic

#: Columns of ``steps.csv`` before the observation's (which are named by the env).
STEP_COLUMNS = (
    "episode",
    "step",
    "time",
    "host_ns",
    "tick_us",
    "seq",
    "seq_applied",
    "late",
    "skipped",
    "status",
    "requested",
    "applied",
    "measured",
)
#: Columns after the observation's.
RESULT_COLUMNS = ("reward", "terminated")
#: Where runs go when the env is not told: ``$FRICTIONGYM_RUNS`` or ``./frictiongym-runs``.
DEFAULT_ROOT = "frictiongym-runs"


#: Names tried for a new run folder (``-2``, ``-3``... after the first) before giving up.
NAME_TRIES = 1000


def default_directory(device: str) -> Path:
    """Create and return a new run directory under ``$FRICTIONGYM_RUNS`` (./frictiongym-runs).

    It is named ``<UTC time>-<device>-<pid>``, then ``-2``, ``-3``... while that name is taken
    (envs opened in the same second). ``mkdir`` creates the folder or fails at once, so two
    envs opening together, in threads or processes, never share one, and an existing name (a
    link too) is never reused or followed.
    """
    root = Path(os.environ.get("FRICTIONGYM_RUNS", DEFAULT_ROOT))
    _make_folder(root, "the run logs' folder (FRICTIONGYM_RUNS)")
    base = f"{datetime.now(timezone.utc).strftime('%Y%m%d-%H%M%S')}-{device}-{os.getpid()}"
    for n in range(1, NAME_TRIES + 1):
        path = root / (base if n == 1 else f"{base}-{n}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        return path
    raise FileExistsError(
        f"{root} already holds {NAME_TRIES} run folders named {base}-N; clear it out or set "
        "FRICTIONGYM_RUNS to another folder"
    )


def _make_folder(folder: Path, what: str) -> None:
    """Create ``folder`` and its parents if missing; a clear FileExistsError if it cannot be."""
    if os.path.islink(folder) and not folder.exists():
        raise FileExistsError(
            f"{what} {folder} is a link to {os.readlink(folder)}, which does not exist; create "
            "that folder or give another"
        )
    if os.path.lexists(folder) and not folder.is_dir():
        raise FileExistsError(f"{what} {folder} is a file, not a folder; give another path")
    folder.mkdir(parents=True, exist_ok=True)


def software() -> dict[str, str]:
    """Versions that produced a run."""
    return {
        "frictiongym": __version__,
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "platform": platform.platform(),
    }


@dataclass(frozen=True)
class Timing:
    """How well a run kept its period (from the host's arrival times and device ticks)."""

    steps: int  #: steps timed (each after a previous step of its episode)
    duration: float  #: s, host clock, summed over the timed steps
    rate_hz: float  #: achieved steps per second
    period_p50: float  #: median |host period - dt|, s
    period_p99: float
    period_max: float
    late: int  #: commands that missed their tick and were held one period late
    skipped: int  #: device ticks without a host step (missed deadlines)

    @classmethod
    def from_periods(
        cls, periods: npt.ArrayLike, dt: float, late: int = 0, skipped: int = 0
    ) -> Timing:
        """Statistics of the host periods (s) between consecutive steps, for a period ``dt``."""
        p = np.asarray(periods, dtype=np.float64)
        error = np.abs(p - dt) if p.size else np.zeros(1)
        duration = float(p.sum())
        return cls(
            steps=int(p.size),
            duration=duration,
            rate_hz=p.size / duration if duration > 0 else math.nan,
            period_p50=float(np.percentile(error, 50)),
            period_p99=float(np.percentile(error, 99)),
            period_max=float(error.max()),
            late=int(late),
            skipped=int(skipped),
        )


class RunLog:
    """The log of one device run (any number of episodes).

    Parameters
    ----------
    directory : path
        Created if missing; must not already hold a log.
    observation_names : sequence of str
        Names of the observation's entries (CSV columns ``obs_<name>``).
    metadata : mapping
        Written to ``meta.json`` at once (parameters, device, controller...).
    """

    def __init__(
        self,
        directory: str | os.PathLike[str],
        observation_names: Sequence[str],
        metadata: Mapping[str, Any],
    ) -> None:
        self.directory = Path(directory)
        _make_folder(self.directory, "the run log directory")
        self.steps_path = self.directory / "steps.csv"
        self.meta_path = self.directory / "meta.json"
        self.columns = (*STEP_COLUMNS, *(f"obs_{n}" for n in observation_names), *RESULT_COLUMNS)
        if os.path.lexists(self.meta_path):
            self._refuse(self.meta_path)
        try:  # claims the folder: of two runs opening it at once, one gets FileExistsError
            descriptor = os.open(self.steps_path, NEW_FILE_FLAGS, 0o666)
        except FileExistsError:
            self._refuse(self.steps_path)
        self._file = os.fdopen(descriptor, "w", newline="", buffering=1)
        try:
            self._writer = csv.writer(self._file)
            self._writer.writerow(self.columns)
            self._file.flush()
            self.metadata: dict[str, Any] = {
                "format": "frictiongym.runlog/1",
                "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                "software": software(),
                "columns": list(self.columns),
                **metadata,
            }
            write_json_atomic(self.meta_path, self.metadata, default=json_value)
        except BaseException:  # no log without its metadata
            self._file.close()
            self.steps_path.unlink(missing_ok=True)
            raise
        self.rows = 0

    @staticmethod
    def _refuse(path: Path) -> NoReturn:
        link = " (a link: run logs never write through one)" if path.is_symlink() else ""
        raise FileExistsError(
            f"{path} already exists{link}; give each run its own directory (or omit the log "
            "directory for a new time-stamped one)"
        ) from None

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` ran."""
        return self._file.closed

    def record(self, row: Sequence[object]) -> None:
        """Append one step (values in :attr:`columns` order) and flush it to the file."""
        self._writer.writerow(row)
        self._file.flush()
        self.rows += 1

    def update(self, **metadata: Any) -> None:
        """Add to ``meta.json`` (rewritten atomically)."""
        self.metadata.update(metadata)
        write_json_atomic(self.meta_path, self.metadata, default=json_value)

    def close(self, **metadata: Any) -> None:
        """Close ``steps.csv`` and write the final metadata (idempotent)."""
        if self.closed:
            return
        self._file.close()
        self.update(
            ended=datetime.now(timezone.utc).isoformat(timespec="seconds"),
            rows=self.rows,
            **metadata,
        )


def read_steps(directory: str | os.PathLike[str]) -> dict[str, npt.NDArray[np.float64]]:
    """Read a run's ``steps.csv`` as float columns by name (a partial last line is dropped)."""
    path = Path(directory) / "steps.csv"
    with path.open(newline="") as handle:
        rows = list(csv.reader(handle))
    if not rows:
        raise ValueError(f"{path} is empty: not a frictiongym run log")
    header, body = rows[0], [r for r in rows[1:] if len(r) == len(rows[0])]
    data = np.array(body, dtype=np.float64).reshape(len(body), len(header))
    return {name: data[:, j] for j, name in enumerate(header)}
