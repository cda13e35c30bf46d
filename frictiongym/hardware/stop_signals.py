"""Stopping the motors on ``SIGTERM`` and ``SIGHUP``, as a Ctrl-C inside a step does.

``kill PID``, a closed terminal or a service manager's stop end a process without raising
``KeyboardInterrupt``, and without running ``atexit`` either: a device would hold its last
command (the stock Altino, which has no watchdog, indefinitely). While a device backend is
open, :func:`install_stop_signals` puts a handler on both signals that first stops every open
device, then does what the signal did before:

* a Python handler installed earlier is called (the emulator's, a user's);
* the default action becomes ``SystemExit(128 + signal)``, so ``finally`` blocks, ``with``
  blocks and ``atexit`` still run (a run log is closed, the link too) and the exit status is
  the shell's convention for a death by that signal (143 for ``SIGTERM``, 129 for ``SIGHUP``);
* a signal that was ignored (``nohup``) stays ignored, and one whose handler Python does not
  know (set from C) is left alone.

Handlers are installed from the main thread only (Python allows no other; a backend opened in
another thread relies on ``atexit`` and the device's watchdog) and restored when the last
backend closes, unless someone replaced ours meanwhile.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

#: The signals that stop the devices (those this platform has).
STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)
)

_stop_devices: Callable[[], None] | None = None
_previous: dict[int, Any] = {}  # signal -> the handler ours replaced


def _on_stop_signal(signum: int, frame: FrameType | None) -> None:
    """Stop every open device, then act as the handler ours replaced would have."""
    if _stop_devices is not None:
        _stop_devices()
    previous = _previous.get(signum, signal.SIG_DFL)
    if callable(previous):
        previous(signum, frame)
    elif previous is not signal.SIG_IGN:
        raise SystemExit(128 + signum)


def install_stop_signals(stop_devices: Callable[[], None]) -> None:
    """Put :func:`_on_stop_signal` on :data:`STOP_SIGNALS` (main thread only; idempotent).

    ``stop_devices`` zeroes every open device's motor; it must not raise.
    """
    global _stop_devices
    _stop_devices = stop_devices
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in STOP_SIGNALS:
        current = signal.getsignal(sig)
        if current is _on_stop_signal or current is None or current is signal.SIG_IGN:
            continue  # ours already; set outside Python; or ignored on purpose (nohup)
        _previous[sig] = current
        signal.signal(sig, _on_stop_signal)


def release_stop_signals() -> None:
    """Put back the handlers ours replaced, where ours is still in place (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        return  # ours stays; with no device open it only hands over to the previous one
    for sig, previous in list(_previous.items()):
        if signal.getsignal(sig) is _on_stop_signal:
            signal.signal(sig, previous)
        del _previous[sig]


__all__ = ["STOP_SIGNALS", "install_stop_signals", "release_stop_signals"]
