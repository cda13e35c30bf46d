"""Which block of a batch each of numba's threads steps next: its own share, then the others'.

numba's ``prange`` hands each thread a fixed share of the iterations (its OpenMP layer
schedules statically). Each thread then steps the same envs at every call, whose data stay in
its core's cache, but a call lasts as long as its slowest share: on a virtual machine one of
two cores is at times served less by the host (a step's second half then took 67 µs against
the first half's 46 µs, docs/benchmarks.md "Fifth round"). Here each thread first steps its own
share in order and then takes blocks from the end of the shares not yet finished, so a slow
core's work passes to the fast one while on an even machine every thread keeps its share.

A block is claimed by an atomic exchange on its entry of ``claims`` (one cache line each), so
each block is stepped once, by whichever thread claims it. Blocks are independent (each env's
step reads and writes its own columns only), so the results do not depend on which thread
stepped which block.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

#: int64 entries between two claims: one cache line each, so that claiming a block does not
#: contend with the other thread's claims
CLAIM_STRIDE = 8


def _typed_exchange(typingctx: Any, claims: Any, index: Any) -> Any:
    """Set ``claims[index]`` to 1 atomically; return what it held (0: the caller claimed it)."""
    signature = types.int64(claims, types.intp)

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        array_type = sig.args[0]
        array = context.make_array(array_type)(context, builder, args[0])
        pointer = cgutils.get_item_pointer(context, builder, array_type, array, [args[1]])
        one = context.get_constant(types.int64, 1)
        return builder.atomic_rmw("xchg", pointer, one, "acq_rel")

    return signature, codegen


#: ``_exchange(claims, index)`` in compiled code (typed Any: numba's stubs want ``typingctx``)
_exchange: Any = intrinsic(_typed_exchange)


def _typed_thread_count(typingctx: Any) -> Any:
    """Return numba's current number of threads (``numba.get_num_threads()``) in compiled code.

    ``numba.get_num_threads`` itself calls the threading layer through a ctypes pointer, which
    keeps a kernel out of numba's cache; this calls the same C function by its symbol, as
    numba's parallel loops do (a cached parallel kernel launches the layer when loaded).
    """
    from numba.np.ufunc.parallel import _launch_threads

    _launch_threads()  # the layer defines the symbol

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        function_type = ir.FunctionType(cgutils.intp_t, [])
        function = cgutils.get_or_insert_function(builder.module, function_type, "get_num_threads")
        return builder.call(function, [])

    return types.intp(), codegen


thread_count: Any = intrinsic(_typed_thread_count)


@njit(cache=True)
def new_claims(blocks: int) -> npt.NDArray[np.int64]:
    """Return the claims of ``blocks`` blocks, none claimed.

    A plain loop fills them: ``np.zeros`` is a parallel loop of its own in a kernel compiled
    with ``parallel=True``.
    """
    claims = np.empty(blocks * CLAIM_STRIDE, dtype=np.int64)
    for i in range(claims.shape[0]):
        claims[i] = 0
    return claims


@njit(cache=True, inline="always")
def share(worker: int, workers: int, blocks: int) -> tuple[int, int]:
    """Return the first block of ``worker``'s share and the end of it (``prange``'s split)."""
    return worker * blocks // workers, (worker + 1) * blocks // workers


@njit(cache=True, inline="always")
def next_block(
    claims: npt.NDArray[np.int64], walk: tuple[int, int, int], worker: int, workers: int
) -> tuple[int, tuple[int, int, int]]:
    """Return the next block ``worker`` steps (-1 when every block is claimed) and its walk.

    ``walk`` is where the worker is: ``(phase, next block, shares robbed)``, first ``(0, first
    block of its share, 0)``. Phase 0 walks its own share upwards, phase 1 the other shares
    downwards from their ends. A walk stops at the first block claimed already: the owner and
    the one thief that took a share's last block meet there, so no block is left between.
    """
    blocks = claims.shape[0] // CLAIM_STRIDE
    phase, block, robbed = walk
    if phase == 0:
        if (
            block < share(worker, workers, blocks)[1]
            and _exchange(claims, block * CLAIM_STRIDE) == 0
        ):
            return block, (0, block + 1, 0)
        phase, robbed = 1, 1
        block = share((worker + 1) % workers, workers, blocks)[1] - 1
    while robbed < workers:
        victim = (worker + robbed) % workers
        if block >= share(victim, workers, blocks)[0] and (
            _exchange(claims, block * CLAIM_STRIDE) == 0
        ):
            return block, (1, block - 1, robbed)
        robbed += 1
        block = share((worker + robbed) % workers, workers, blocks)[1] - 1
    return -1, (1, block, robbed)
