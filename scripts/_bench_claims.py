"""The ``claims`` part of ``bench_envs.py``: the threaded kernel's claims and in-kernel autoreset.

Issue J's eighth round changed two things in how a vector env's threaded step runs (see
``frictiongym/plants/_claims.py`` and docs/benchmarks.md, "Eighth round"):

* **claims**: numba's threads claim the blocks one at a time (each its own share first, then
  what is left of the others'), instead of ``prange``'s fixed split, in which a call lasts as
  long as its slower thread;
* **autoreset in the kernel**: an autoreset that draws nothing runs in the kernel, each env
  reset by the thread that steps its block, instead of on the main thread before the call.

This part times, for each env (``--num-envs`` envs, default kwargs, the AR(1) actions), four
kernels on the same vector env class: the serial kernel (``parallel=False``), the kernel before
the round (a fixed split, compiled here from the kernel's own block step, and the autoreset
before the call), the claims with the autoreset before the call, and the kernel as shipped
(``parallel=True``: claims and the autoreset in the kernel). The machine's second core gives
the threads a share that changes within seconds here, so the kernels run in short turns of
``TURN`` steps each, one after another in an order reversed every round, for ``300 *
--repeats`` rounds: each kernel sees the same spells. Figures are µs per vector step (median
and quartiles over rounds) and the ratio to the kernel before the round (median of the per-round
ratios, quartiles, and the ratio of the total times). Every kernel's first steps are checked
to give the same observations and rewards as the serial kernel's, bit for bit.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numba
import numpy as np
import numpy.typing as npt
from _bench import thousands

from frictiongym.envs import _kernel as env_kernel
from frictiongym.plants import _batch as plant_batch

#: Steps of one kernel's turn, and rounds of turns per ``--repeats``.
TURN, ROUNDS_PER_REPEAT = 40, 300
#: Steps compared with the serial kernel before the timing.
CHECK_STEPS = 64
#: The kernels timed, as (label, threaded, claims, autoreset in the kernel).
KERNELS = (
    ("serial (parallel=False)", False, False, True),
    ("before: fixed split, autoreset before the call", True, False, False),
    ("claims, autoreset before the call", True, True, False),
    ("as shipped: claims, autoreset in the kernel", True, True, True),
)
BEFORE = 1  #: the reference of the ratios


@numba.njit(cache=True, parallel=True)
def _fixed_split(
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    dt: float,
    n_sub: int,
    plant_rows: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    rng: npt.NDArray[np.uint64],
    config: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    reset: bool,
    start: npt.NDArray[np.float64],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> int:
    """The threaded env kernel before the claims: ``prange`` over the blocks (a fixed split)."""
    bad = plant_batch.first_non_finite(command)
    if bad >= 0:
        return bad
    command64 = env_kernel.float64_commands(command)
    ended = 0
    for block in numba.prange((state.shape[1] + env_kernel.BLOCK - 1) // env_kernel.BLOCK):
        ended += env_kernel._step_block(
            np.int64(block),
            state,
            delay_buffer,
            head,
            command,
            command64,
            dt,
            n_sub,
            plant_rows,
            rows,
            rng,
            config,
            fresh,
            reset,
            start,
            obs,
            out,
            flags,
        )
    return -1 - ended


def _reset_before_the_call(sim: Any) -> None:
    """Make ``sim`` autoreset on the main thread before the kernel's call, as before the round."""
    run = sim.run

    def run_after_reset(
        command: npt.NDArray[Any],
        fresh: npt.NDArray[np.bool_],
        obs: npt.NDArray[np.float32],
        out: npt.NDArray[np.float64],
        flags: npt.NDArray[np.bool_],
        autoreset: Callable[[int], np.random.Generator] | None = None,
    ) -> int:
        if autoreset is not None and sim._rows_default:
            sim.check_commands(command)  # the commands' check first, as the autoreset did
            env_kernel.reset_envs(fresh, *sim._reset_args(), False)
            autoreset = None
        return int(run(command, fresh, obs, out, flags, autoreset))

    sim.run = run_after_reset


def _make(env_id: str, n: int, seed: int, threaded: bool, claims: bool, in_kernel: bool) -> Any:
    env = gym.make_vec(
        env_id, num_envs=n, vectorization_mode="vector_entry_point", parallel=threaded
    )
    sim = env.unwrapped.sim
    if threaded and not claims:
        sim.plants._step_kernel = _fixed_split
    if not in_kernel:
        _reset_before_the_call(sim)
    env.reset(seed=seed)
    return env


def _check(envs: Sequence[Any], table: list[npt.NDArray[Any]]) -> None:
    """Stop unless every kernel's first steps give the serial kernel's outputs, bit for bit."""
    for t in range(CHECK_STEPS):
        first, *others = (env.step(table[t % len(table)]) for env in envs)
        for k, other in enumerate(others, start=1):
            for a, b in zip(first[:4], other[:4], strict=True):
                if not np.array_equal(a, b):
                    raise SystemExit(f"error: kernel {KERNELS[k][0]!r} differs at step {t}")


def _turns(envs: Sequence[Any], table: list[npt.NDArray[Any]], rounds: int) -> npt.NDArray[Any]:
    """Run the kernels in turns; returns µs per step, shape (kernels, rounds)."""
    times = np.empty((len(envs), rounds))
    place = [CHECK_STEPS] * len(envs)
    for r in range(rounds):
        order = range(len(envs)) if r % 2 == 0 else range(len(envs) - 1, -1, -1)
        for k in order:
            env, at = envs[k], place[k]
            start = time.perf_counter()
            for t in range(at, at + TURN):
                env.step(table[t % len(table)])
            times[k, r] = (time.perf_counter() - start) / TURN * 1e6
            place[k] = at + TURN
    return times


def claims_part(
    args: argparse.Namespace,
    env_ids: Sequence[str],
    actions: Callable[[str, int, int], list[npt.NDArray[Any]]],
) -> str:
    """Time the four kernels of each env in turns; print the table, return it as markdown."""
    n, rounds = args.num_envs, ROUNDS_PER_REPEAT * args.repeats
    title = (
        f"Threaded kernels of the vector envs, claims and autoreset (N = {thousands(n)}, "
        f"{numba.config.NUMBA_NUM_THREADS} threads; µs per vector step over {thousands(rounds)} "
        f"rounds of {TURN}-step turns, median [quartiles]; ratio = kernel / the kernel before)"
    )
    lines = [
        "| env | kernel | µs per step | ratio, median of rounds [quartiles] | ratio of totals |",
        "|---|---|---|---|---|",
    ]
    print(f"\n{title}")
    for env_id in env_ids:
        table = actions(env_id, n, args.seed)
        envs = [_make(env_id, n, args.seed, *kernel[1:]) for kernel in KERNELS]
        _check(envs, table)
        times = _turns(envs, table, rounds)
        for k, (label, *_) in enumerate(KERNELS):
            q1, mid, q3 = np.percentile(times[k], [25, 50, 75])
            ratio = times[k] / times[BEFORE]
            r1, rmid, r3 = np.percentile(ratio, [25, 50, 75])
            total = times[k].sum() / times[BEFORE].sum()
            cells = (
                env_id.removeprefix("frictiongym/"),
                label,
                f"{mid:.1f} [{q1:.1f}, {q3:.1f}]",
                f"{rmid:.3f} [{r1:.3f}, {r3:.3f}]",
                f"{total:.3f}",
            )
            lines.append("| " + " | ".join(cells) + " |")
            print(f"  {cells[0]:18s} {label:48s} {cells[2]:20s} x {cells[3]:24s} totals {cells[4]}")
        for env in envs:
            env.close()
    return f"{title}:\n\n" + "\n".join(lines)
