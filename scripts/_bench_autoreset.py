"""The ``autoreset`` part of ``bench_envs.py``: a vector env's autoreset in the kernel or before it.

Issue J's eighth round moved the vector env's ``NEXT_STEP`` autoreset of envs that draw
nothing into the kernel's call: each such env is reset in its block, by the thread that steps
it, instead of on the main thread before the call (``Simulation.run``, docs/benchmarks.md,
"Eighth round"). The Altino's steps reset an env or two nearly every step (its episodes end at
the wall); the servo's envs end together, one step in 2 500.

This part times, for each env (``--num-envs`` envs, default kwargs, the AR(1) actions), the
same vector env class four ways: the serial kernel (``parallel=False``, for the threads' gain),
the threaded kernel with the autoreset before the call as before the round (a wrapper of
``Simulation.run`` that does it with the same compiled ``reset_envs``), a second env of that
kind (a control: the method's own bias between two identical envs), and the threaded kernel as
shipped. The machine's second core gives the threads a share that changes within seconds here,
so the envs run in short turns of ``TURN`` steps each, one after another in a new random order
every round, for ``300 * --repeats`` rounds: each sees the same spells, and none always
follows the same other. Figures are µs per vector step (median and quartiles over rounds) and
the ratio to the autoreset before the call (median of the per-round ratios, quartiles, and the
ratio of the total times). Every env's first steps are checked to give the serial kernel's
observations and rewards, bit for bit.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from typing import Any

import numba
import numpy as np
import numpy.typing as npt
from _bench import cycled_runner, quartile_stats, thousands, turns

from frictiongym.envs import _kernel as env_kernel

#: Steps of one env's turn, and rounds of turns per ``--repeats``.
TURN, ROUNDS_PER_REPEAT = 40, 300
#: Steps compared with the serial kernel before the timing.
CHECK_STEPS = 64
#: The envs timed, as (label, threaded, autoreset in the kernel).
VARIANTS = (
    ("serial kernel (parallel=False)", False, True),
    ("threads, autoreset before the call", True, False),
    ("the same, a second env (control)", True, False),
    ("threads, autoreset in the kernel", True, True),
)
BEFORE = 1  #: the reference of the ratios


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


#: Makes a vector env and resets it: ``(env id, num envs, kwargs, seed)``.
MakeVector = Callable[[str, int, dict[str, Any], int], Any]


def _make(make: MakeVector, env_id: str, n: int, seed: int, threaded: bool, in_kernel: bool) -> Any:
    env = make(env_id, n, {"parallel": threaded}, seed)
    if not in_kernel:
        _reset_before_the_call(env.unwrapped.sim)
    return env


def _check(envs: Sequence[Any], table: list[npt.NDArray[Any]]) -> None:
    """Stop unless every env's first steps give the serial kernel's outputs, bit for bit."""
    for t in range(CHECK_STEPS):
        first, *others = (env.step(table[t % len(table)]) for env in envs)
        for k, other in enumerate(others, start=1):
            for a, b in zip(first[:4], other[:4], strict=True):
                if not np.array_equal(a, b):
                    raise SystemExit(f"error: {VARIANTS[k][0]!r} differs at step {t}")


def autoreset_part(
    args: argparse.Namespace,
    env_ids: Sequence[str],
    actions: Callable[[str, int, int], list[npt.NDArray[Any]]],
    make: MakeVector,
) -> str:
    """Time the four envs of each env id in turns; print the table, return it as markdown."""
    n, rounds = args.num_envs, ROUNDS_PER_REPEAT * args.repeats
    title = (
        f"Vector envs' autoreset in the kernel or before it (N = {thousands(n)}, "
        f"{numba.config.NUMBA_NUM_THREADS} threads; µs per vector step over {thousands(rounds)} "
        f"rounds of {TURN}-step turns, median [quartiles]; ratio = env / autoreset before)"
    )
    lines = [
        "| env | step | µs per step | ratio, median of rounds [quartiles] | ratio of totals |",
        "|---|---|---|---|---|",
    ]
    print(f"\n{title}")
    for env_id in env_ids:
        table = actions(env_id, n, args.seed)
        envs = [_make(make, env_id, n, args.seed, *variant[1:]) for variant in VARIANTS]
        _check(envs, table)
        runners = [cycled_runner(env, table) for env in envs]
        times = turns(runners, [TURN] * len(runners), rounds) * 1e6  # µs per step
        for k, (label, *_) in enumerate(VARIANTS):
            total = times[k].sum() / times[BEFORE].sum()
            cells = (
                env_id.removeprefix("frictiongym/"),
                label,
                quartile_stats(times[k], lambda v: f"{v:.1f}"),
                quartile_stats(times[k] / times[BEFORE], lambda v: f"{v:.3f}"),
                f"{total:.3f}",
            )
            lines.append("| " + " | ".join(cells) + " |")
            print(f"  {cells[0]:18s} {label:36s} {cells[2]:20s} x {cells[3]:24s} totals {cells[4]}")
        for env in envs:
            env.close()
    return f"{title}:\n\n" + "\n".join(lines)
