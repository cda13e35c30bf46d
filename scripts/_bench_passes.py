"""The ``passes`` part of ``bench_envs.py``: where a vector env's plant step goes, pass by pass.

A plant step of a batch runs in blocks of 256 plants, up to three passes each (see
``frictiongym/plants/_batch.py`` and docs/physics.md, "How a batch is stepped"): pass 1 (SIMD
code over every plant), the list of the plants it left pending, pass 1b (SIMD code over the
pending plants, the ``log1p`` and ``expm1`` calls in scalar loops) and pass 2 (the element
step for what is still pending). This part times them cumulatively on one thread: for each env
it runs the vector env (``--num-envs`` envs, default kwargs, the AR(1) actions) for 400 steps,
keeps a snapshot of the plants' state every fourth of the next 200 steps with the command of
the step after, and steps each snapshot with pass 1 only, then pass 1 and the list, then also
pass 1b, then all passes. Each snapshot is copied into the stepped arrays before its timed
call, so the figures are those of a state in cache, and the timed calls are the same work for
every variant. The time of the call alone (numba's dispatch) is timed too and taken off each
variant, per round. Each increment is what that pass adds, in ns per
plant-step; the shares are of the plants each step leaves pending after pass 1 and after pass
1b. Every block must hold at least ``LANES_MIN`` (16) plants, as the kernel gives smaller ones
the element step only: ``--num-envs`` below 16, or one that leaves a last block of fewer, is
refused.

The passes are the kernel's own compiled functions, called here in its order: this part runs
on any source that has them (issue J's second round, with pass 1b, and later), another
checkout's through ``PYTHONPATH=<checkout>``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from itertools import cycle, islice, pairwise
from typing import Any

import gymnasium as gym
import numba
import numpy as np
import numpy.typing as npt
from _bench import ns_stats, thousands

from frictiongym.plants import _batch as plant_batch
from frictiongym.plants._kernel import S_FRICTION, S_STUCK

#: The passes, in order: variant ``k`` runs the first ``k + 1`` of them.
VARIANTS = ("pass 1", "pending list", "pass 1b", "pass 2")
#: Steps run before the first snapshot, and the steps over which snapshots are kept.
WARM_STEPS, SNAPSHOT_STEPS, SNAPSHOT_EVERY = 400, 200, 4


@numba.njit(cache=True)
def _passes(
    upto: int,
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    h: float,
    params: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    work: npt.NDArray[np.float64],
    index: npt.NDArray[np.int64],
) -> tuple[int, int]:
    """Step every block with passes 1 to ``upto`` (0 to 3) as ``_step_lanes`` orders them.

    Returns the plants left pending after pass 1 and after pass 1b (0 where not run). With
    ``upto`` -1 it returns at once: the cost of the call alone.
    """
    after_one, after_one_b = 0, 0
    if upto < 0:
        return after_one, after_one_b
    block = plant_batch.BLOCK
    for lo in range(0, state.shape[1], block):
        hi = min(lo + block, state.shape[1])
        plant_batch.slide_lanes(state, delay_buffer, head, command, h, params, fresh, lo, hi)
        if upto < 1:
            continue
        pending = 0
        for i in range(lo, hi):
            index[pending] = i
            pending += state[S_STUCK, i] == plant_batch.PENDING
        after_one += pending
        if upto < 2:
            continue
        plant_batch.two_phase_lanes(state, h, params, index, pending, work)
        for m in range(pending):
            i = index[m]
            if state[S_STUCK, i] == plant_batch.PENDING:
                after_one_b += 1
                if upto >= 3:
                    plant_batch.advance_plant(i, state, state[S_FRICTION, i], h, 1, params, True)
    return after_one, after_one_b


Snapshot = tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], int, npt.NDArray[np.float64]]


def _snapshots(
    env_id: str, n: int, table: list[npt.NDArray[Any]], seed: int
) -> tuple[Any, list[Snapshot]]:
    """Run the vector env and return its plants and the snapshots (see the module docstring)."""
    env = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", parallel=False)
    env.reset(seed=seed)
    plants = env.unwrapped.sim.plants
    actions = cycle(table)
    snapshots: list[Snapshot] = []
    for t, action in enumerate(islice(actions, WARM_STEPS + SNAPSHOT_STEPS)):
        env.step(action)
        if t >= WARM_STEPS and (t - WARM_STEPS) % SNAPSHOT_EVERY == 0:
            following = table[(t + 1) % len(table)].astype(np.float64).reshape(n)
            state = (plants.state.copy(), plants.delay_buffer.copy(), plants.head, following)
            snapshots.append(state)
    return plants, snapshots


def _timed(plants: Any, snapshots: list[Snapshot], upto: int) -> tuple[float, int, int]:
    """Seconds of ``_passes(upto)`` over the snapshots, and the pending counts it returned."""
    state, buffer = np.empty_like(plants.state), np.empty_like(plants.delay_buffer)
    fresh = np.zeros(state.shape[1], dtype=bool)
    work = np.empty(plant_batch.WORK_ROWS * plant_batch.BLOCK)
    index = np.empty(plant_batch.BLOCK, dtype=np.int64)
    seconds, after_one, after_one_b = 0.0, 0, 0
    for snapshot_state, snapshot_buffer, head, command in snapshots:
        np.copyto(state, snapshot_state)
        np.copyto(buffer, snapshot_buffer)
        start = time.perf_counter()
        counts = _passes(
            upto, state, buffer, head, command, plants.dt, plants.rows, fresh, work, index
        )
        seconds += time.perf_counter() - start
        after_one, after_one_b = after_one + counts[0], after_one_b + counts[1]
    return seconds, after_one, after_one_b


def passes_part(
    args: argparse.Namespace,
    envs: list[str],
    actions: Callable[[str, int, int], list[npt.NDArray[Any]]],
) -> str:
    """Time the passes of each env's plant step; print and return the markdown."""
    n = args.num_envs
    smallest = min(n % plant_batch.BLOCK or plant_batch.BLOCK, n)
    if smallest < plant_batch.LANES_MIN:
        raise SystemExit(
            f"bench_envs.py: error: --part passes needs every block of {plant_batch.BLOCK} "
            f"plants to hold at least {plant_batch.LANES_MIN} (smaller ones take the element "
            f"step only); --num-envs {n} leaves one of {smallest}"
        )
    print(
        f"\npasses: ns per plant-step at N = {n}, one thread, state in cache, median of "
        f"{args.repeats} rounds (each pass: what it adds)"
    )
    lines = [
        f"Where a plant step of the vector env goes (N = {thousands(n)}, one thread, the state "
        "in cache; ns per plant-step, median [min, max] of "
        f"{args.repeats} rounds; each pass: what it adds to the ones before):",
        "",
        "| env | " + " | ".join(VARIANTS) + " | all | pending after pass 1 | after pass 1b |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for env_id in envs:
        plants, snapshots = _snapshots(env_id, n, actions(env_id, n, args.seed), args.seed)
        for upto in range(-1, len(VARIANTS)):  # compile, or load numba's cache, untimed
            _timed(plants, snapshots[:1], upto)
        ns: list[list[float]] = [[] for _ in VARIANTS]
        counts = (0, 0)
        for round_ in range(args.repeats):
            order = list(range(-1, len(VARIANTS)))  # -1: the call alone, taken off the others
            timed = {}
            for upto in order[round_ % len(order) :] + order[: round_ % len(order)]:
                seconds, after_one, after_one_b = _timed(plants, snapshots, upto)
                timed[upto] = seconds
                if upto == len(VARIANTS) - 1:
                    counts = (after_one, after_one_b)
            for upto in range(len(VARIANTS)):
                ns[upto].append((timed[upto] - timed[-1]) / len(snapshots) / n * 1e9)
        added = [ns[0]] + [
            [b - a for a, b in zip(before, after, strict=True)] for before, after in pairwise(ns)
        ]
        shares = [f"{100 * c / len(snapshots) / n:.2f} %" for c in counts]
        cells = [ns_stats(values, 2) for values in added] + [ns_stats(ns[-1], 2), *shares]
        name = env_id.removeprefix("frictiongym/")
        heads = (*VARIANTS, "all", "pending", "after 1b")
        print(f"  {name:18s} " + "  ".join(f"{k} {v}" for k, v in zip(heads, cells, strict=True)))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
