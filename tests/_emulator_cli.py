"""The emulator's command in another process, for the tests that connect to it."""

from __future__ import annotations

import select
import signal
import subprocess
from collections.abc import Iterator, Sequence
from contextlib import contextmanager


@contextmanager
def emulator_port(argv: Sequence[str], timeout: float = 60.0) -> Iterator[str]:
    """Run ``argv`` (an emulator's command line), yield the port it prints first.

    On leaving, the emulator must stop on a SIGINT with status 0; it is killed if it is
    still running after a failure.
    """
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], timeout)
        assert ready, proc.stderr.read() if proc.poll() is not None else "it printed nothing"
        yield proc.stdout.readline().strip()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
