"""The output module: atomic text, JSON, CSV and figure writes; the ``--out`` folder."""

import dataclasses
import json
import os
import stat
import subprocess
import sys

import numpy as np
import pytest

from frictiongym._io import (
    STAGING_PREFIX,
    OutputDir,
    csv_text,
    json_value,
    pyplot,
    save_figure,
    write_json_atomic,
    write_text_atomic,
)


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


def test_json_is_written_whole_with_the_options_given(tmp_path):
    target = tmp_path / "results.json"
    write_json_atomic(target, {"a": [1.5, 2]}, indent=1)
    assert target.read_text() == '{\n "a": [\n  1.5,\n  2\n ]\n}\n'
    target.write_text("old")
    with pytest.raises(ValueError, match="JSON compliant"):
        write_json_atomic(target, {"a": float("nan")}, allow_nan=False)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.json"]


def test_json_value_writes_numpy_and_dataclasses(tmp_path):
    @dataclasses.dataclass
    class Gains:
        kp: float

    data = {"x": np.float32(0.5), "v": np.arange(3), "g": Gains(2.0), "p": tmp_path}
    write_json_atomic(tmp_path / "meta.json", data, default=json_value)
    read = json.loads((tmp_path / "meta.json").read_text())
    assert read == {"x": 0.5, "v": [0, 1, 2], "g": {"kp": 2.0}, "p": repr(tmp_path)}


def test_csv_text_has_lf_line_ends_and_quotes_what_needs_it():
    assert csv_text([["a", "b"], [1, "x,y"], [2.5, None]]) == 'a,b\n1,"x,y"\n2.5,\n'


def test_a_figure_is_saved_whole_in_the_format_its_name_says_and_closed(tmp_path):
    plt = pyplot()
    assert plt.get_backend().lower() == "agg"
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    assert save_figure(fig, tmp_path / "f.png", dpi=50) == tmp_path / "f.png"
    assert (tmp_path / "f.png").read_bytes().startswith(b"\x89PNG")
    assert not plt.fignum_exists(fig.number)
    fig, _ = plt.subplots()
    save_figure(fig, tmp_path / "f.svg", dpi=50)
    assert b"<svg" in (tmp_path / "f.svg").read_bytes()
    fig, _ = plt.subplots()
    with pytest.raises(ValueError, match="not supported"):
        save_figure(fig, tmp_path / "f.nope", dpi=50)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png", "f.svg"]


def test_the_io_module_imports_nothing_heavy():
    code = "import sys, frictiongym._io; print(sorted(set(sys.modules) & {'numpy', 'matplotlib'}))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
