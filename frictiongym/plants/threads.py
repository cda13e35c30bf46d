"""Which twin of a batched kernel runs a call: the serial loop, numba's threads, or the faster now.

Each batched kernel (:func:`~frictiongym.plants._batch.step_batch`,
:func:`~frictiongym.envs._kernel.step_envs`) has a serial twin and a threaded ``prange`` twin
that give bit-identical results. The threads pay off on an idle machine, but every call ends in a
join that waits for all of numba's threads: when another process, or torch's own OpenMP threads
in the same process, holds a core, a descheduled worker stalls each call and the threaded kernel
ran 5 to 40 times slower than the serial one at 4 096 envs (docs/benchmarks.md, "Threads beside
a learner").
No fixed rule is right on both sides of that, so :class:`AdaptiveKernel` times the calls
themselves and runs whichever twin is currently faster. Since the twins agree bit for bit, the
choice changes how long a call takes, never what it computes.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import numba
import numpy as np

#: A compiled batch kernel: the serial and threaded twins take the same arguments and return
#: the same int (-1, or the index of the first non-finite command).
Kernel = Callable[..., int]

#: Batches smaller than this always run serially: below it the threads gain little even on an
#: idle machine (their fork/join costs a few µs per call), and timing the calls would cost over
#: 1.5 % of a serial call (docs/benchmarks.md).
PARALLEL_MIN_PLANTS = 512

#: Calls of the twin in use between two looks at the timings (the bookkeeping runs once per
#: block, so a call costs only two clock reads more than the bare kernel).
BLOCK_CALLS = 8
#: After a trial takes over, this many blocks of one call each: a trial won by luck (three
#: fast calls between a learner's bursts) is undone after one slow call, not eight.
PROBATION = 4
#: Calls measured in a trial of a twin, after one warm-up call whose time counts towards the
#: trial's cost but not its figure (a worker asleep since the last threaded call must wake).
#: A trial's figure is the median of its measured calls: beside a learner one call of either
#: twin can stall for tens of ms (the main thread descheduled), and a serial trial whose mean
#: took such a stall once handed the kernel to threads whose calls all stalled, for rounds of
#: a benchmark (docs/benchmarks.md, "Eighth round"). A trial of the threads stops at its first
#: call too slow to win, a trial of the serial twin once its median cannot win.
TRIAL_CALLS = 3
#: Weight of the latest block in the running mean call time of the twin in use.
SMOOTHING = 0.25
#: A trial must beat the twin in use by this fraction to take over (no flapping on noise).
MARGIN = 0.03
#: The other twin is tried again once the calls since its last trial have taken ``1 / BUDGET``
#: times what that trial lost, so trials cost about this fraction of the time at most ...
BUDGET = 0.01
#: ... but after at most this many seconds of calls (one unlucky trial, stalled by a burst of
#: other work, must not keep the threads away for long once the machine is idle again), a wait
#: that doubles with every trial lost in a row up to ``MAX_BACKOFF``: beside a learner a trial
#: of the threads can stall for tens of ms, which retried every second cost 10 % ...
MAX_WAIT = 1.0
MAX_BACKOFF = 16.0
#: ... and never sooner than this many calls after the last trial, unless the twin in use has
#: become slower than the other was at its last trial.
MIN_GAP = 16

_WARM_UP, _TRIAL, _USING = 0, 1, 2

#: What the batches of each pair of twins have learnt: per batch element, the seconds per call
#: of each twin and the last trial's loss; the twin in use; the seconds and calls spent on it
#: since that trial; the longest wait for the next. A new batch of the same twins goes on from
#: there instead of trying both twins again: a tuner's short chunks would otherwise each pay a
#: losing trial (7 % of a chunk beside a busy core), and never run long enough to try the
#: threads again.
_LEARNT: dict[tuple[Kernel, Kernel], tuple[float, float, float, int, float, int, float]] = {}


class AdaptiveKernel:
    """Call the faster of two bit-identical kernel twins, judged by timing the calls.

    It starts with a trial of each twin, then runs the faster one and keeps a running mean of
    its call time. Now and then it tries the other twin again for ``1 + TRIAL_CALLS`` calls and
    switches if that twin's median call was faster by ``MARGIN``. A trial is due once the time
    spent since the last one reaches ``1 / BUDGET`` times what that last trial lost (at most
    ``MAX_WAIT``), so a twin that lost badly, such as the threaded one beside a learner, is
    retried rarely, while twins close in speed are compared often; if the twin in use slows
    down past the other's last time, the trial comes at once.

    Parameters
    ----------
    serial, parallel : callable
        The serial and the threaded twin of one kernel.

    Attributes
    ----------
    calls : list of int
        Calls so far on each twin, ``[serial, threaded]``, counted at the end of each block.
    switches : int
        Times a trial took over from the twin in use.
    """

    __slots__ = (
        "_block",
        "_credit",
        "_gap",
        "_kernel",
        "_kernels",
        "_left",
        "_loss",
        "_mean",
        "_phase",
        "_probation",
        "_running",
        "_size",
        "_tenure",
        "_time",
        "_trial_calls",
        "_trial_cost",
        "_using",
        "_wait",
        "calls",
        "switches",
    )

    def __init__(self, serial: Kernel, parallel: Kernel, size: int = 0) -> None:
        self._kernels = (serial, parallel)
        self._size = float(size)  # batch elements, 0 if unknown: then nothing is shared
        #: seconds per call of each twin: a running mean for the one in use, the last trial's
        #: median for the other
        self._mean = [0.0, 0.0]
        self._using = 0  # the twin in use: 0 serial, 1 threaded
        self._credit = 0.0  # seconds spent on the twin in use since the last trial
        self._gap = 0  # calls since the last trial
        self._loss = 0.0  # seconds the last trial of the other twin cost beyond the one in use
        self._wait = MAX_WAIT  # the longest wait for the next trial, s of calls
        self._trial_cost = 0.0  # seconds of the trial under way, warm-up included
        self._trial_calls: list[float] = []  # seconds of each of its measured calls
        self._probation = 0  # single-call blocks left after a switch
        #: since the twin in use took over: its seconds and calls (trial included) and the
        #: other twin's mean then, to charge a takeover that went wrong (none at the start)
        self._tenure = [0.0, 0.0, 0.0]
        self.calls = [0, 0]
        self.switches = 0
        learnt = _LEARNT.get(self._kernels) if size > 0 else None
        if learnt is None:
            self._start(0, _WARM_UP)  # the first trial measures the serial twin, in use
        else:  # go on where earlier batches of these twins left off
            self._mean = [learnt[0] * size, learnt[1] * size]
            self._loss, self._using = learnt[2] * size, learnt[3]
            self._credit, self._gap, self._wait = learnt[4], learnt[5], learnt[6]
            self._start(self._using, _USING)

    @property
    def parallel(self) -> bool:
        """Whether the next call runs on the threaded twin."""
        return self._running == 1

    def rescale(self, factor: float) -> None:
        """Scale what the timings have learnt by ``factor`` (the batch changed size)."""
        self._size *= factor
        self._mean = [m * factor for m in self._mean]
        self._loss *= factor
        self._tenure[0] *= factor
        self._tenure[2] *= factor

    def __call__(self, *args: Any) -> int:
        """Run the kernel on ``args`` with the twin due now; returns the kernel's result."""
        start = time.perf_counter()
        result = self._kernel(*args)
        self._time += time.perf_counter() - start
        self._left -= 1
        if self._left == 0:
            self._end_block()
        return result

    def _start(self, which: int, phase: int) -> None:
        """Begin a block of calls on twin ``which`` (trial calls go one at a time)."""
        self._running, self._kernel, self._phase = which, self._kernels[which], phase
        self._block = 1
        if phase == _USING:
            if self._probation:
                self._probation -= 1
            else:
                self._block = BLOCK_CALLS
        self._left = self._block
        self._time = 0.0

    def _end_block(self) -> None:
        """Account a finished block; choose the next one."""
        which, calls, elapsed, mean = self._running, self._block, self._time, self._mean
        self.calls[which] += calls
        if self._phase == _WARM_UP:
            self._trial_cost, self._trial_calls = elapsed, []
            self._start(which, _TRIAL)
        elif self._phase == _TRIAL:
            self._trial_cost += elapsed
            self._trial_calls.append(elapsed)
            # The serial twin is the safe one: a trial that could hand the kernel to the
            # threads ends at its first call too slow to win, one that could hand it back
            # once its median cannot win.
            too_slow = (1.0 - MARGIN) * mean[self._using]
            slow_calls = sum(t >= too_slow for t in self._trial_calls)
            allowed = TRIAL_CALLS // 2 if which == 0 else 0
            hopeless = which != self._using and slow_calls > allowed
            if hopeless or len(self._trial_calls) == TRIAL_CALLS:
                self._end_trial(which, statistics.median(self._trial_calls), self._trial_cost)
            else:
                self._start(which, _TRIAL)
        else:
            mean[which] += (elapsed / calls - mean[which]) * SMOOTHING
            self._credit += elapsed
            self._gap += calls
            self._tenure[0] += elapsed
            self._tenure[1] += calls
            self._remember()
            waited = self._credit >= min(self._loss / BUDGET, self._wait)
            if mean[which] > mean[1 - which] or (self._gap >= MIN_GAP and waited):
                self._start(1 - which, _WARM_UP)
            else:
                self._start(which, _USING)

    def _remember(self) -> None:
        """Share what this batch has learnt with later batches of the same twins."""
        if self._size > 0:
            serial, threaded = (m / self._size for m in self._mean)
            loss = self._loss / self._size
            credit, gap, wait = self._credit, self._gap, self._wait
            _LEARNT[self._kernels] = (serial, threaded, loss, self._using, credit, gap, wait)

    def _end_trial(self, which: int, per_call: float, cost: float) -> None:
        """Keep the twin in use or hand over to the one just tried."""
        mean, using = self._mean, self._using
        if which == using:  # the first trial measured the twin in use: now try the other
            mean[which] = per_call
            self._start(1 - which, _WARM_UP)
            return
        calls = 1 + len(self._trial_calls)
        if per_call < mean[using] * (1.0 - MARGIN):  # take over
            # Retrying the twin left costs what its own tenure lost against this one (a
            # lucky trial, then a stall beside a learner), or what its mean predicts.
            held, held_calls, other_then = self._tenure
            regret = held - held_calls * other_then if self.switches else 0.0
            self._loss = max(regret, calls * (mean[using] - per_call), 0.0)
            self._tenure = [cost, float(calls), mean[using]]
            self._using, self._probation = which, PROBATION
            self.switches += 1
            self._wait = MAX_WAIT
        else:
            self._loss = max(0.0, cost - calls * mean[using])
            self._wait = min(2.0 * self._wait, MAX_BACKOFF)
        mean[which] = per_call
        self._credit, self._gap = 0.0, 0
        self._remember()
        self._start(self._using, _USING)


def select_kernel(serial: Kernel, parallel: Kernel, size: int, choice: bool | None) -> Kernel:
    """Return the kernel that steps a batch of ``size``.

    Parameters
    ----------
    serial, parallel : callable
        The twins.
    size : int
        Batch size (plants or envs).
    choice : bool or None
        ``True``: always the threaded twin; ``False``: always the serial one; ``None`` (the
        default of :class:`~frictiongym.plants.Plant` and the envs): serial below
        ``PARALLEL_MIN_PLANTS`` or when numba has one thread, else an :class:`AdaptiveKernel`.
    """
    if choice is not None:
        if not isinstance(choice, bool | np.bool_):
            raise TypeError(f"parallel must be True, False or None (adaptive), got {choice!r}")
        return parallel if bool(choice) else serial
    threads: int = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]
    if size < PARALLEL_MIN_PLANTS or threads < 2:
        return serial
    return AdaptiveKernel(serial, parallel, size)
