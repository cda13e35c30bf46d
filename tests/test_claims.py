"""The threaded kernels' block claims: every block once, own share first, the slow helped."""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt
import pytest
from numba import njit, prange

from frictiongym.plants import _claims as claims


@njit
def _claim_in_order(
    schedule: npt.NDArray[np.int64], workers: int, blocks: int
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Let the workers of ``schedule`` claim in its order; return each claim's block and worker."""
    counters = claims.new_counters(workers)
    got = np.full(schedule.shape[0], -1, dtype=np.int64)
    for k in range(schedule.shape[0]):
        got[k] = claims.claim(counters, schedule[k], workers, blocks)
    return got, schedule


@pytest.mark.parametrize(("workers", "blocks"), [(1, 1), (2, 16), (2, 3), (3, 16), (4, 5), (8, 8)])
@pytest.mark.parametrize("seed", range(5))
def test_every_block_is_claimed_once_and_each_share_in_order(
    workers: int, blocks: int, seed: int
) -> None:
    """Whatever the order of the claims, each block goes to exactly one worker.

    A share's blocks are handed out in order, and a worker takes another's block only once
    its own are all gone.
    """
    rng = np.random.default_rng(seed)
    # more claims than blocks: the last ones of every worker find none left
    schedule = rng.integers(0, workers, size=3 * blocks + 2 * workers).astype(np.int64)
    got, by = _claim_in_order(schedule, workers, blocks)
    claimed = got[got >= 0]
    assert sorted(claimed.tolist()) == list(range(blocks))
    share_of = np.array(
        [next(s for s in range(workers) if b < (s + 1) * blocks // workers) for b in range(blocks)]
    )
    for share in range(workers):
        handed = [b for b in claimed.tolist() if share_of[b] == share]
        assert handed == sorted(handed)
    for worker in range(workers):
        mine = got[(by == worker) & (got >= 0)].tolist()
        own = [b for b in mine if share_of[b] == worker]
        assert mine[: len(own)] == own  # its own blocks come first
    # a claim that finds none (-1) comes only once every block is out, and so do all later ones
    first_none = int(np.flatnonzero(got < 0).min())
    assert first_none == blocks
    assert (got[first_none:] == -1).all()


@njit(parallel=True)
def _work_with_one_slow_worker(
    blocks: int, slow: int, spin: int
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """Run ``blocks`` blocks on numba's threads; worker ``slow`` spins ``spin`` turns per block."""
    workers = claims.workers_for(blocks)
    counters = claims.new_counters(workers)
    owner = np.empty(blocks, dtype=np.int64)
    sink = np.empty(workers, dtype=np.float64)
    for each in prange(workers):
        worker = np.int64(each)
        total = 0.0
        block = claims.claim(counters, worker, workers, blocks)
        while block >= 0:
            owner[block] = worker
            turns = spin if worker == slow else spin // 1000
            for t in range(turns):
                total += np.sqrt(t + 1.0)
            block = claims.claim(counters, worker, workers, blocks)
        sink[worker] = total
    return owner, sink


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two numba threads")
def test_a_fast_worker_takes_the_blocks_a_slow_one_has_not_reached() -> None:
    """The second worker is 1 000 times slower per block: the first runs most of its share."""
    blocks = 16
    _work_with_one_slow_worker(blocks, 1, 10)  # compile
    owner, _ = _work_with_one_slow_worker(blocks, 1, 2_000_000)
    # a fixed split gives each worker 8; the slow one, busy with its first block while the
    # fast one runs through the rest, ends with far fewer
    assert (owner == 1).sum() <= 3
    assert (owner[:8] == 0).all()  # the fast worker's own share stayed its own
