"""Keeping a device loop on time on a general-purpose host: the garbage collector, the scheduler.

Two things stalled the host loop for longer than a device's watchdog in our measurements
(docs/hardware.md, "Timing and the watchdog"):

* **A full garbage collection** scans every object of the process: 40-330 ms in ``frictiongym
  sim2real`` (it imports numba, gymnasium and matplotlib), over 1 s in a test process that has
  imported torch. :func:`freeze_heap` moves every object alive now out of the collector's reach
  (:func:`gc.freeze`, O(1)), so the collections during an episode scan only what the episode
  allocated; :func:`thaw_heap` hands them back when the device closes. Reference counting
  still frees frozen objects; only reference cycles among them wait for the thaw.
* **The scheduler**: with every core busy, a woken loop may wait several time slices before
  it runs. :func:`realtime_priority` runs the calling thread under ``SCHED_FIFO`` where the
  system permits it (root, ``CAP_SYS_NICE``, or an ``rtprio`` limit in
  ``/etc/security/limits.conf``), and says why not where it does not; the loop then holds its
  period with other cores busy. Without it, the device's watchdog margin absorbs the stalls.
"""

from __future__ import annotations

import gc
import os
from collections.abc import Iterator
from contextlib import contextmanager

#: ``SCHED_FIFO`` priority of a device loop: above every ordinary task, below the kernel's
#: interrupt threads (50), so a runaway loop cannot starve the system's I/O.
REALTIME_PRIORITY = 10

_frozen_by: set[int] = set()


def freeze_heap(owner: object) -> None:
    """Keep the garbage collector off every object alive now, until ``owner`` thaws it.

    Cheap (no collection runs); call it when a real-time phase starts, e.g. before a device
    is armed.
    """
    _frozen_by.add(id(owner))
    gc.freeze()


def thaw_heap(owner: object) -> None:
    """Hand the frozen objects back to the collector once no owner holds them (idempotent)."""
    if id(owner) not in _frozen_by:
        return
    _frozen_by.discard(id(owner))
    if not _frozen_by:
        gc.unfreeze()


def raise_priority(priority: int = REALTIME_PRIORITY) -> str | None:
    """Run the calling thread under ``SCHED_FIFO`` at ``priority``.

    Returns
    -------
    str or None
        None if it now runs so, else why not (the thread keeps its priority).
    """
    setscheduler = getattr(os, "sched_setscheduler", None)
    if setscheduler is None or not hasattr(os, "SCHED_FIFO"):
        return "not supported on this system"
    policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)  # children start ordinary
    try:
        setscheduler(0, policy, os.sched_param(priority))
    except PermissionError:
        return "not permitted (it needs root, CAP_SYS_NICE or an rtprio limit)"
    except OSError as exc:
        return f"refused ({exc.strerror})"
    return None


def describe_priority(why_not: str | None, priority: int = REALTIME_PRIORITY) -> str:
    """Say what a thread got from :func:`raise_priority` (its answer ``why_not``)."""
    if why_not is None:
        return f"SCHED_FIFO {priority}"
    return f"ordinary, SCHED_FIFO {why_not}"


@contextmanager
def realtime_priority(priority: int = REALTIME_PRIORITY) -> Iterator[str]:
    """Run the block with the calling thread under ``SCHED_FIFO``, where permitted.

    Yields a description of what the thread got (``"SCHED_FIFO 10"`` or ``"ordinary, SCHED_FIFO
    not permitted ..."``) for logs and reports; the thread's own scheduling is restored
    afterwards. Keep inside only the loop: threads started inside inherit it.
    """
    getscheduler = getattr(os, "sched_getscheduler", None)
    if getscheduler is None:
        yield describe_priority("not supported on this system", priority)
        return
    policy, previous = getscheduler(0), os.sched_getparam(0).sched_priority
    why_not = raise_priority(priority)
    try:
        yield describe_priority(why_not, priority)
    finally:
        if why_not is None:
            try:
                os.sched_setscheduler(0, policy, os.sched_param(previous))
            except OSError:  # best effort
                pass


__all__ = [
    "REALTIME_PRIORITY",
    "describe_priority",
    "freeze_heap",
    "raise_priority",
    "realtime_priority",
    "thaw_heap",
]
