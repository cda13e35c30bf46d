"""The threads' block schedule: every block stepped once, each thread its own share first."""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt
import pytest

from frictiongym.plants import _steal as steal


@numba.njit
def _run_schedule(
    order: npt.NDArray[np.int64], workers: int, blocks: int
) -> tuple[npt.NDArray[np.int64], int]:
    """Play the workers' calls of ``next_block`` in ``order``, then round robin until all end.

    Returns who stepped each block (-1: nobody) and how many blocks were claimed twice.
    """
    claims = steal.new_claims(blocks)
    walks = np.zeros((workers, 3), dtype=np.int64)
    for w in range(workers):
        walks[w, 1] = steal.share(w, workers, blocks)[0]
    done = np.zeros(workers, dtype=np.bool_)
    owner = np.full(blocks, -1, dtype=np.int64)
    twice = 0
    k = 0
    while not done.all():
        w = order[k] if k < order.shape[0] else k % workers
        k += 1
        if done[w]:
            continue
        block, walk = steal.next_block(claims, (walks[w, 0], walks[w, 1], walks[w, 2]), w, workers)
        walks[w, 0], walks[w, 1], walks[w, 2] = walk
        if block < 0:
            done[w] = True
        elif owner[block] >= 0:
            twice += 1
        else:
            owner[block] = w
    return owner, twice


def _share_of(block: int, workers: int, blocks: int) -> int:
    return next(w for w in range(workers) if block < steal.share(w, workers, blocks)[1])


@pytest.mark.parametrize("workers", [1, 2, 3, 4, 7])
@pytest.mark.parametrize("blocks", [1, 2, 5, 16, 17, 64])
def test_every_block_is_stepped_once_in_any_interleaving(workers: int, blocks: int) -> None:
    rng = np.random.default_rng(workers * 100 + blocks)
    for trial in range(200):
        # each worker at its own speed: a slow core gets few turns, some get none for a while
        speeds = rng.exponential(size=workers) ** (1 + trial % 3)
        order = rng.choice(workers, size=rng.integers(0, 4 * blocks + 1), p=speeds / speeds.sum())
        owner, twice = _run_schedule(order.astype(np.int64), workers, blocks)
        assert twice == 0
        assert (owner >= 0).all(), f"blocks left unstepped: {np.flatnonzero(owner < 0)}"


@pytest.mark.parametrize(("workers", "blocks"), [(2, 16), (3, 15), (4, 16)])
def test_threads_at_one_speed_keep_their_own_share(workers: int, blocks: int) -> None:
    # equal shares (with unequal ones a thread that ends first rightly takes a block)
    owner, _ = _run_schedule(np.zeros(0, dtype=np.int64), workers, blocks)  # round robin
    assert [int(w) for w in owner] == [_share_of(b, workers, blocks) for b in range(blocks)]


def test_a_stalled_thread_leaves_its_share_to_the_others() -> None:
    workers, blocks = 2, 16
    # worker 1 is descheduled until worker 0 has found nothing left
    order = np.zeros(blocks + 1, dtype=np.int64)
    owner, twice = _run_schedule(order, workers, blocks)
    assert twice == 0
    assert (owner == 0).all()
    # worker 1 got one turn at the start: it stepped its first block, worker 0 the rest
    order = np.concatenate([[1], np.zeros(blocks, dtype=np.int64)])
    owner, _ = _run_schedule(order, workers, blocks)
    assert owner[8] == 1
    assert (np.delete(owner, 8) == 0).all()


def test_the_kernels_count_numbas_threads() -> None:
    @numba.njit
    def count() -> int:
        return steal.thread_count()

    assert count() == numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        assert count() == 1
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
