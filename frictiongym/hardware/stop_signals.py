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

Handlers are installed from the main thread only (Python allows no other) and restored when
the last backend closes, unless someone replaced ours meanwhile. A backend opened in another
thread is covered only if the main thread installed them first, for good, with
:func:`frictiongym.hardware.stop_devices_on_signals`; otherwise it warns once (``atexit`` does
not run on these signals, and the stock Altino has no watchdog).
"""

from __future__ import annotations

import signal
import threading
import warnings
from collections.abc import Callable
from types import FrameType
from typing import Any

#: The signals that stop the devices (those this platform has).
STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)
)

_stop_devices: Callable[[], None] | None = None
_previous: dict[int, Any] = {}  # signal -> the handler ours replaced
_kept = False  # installed for good (stop_devices_on_signals): not released on close
_warned = False


def _on_stop_signal(signum: int, frame: FrameType | None) -> None:
    """Stop every open device, then act as the handler ours replaced would have."""
    if _stop_devices is not None:
        _stop_devices()
    previous = _previous.get(signum, signal.SIG_DFL)
    if callable(previous):
        previous(signum, frame)
    elif previous is not signal.SIG_IGN:
        raise SystemExit(128 + signum)


def install_stop_signals(stop_devices: Callable[[], None], keep: bool = False) -> None:
    """Put :func:`_on_stop_signal` on :data:`STOP_SIGNALS` (main thread only; idempotent).

    ``stop_devices`` zeroes every open device's motor; it must not raise. ``keep``: leave the
    handlers in place when the last device closes. From another thread nothing can be
    installed: unless the main thread did so before, this warns once.
    """
    global _stop_devices, _kept, _warned
    _stop_devices = stop_devices
    if threading.current_thread() is not threading.main_thread():
        covered = all(signal.getsignal(sig) is _on_stop_signal for sig in STOP_SIGNALS)
        if not (covered or _warned):
            _warned = True
            warnings.warn(
                "a device opened outside the main thread is not stopped by SIGTERM or SIGHUP "
                "(only the main thread can set signal handlers, and atexit does not run on "
                "them): call frictiongym.hardware.stop_devices_on_signals() from the main "
                "thread before starting the thread",
                RuntimeWarning,
                stacklevel=4,
            )
        return
    _kept = _kept or keep
    for sig in STOP_SIGNALS:
        current = signal.getsignal(sig)
        if current is _on_stop_signal or current is None or current is signal.SIG_IGN:
            continue  # ours already; set outside Python; or ignored on purpose (nohup)
        _previous[sig] = current
        signal.signal(sig, _on_stop_signal)


def release_stop_signals() -> None:
    """Put back the handlers ours replaced, where ours is still in place (main thread only)."""
    if _kept or threading.current_thread() is not threading.main_thread():
        return  # ours stays; with no device open it only hands over to the previous one
    for sig, previous in list(_previous.items()):
        if signal.getsignal(sig) is _on_stop_signal:
            signal.signal(sig, previous)
        del _previous[sig]


__all__ = ["STOP_SIGNALS", "install_stop_signals", "release_stop_signals"]
