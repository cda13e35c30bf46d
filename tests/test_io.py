"""The atomic text writer: all or nothing, and the permissions a plain write would give."""

import os
import stat

import pytest

from frictiongym._io import STAGING_PREFIX, OutputDir, write_text_atomic


def test_the_file_gets_the_permissions_of_a_plain_write(tmp_path):
    old = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "atomic.txt", "x")
        (tmp_path / "plain.txt").write_text("x")
    finally:
        os.umask(old)
    mode = [stat.S_IMODE((tmp_path / n).stat().st_mode) for n in ("atomic.txt", "plain.txt")]
    assert mode[0] == mode[1] == 0o644  # mkstemp alone would leave 0o600


def test_a_failed_write_keeps_the_old_file_and_leaves_nothing_behind(tmp_path):
    target = tmp_path / "results.md"
    target.write_text("old")
    with pytest.raises(TypeError):
        write_text_atomic(target, None)  # type: ignore[arg-type]
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.md"]


def test_a_killed_run_s_staging_folder_is_removed_by_the_next_run(tmp_path):
    """A SIGKILL leaves the staging folder; the next run into ``out`` removes it, but not the
    staging folder of a run still going (this process)."""
    out = tmp_path / "out"
    abandoned = out / f"{STAGING_PREFIX}999999999-0badc0de"  # beyond Linux's largest pid
    live = out / f"{STAGING_PREFIX}{os.getpid()}-0123abcd"
    for folder in (abandoned, live):
        (folder / "deep").mkdir(parents=True)
        (folder / "deep" / "results.json").write_text("half")
    with OutputDir(out, ["results.json"]) as run:
        (run.path / "results.json").write_text("{}")
        run.commit()
    assert not abandoned.exists()
    assert (live / "deep" / "results.json").read_text() == "half"
    assert (out / "results.json").read_text() == "{}"
