"""The blocks of a threaded batch kernel, claimed by its threads one at a time as they go.

``prange`` gives each thread an equal share of the blocks before the loop starts, so a call
lasts as long as its slowest thread: on a virtual machine whose second core runs slower for a
while (the host's other guests), the first thread waited idle for up to half the call
(docs/benchmarks.md, "Eighth round"). Here the threaded kernels run one ``prange`` iteration per
thread (a *worker*), and each worker claims blocks from a shared counter per share:

* its own share first, in order: the same blocks as a fixed split, every call, so their state
  stays in that core's cache while the threads keep pace;
* then any block left in another worker's share, so a fast worker finishes a slow one's work.

A claim is one atomic increment, so every block runs exactly once, on whichever thread claims
it; blocks are independent, so results are bit-identical to the serial kernel's.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

# The thread count as numba's own parallel loops read it: ``numba.get_num_threads()`` calls the
# threading layer through a pointer found at run time, which keeps a kernel out of the cache.
from numba.np.ufunc.parallel import _iget_num_threads as _num_threads

#: int64 entries per counter: one cache line each, so that two workers claiming from their own
#: shares do not contend for a line.
STRIDE = 8


@intrinsic
def _fetch_add(typingctx: Any, counters: Any, index: Any) -> Any:
    """``counters[index] += 1`` as one atomic operation; returns the value before it."""
    signature = types.int64(counters, index)

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        array_type = sig.args[0]
        array = context.make_array(array_type)(context, builder, args[0])
        pointer = cgutils.get_item_pointer(
            context, builder, array_type, array, [args[1]], wraparound=False
        )
        # "monotonic": the claim needs only atomicity; the join at the end of the parallel
        # region orders every block's writes before the caller reads them
        return builder.atomic_rmw("add", pointer, ir.Constant(ir.IntType(64), 1), "monotonic")

    return signature, codegen


@njit(cache=True, inline="always")
def workers_for(blocks: int) -> int:
    """Return the workers of a call over ``blocks`` blocks: one per thread, at most one each."""
    return max(min(_num_threads(), blocks), 1)  # type: ignore[call-arg]  # an intrinsic


@njit(cache=True, inline="always")
def new_counters(workers: int) -> npt.NDArray[np.int64]:
    """Return the claim counters of one call: every share unclaimed.

    Filled by a loop, not ``np.zeros``: in a kernel compiled with ``parallel=True`` that is a
    parallel loop of its own, a second fork and join of the threads per call.
    """
    counters = np.empty(workers * STRIDE, dtype=np.int64)
    for i in range(counters.shape[0]):
        counters[i] = 0
    return counters


@njit(cache=True, inline="always")
def claim(counters: npt.NDArray[np.int64], worker: int, workers: int, blocks: int) -> int:
    """Return the next block for ``worker`` (its own share first), or -1 once none is left.

    Share ``s`` is blocks ``s * blocks // workers`` up to ``(s + 1) * blocks // workers``; its
    counter counts the claims made on it, so it runs past the share's end once the share is
    spent (every claim after that fails, and no block is claimed twice).
    """
    for offset in range(workers):
        share = worker + offset
        share = share - workers if share >= workers else share
        first = share * blocks // workers
        block = first + _fetch_add(counters, share * STRIDE)  # type: ignore[call-arg]
        if block < (share + 1) * blocks // workers:
            return block
    return -1
