"""Writing files so that a reader never sees half of one, and runs that never mix their outputs.

Every result the package writes goes through here. :func:`write_text_atomic`,
:func:`write_json_atomic` (with :func:`csv_text` for CSV) and :func:`write_file_atomic` replace
one file whole; :func:`save_figure` does so for a matplotlib figure, which :func:`pyplot`
draws with the one backend the package uses (Agg: files, never a window).
:class:`OutputDir` is a tool's ``--out`` folder: checked before the work starts, written by
the run into a hidden folder inside it, and moved into place only when the run succeeds, so
an error or a Ctrl-C leaves the folder as it was. A folder that holds an earlier run's
results is refused unless the user asks to replace them (``--overwrite``).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import io
import json
import os
import secrets
import shutil
import signal
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

#: Prefix of the hidden folder a staged run writes into, inside its ``--out``.
STAGING_PREFIX = ".frictiongym-partial-"


#: Flags of a file that must be new: never opened through a link (``O_EXCL`` refuses any
#: existing name, a dangling link among them; ``O_NOFOLLOW`` where the platform has it).
NEW_FILE_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)


def _new_temporary(target: Path) -> tuple[Path, int]:
    """Create a file under a new random name beside ``target``; return it and its descriptor."""
    while True:
        tmp = target.with_name(f".{target.name}.{secrets.token_hex(4)}.tmp")
        try:
            # Mode 0o666 less the umask, as open() gives; mkstemp would make it 0600.
            return tmp, os.open(tmp, NEW_FILE_FLAGS, 0o666)
        except FileExistsError:
            continue


def _replace_with(tmp: Path, target: Path, fill: Callable[[], object]) -> None:
    """Run ``fill()`` (which writes ``tmp``), rename ``tmp`` to ``target``; remove it on error.

    The rename replaces a link at ``target`` instead of writing through it.
    """
    try:
        fill()
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_file_atomic(path: str | os.PathLike[str], write: Callable[[Path], object]) -> None:
    """Have ``write(tmp)`` write a temporary file beside ``path``, then rename it to ``path``.

    An error (or an interruption) leaves an existing file as it was and no temporary file
    behind. The file gets the permissions a plain ``open(path, "w")`` would give.
    """
    target = Path(path)
    tmp, descriptor = _new_temporary(target)
    os.close(descriptor)
    _replace_with(tmp, target, lambda: write(tmp))


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` whole or not at all (see :func:`write_file_atomic`).

    The text goes through the descriptor that created the temporary file, so a link put in its
    place meanwhile is not written through.
    """
    if not isinstance(text, str):  # before the temporary file exists
        raise TypeError(f"text must be a str, got {type(text).__name__}")
    target = Path(path)
    tmp, descriptor = _new_temporary(target)

    def fill() -> None:
        with os.fdopen(descriptor, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())  # on disk before the rename, so a power cut keeps one

    _replace_with(tmp, target, fill)


def write_json_atomic(
    path: str | os.PathLike[str], data: object, *, indent: int = 2, **options: Any
) -> None:
    """Write ``data`` as JSON and a newline to ``path`` whole or not at all.

    ``options`` go to :func:`json.dumps`, e.g. ``allow_nan=False`` or ``default=json_value``.
    """
    write_text_atomic(path, json.dumps(data, indent=indent, **options) + "\n")


def json_value(value: Any) -> Any:
    """JSON form of a value ``json`` cannot write (a ``default`` for :func:`write_json_atomic`).

    numpy scalars and arrays become numbers and lists, dataclasses dicts, anything else its
    ``repr``.
    """
    if hasattr(value, "tolist"):  # numpy, without importing it here
        return value.tolist()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    return repr(value)


def csv_text(rows: Iterable[Sequence[object]]) -> str:
    """Return ``rows`` as CSV text, one line (LF-ended) per row, for :func:`write_text_atomic`."""
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    return out.getvalue()


def pyplot() -> Any:
    """Return ``matplotlib.pyplot`` on the Agg backend: the one place the package chooses it.

    matplotlib is imported only when a figure is drawn: it is heavy, and the metrics are
    complete without it. Raises ``ImportError`` without it.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot

    return matplotlib.pyplot


def save_figure(figure: Any, path: str | os.PathLike[str], dpi: int) -> Path:
    """Write ``figure`` to ``path`` whole or not at all, then close it; return ``path``.

    The format is the one the file name's suffix names (PNG without a suffix).
    """
    target = Path(path)
    image_format = target.suffix[1:].lower() or "png"
    try:
        write_file_atomic(target, lambda tmp: figure.savefig(tmp, format=image_format, dpi=dpi))
    finally:
        pyplot().close(figure)
    return target


def add_output_arguments(parser: argparse.ArgumentParser, default: str, contents: str) -> None:
    """Add ``--out DIR`` and ``--overwrite``, the output options every tool shares.

    ``contents`` says what the tool writes there, e.g. ``"results.json and the figures"``.
    """
    parser.add_argument(
        "--out",
        type=Path,
        default=Path(default),
        metavar="DIR",
        help=f"directory for {contents}, created if needed (default: ./{default})",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the results of an earlier run in --out, all of them (without it, an "
        "--out holding them is refused, so two runs' files never mix); other files stay",
    )


class OutputError(Exception):
    """An output path the run cannot use; the message says why and what to give instead."""


def _reason(error: OSError) -> str:
    return error.strerror or str(error)


def _probe(folder: Path) -> None:
    """Create and remove a file in ``folder`` (OSError if it cannot be written)."""
    probe = folder / f".frictiongym-probe-{secrets.token_hex(4)}"
    os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    probe.unlink()


@contextlib.contextmanager
def sigint_held() -> Iterator[None]:
    """Ignore Ctrl-C inside the block (in the main thread), so a cleanup or a commit finishes.

    The block must be short: a few renames or the removal of a temporary folder.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _first_existing(path: Path) -> Path:
    """Return ``path`` or its nearest ancestor that exists."""
    for candidate in (path, *path.parents):
        if candidate.exists():
            return candidate
    return Path(".")  # pragma: no cover (a relative path's "." exists)


def check_file_target(path: Path, option: str) -> None:
    """Check before the work that a file can be written at ``path`` (its folder must exist).

    Raises
    ------
    OutputError
        When ``path`` is a folder, its folder is missing or not a folder, or not writable.
    """
    folder = path.parent
    if path.is_dir():
        raise OutputError(f"{option} {path} is a directory; give a file name")
    if not folder.is_dir():
        what = "is a file" if folder.exists() else "does not exist"
        raise OutputError(
            f"{option} {path}: the folder {folder} {what}; give a path in an existing folder"
        )
    try:
        _probe(folder)
    except OSError as error:
        raise OutputError(
            f"cannot write {option} {path}: {_reason(error)}; give a path in a writable folder"
        ) from None


class OutputDir:
    """A tool's output folder, checked before the work and written whole or not at all.

    Use it as a context manager: entering it checks the folder (creating it and any missing
    parents) and that it can be written, and raises :class:`OutputError` otherwise; the run
    writes into :attr:`path` and calls :meth:`commit` when done. Leaving the block without a
    commit (an error, a Ctrl-C, an exit status other than 0) removes what the run wrote and
    the folders it created.

    Parameters
    ----------
    out : Path
        The folder (``--out``).
    outputs : iterable of str
        The names (files or folders) a run of the tool may write into ``out``. Any of them
        present marks an earlier run's results; other files in ``out`` are never touched.
    overwrite : bool, default False
        Replace an earlier run's results: all of them, so no file of that run stays beside
        the new ones. Without it, a folder holding any of them is refused.
    staged : bool, default True
        The run writes into a hidden folder inside ``out`` (:attr:`path`), and :meth:`commit`
        moves its outputs into place. False: the run writes into ``out`` itself, for a run
        whose partial outputs are meant to stay (``frictiongym train``'s checkpoints); it
        calls :meth:`replace_earlier` before it writes.
    continuing : bool, default False
        The run continues the earlier run's results in place (``frictiongym train
        --resume``): they are neither refused nor replaced.
    resumable : bool, default False
        An earlier run can be continued: the refusal also suggests ``--resume``.
    option : str, default "--out"
        The option named in the messages.
    """

    def __init__(
        self,
        out: Path,
        outputs: Iterable[str],
        *,
        overwrite: bool = False,
        staged: bool = True,
        continuing: bool = False,
        resumable: bool = False,
        option: str = "--out",
    ) -> None:
        self.out = Path(out)
        self.outputs = tuple(outputs)
        self.overwrite = overwrite
        self.staged = staged
        self.continuing = continuing
        self.resumable = resumable
        self.option = option
        #: Where the run writes: the staging folder, or ``out`` when not staged.
        self.path = self.out
        self._created: list[Path] = []
        self._committed = False

    def earlier(self) -> list[str]:
        """Return the names of the outputs of an earlier run present in ``out``."""
        return [n for n in self.outputs if os.path.lexists(self.out / n)]

    def __enter__(self) -> OutputDir:
        out, option = self.out, self.option
        if out.exists() and not out.is_dir():
            raise OutputError(f"{option} {out} is a file, not a directory; give a directory")
        base = _first_existing(out)
        if not base.is_dir():
            raise OutputError(
                f"{option} {out}: {base} is a file, not a directory; give a "
                "path whose parents are directories"
            )
        found = self.earlier()
        if found and not (self.overwrite or self.continuing):
            shown = ", ".join(found[:4]) + (", ..." if len(found) > 4 else "")
            resume = ", --resume to continue them" if self.resumable else ""
            raise OutputError(
                f"{option} {out} holds the results of an earlier run ({shown}); give "
                f"--overwrite to replace them{resume} or another {option}"
            )
        missing = [p for p in (out, *out.parents) if p != base and base in p.parents]
        try:
            for folder in reversed(missing):
                folder.mkdir()
                self._created.append(folder)
            if self.staged:
                _remove_abandoned_staging(out)
                self.path = out / f"{STAGING_PREFIX}{os.getpid()}-{secrets.token_hex(4)}"
                self.path.mkdir()
            _probe(self.path)
        except OSError as error:
            self._discard()
            raise OutputError(
                f"cannot write to {option} {out}: {_reason(error)}; give a writable {option}"
            ) from None
        except BaseException:
            self._discard()
            raise
        return self

    def final(self, path: Path) -> Path:
        """Return where ``path``, written under :attr:`path`, lies after the commit."""
        return self.out / Path(path).relative_to(self.path)

    def replace_earlier(self) -> None:
        """Remove an earlier run's outputs now (``overwrite``, not staged, not continuing)."""
        if self.overwrite and not self.continuing:
            with sigint_held():
                for name in self.earlier():
                    _remove(self.out / name)

    def commit(self) -> list[Path]:
        """Move the run's outputs into ``out`` (replacing an earlier run's); return them."""
        if not self.staged:
            self._committed = True
            return []
        with sigint_held():
            old = self.path / ".earlier"
            if not self.continuing:
                old.mkdir()
                for name in self.earlier():  # all of the earlier run's, written now or not
                    os.replace(self.out / name, old / name)
            written = []
            for entry in sorted(self.path.iterdir()):
                if entry != old:
                    os.replace(entry, self.out / entry.name)
                    written.append(self.out / entry.name)
            shutil.rmtree(self.path, ignore_errors=True)
            self._committed = True
        return written

    def _discard(self) -> None:
        with sigint_held():
            if self.staged and self.path != self.out:
                shutil.rmtree(self.path, ignore_errors=True)
            for folder in reversed(self._created):  # the deepest first; only if left empty
                with contextlib.suppress(OSError):
                    folder.rmdir()

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if self._committed:
            return
        self._discard()
        if isinstance(error, KeyboardInterrupt) and not error.args:
            kept = "left as it was" if self.out.exists() else "not created"
            error.args = (f"{self.option} {self.out} {kept}",)


def _remove_abandoned_staging(out: Path) -> None:
    """Remove staging folders of runs that were killed outright (``SIGKILL``, a power cut).

    A staging folder is named after its process; one whose process no longer runs is
    abandoned. Folders of live processes (another run into the same ``out``) stay.
    """
    for path in out.glob(f"{STAGING_PREFIX}*"):
        owner = path.name.removeprefix(STAGING_PREFIX).partition("-")[0]
        if owner.isdigit() and not _process_alive(int(owner)) and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):  # another user's process; or not a pid at all
        return True
    return True


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink()
