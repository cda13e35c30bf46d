"""Run-log folders: unique and created atomically, and no log file written through a link."""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym import _io
from frictiongym.hardware import runlog
from frictiongym.hardware.runlog import RunLog, default_directory, read_steps

SERVO = "frictiongym/RotaryServo-v1"
NAMES = ("angle",)
ROW = (0, 0, 0.0, 1, 2, 3, 4, 0, 0, 0, 0.5, 0.5, 0.1, 0.1, 0.0, 0)


class OneSecond(datetime):
    """A clock stopped within one second: every run opens "at the same time"."""

    @classmethod
    def now(cls, tz=None):
        return datetime(2026, 1, 2, 3, 4, 5, tzinfo=timezone.utc)


@pytest.fixture
def runs(tmp_path, monkeypatch):
    """``$FRICTIONGYM_RUNS`` in a temporary folder, with the clock stopped."""
    root = tmp_path / "runs"
    monkeypatch.setenv("FRICTIONGYM_RUNS", str(root))
    monkeypatch.setattr(runlog, "datetime", OneSecond)
    return root


def _open_log(marker: int) -> RunLog:
    log = RunLog(default_directory("rotary"), NAMES, {"marker": marker})
    log.record((marker, *ROW[1:]))
    return log


def _at_once(count: int, run: Callable[[int], None]) -> None:
    """Run ``run(i)`` for i < ``count`` in threads released together."""
    barrier = threading.Barrier(count)

    def released(i: int) -> None:
        barrier.wait()
        run(i)

    threads = [threading.Thread(target=released, args=(i,)) for i in range(count)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()


def _marker_of(folder: Path) -> tuple[int, list[float]]:
    meta = json.loads((folder / "meta.json").read_text())
    return meta["marker"], read_steps(folder)["episode"].tolist()


def test_runs_opened_in_the_same_second_get_their_own_folders(runs):
    logs = [_open_log(i) for i in range(3)]
    for log in logs:
        log.close()
    base = f"20260102-030405-rotary-{os.getpid()}"
    assert [log.directory.name for log in logs] == [base, f"{base}-2", f"{base}-3"]
    assert [_marker_of(log.directory) for log in logs] == [(i, [i]) for i in range(3)]


def test_two_device_envs_opened_at_once_log_apart(runs):
    envs = [gym.make(SERVO, backend="emulator://rotary?lockstep=1", log=True) for _ in range(2)]
    for env in envs:
        env.reset(seed=0)
        env.step(np.array([0.5]))
        env.close()
    folders = sorted(runs.iterdir())
    assert len(folders) == 2
    assert [len(read_steps(f)["step"]) for f in folders] == [2, 2]


def test_threads_opening_at_once_never_share_a_folder(runs):
    count = 8
    logs, errors = [None] * count, []

    def open_one(i: int) -> None:
        try:
            logs[i] = _open_log(i)
        except Exception as error:  # reported below
            errors.append(error)

    _at_once(count, open_one)
    assert errors == []
    for log in logs:
        log.close()
    assert len({log.directory for log in logs}) == count
    # Each folder's metadata and steps are of one run.
    assert sorted(_marker_of(log.directory) for log in logs) == [(i, [i]) for i in range(count)]


def test_threads_given_one_folder_leave_it_to_one_run(tmp_path):
    count, folder = 8, tmp_path / "shared"
    opened, refused = [], []

    def open_one(i: int) -> None:
        try:
            log = RunLog(folder, NAMES, {"marker": i})
        except FileExistsError:
            refused.append(i)
        else:
            log.record((i, *ROW[1:]))
            opened.append(log)

    _at_once(count, open_one)
    assert len(opened) == 1
    assert len(refused) == count - 1
    opened[0].close()
    marker = opened[0].metadata["marker"]
    assert _marker_of(folder) == (marker, [marker])


def test_a_dangling_steps_link_is_refused_not_followed(tmp_path):
    folder, target = tmp_path / "run", tmp_path / "elsewhere.csv"
    folder.mkdir()
    (folder / "steps.csv").symlink_to(target)
    with pytest.raises(FileExistsError, match="a link: run logs never write through one"):
        RunLog(folder, NAMES, {})
    assert not target.exists()
    assert not (folder / "meta.json").exists()


def test_a_meta_link_is_refused_and_its_target_untouched(tmp_path):
    folder, victim = tmp_path / "run", tmp_path / "victim.txt"
    folder.mkdir()
    victim.write_text("keep me\n")
    (folder / "meta.json").symlink_to(victim)
    with pytest.raises(FileExistsError, match=r"meta\.json already exists"):
        RunLog(folder, NAMES, {})
    assert victim.read_text() == "keep me\n"
    assert not (folder / "steps.csv").exists()


def test_meta_rewrites_never_write_through_a_link(tmp_path, monkeypatch):
    """A link put in place of meta.json, or of its temporary file while it is being written."""
    log, victim = RunLog(tmp_path / "run", NAMES, {}), tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    log.meta_path.unlink()
    log.meta_path.symlink_to(victim)
    log.update(note="after the swap")
    assert victim.read_text() == "keep me\n"
    assert json.loads(log.meta_path.read_text())["note"] == "after the swap"
    real_open = os.open

    def swapped(path, flags, mode=0o777, **kwargs):
        descriptor = real_open(path, flags, mode, **kwargs)
        if str(path).endswith(".tmp"):  # the race: the new temporary file becomes a link
            os.unlink(path)
            os.symlink(victim, path)
        return descriptor

    monkeypatch.setattr(_io.os, "open", swapped)
    log.update(note="raced")
    monkeypatch.undo()
    assert victim.read_text() == "keep me\n"
    log.close()


def test_a_log_folder_given_as_a_link_is_followed_a_dangling_one_refused(tmp_path):
    real, link = tmp_path / "real", tmp_path / "link"
    real.mkdir()
    link.symlink_to(real)
    log = RunLog(link, NAMES, {})
    log.close()
    assert sorted(p.name for p in real.iterdir()) == ["meta.json", "steps.csv"]
    dangling, missing = tmp_path / "dangling", tmp_path / "missing"
    dangling.symlink_to(missing)
    with pytest.raises(FileExistsError, match="does not exist; create that folder"):
        RunLog(dangling, NAMES, {})
    assert not missing.exists()


def test_a_link_at_the_next_run_name_is_skipped_not_followed(runs):
    runs.mkdir()
    target = runs.parent / "elsewhere"
    (runs / f"20260102-030405-rotary-{os.getpid()}").symlink_to(target)
    log = _open_log(0)
    log.close()
    assert log.directory.name.endswith("-2")
    assert not target.exists()
