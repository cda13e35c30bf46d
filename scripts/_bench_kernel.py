"""Two parts of ``bench_envs.py`` for the kernel near the machine's limit (issue J).

**loads** (``--part loads``): gymnasium's ``CartPoleVectorEnv`` and frictiongym's vector envs
(default kwargs and kernel) at ``--num-envs`` envs, timed interleaved while each competing load
of ``_load.py`` runs (``--loads``: quiet, busy, learner); the ratio ours / CartPole is taken per
round, so both sides meet the same load. Targets (reported, never enforced): at least 3x
CartPoleVectorEnv quiet, at least 1.5x beside the learner (a torch process on 2 threads).

Beside each load it also times two balanced compiled loops over ``--num-envs`` elements (each
block of 256 the same arithmetic) on numba's threads and on one thread: their ratio, two for a
perfect split, is what the machine gives the threads at that time, against which the vector
envs' own gain from threads can be read. One loop is scalar code (a chain of dependent steps
per element), the other SIMD code (independent multiplies, adds and divides in 8 lanes, as
most of the envs' kernel): on this project's virtual machine the second core has given SIMD
code less than scalar code, and by an amount that changes from hour to hour.

**split** (``--part split``): where the time of one vector env-step goes, ns per env-step at
``--num-envs`` envs, each piece timed on its own on one thread (numba's serial kernels):

* ``plant``: a :class:`~frictiongym.plants.Plant` of the env's plant and friction stepped with
  the env's commands (the bare plant kernel);
* ``env kernel``: the env's whole compiled step (plant, sensor, reference, reward, outputs),
  called the way the env calls it (``sim.plants.run``);
* ``observation``: the env kernel minus the plant (sensor, reference, reward and outputs run
  as one pass, so they are not timed apart);
* ``bookkeeping``: the vector env's ``step`` minus the env kernel (Python: checks, output
  arrays, ``info``, the autoreset, which from 5900f26 on runs inside the kernel's call when it
  draws nothing). The env kernel is timed without resets (an env that ended stays where it
  ended), so the Altino, whose episodes end at the wall, can show a bookkeeping below zero;
* ``memory floor``: a compiled loop that only reads and writes, once, every array element
  one step reads or writes (state, commands, outputs, observation, flags): the cost of
  moving the data, with no arithmetic.

The split uses only what both the current kernel and the one before issue J expose (the
public ``Plant``, ``sim.plants.run``), so it also runs against an older checkout
(``PYTHONPATH=<old checkout> python scripts/bench_envs.py --part split``).
"""

from __future__ import annotations

import argparse
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from itertools import chain, cycle, islice
from typing import Any

import _load
import gymnasium as gym
import numba
import numpy as np
import numpy.typing as npt
from _bench import (
    TURN_SECONDS,
    Runner,
    measure,
    measure_in_turns,
    ns_stats,
    paired_ratios,
    quartile_stats,
    si,
    single_threaded,
    thousands,
    turn_rounds,
)

from frictiongym.envs import _kernel as env_kernel
from frictiongym.plants import Plant
from frictiongym.plants.threads import AdaptiveKernel

#: Targets of issue J (vector env at N = 4 096 against CartPoleVectorEnv, env-steps/s).
QUIET_TARGET = 3.0
LEARNER_TARGET = 1.5


@dataclass
class Timed:
    """A runner and what it measured (as :func:`_bench.measure` fills it)."""

    name: str
    run: Runner
    batch: int
    rates: list[float] = field(default_factory=list)


def loads_part(
    args: argparse.Namespace,
    envs: Sequence[str],
    make_runner: Callable[[str, int], tuple[Runner, AdaptiveKernel | None]],
) -> str:
    """Time CartPoleVectorEnv and ``envs`` under each load; print and return the markdown.

    ``make_runner(env_id, n)`` returns a runner of the vector env and its adaptive kernel, if
    it has one (the share of its calls that ran threaded is reported).
    """
    n = args.num_envs
    loads = [load for load in args.loads if load != "torch"]  # in-process torch: see threads
    seconds = args.repeats * args.seconds  # of turns, per variant and load
    rounds = turn_rounds(seconds)
    print(
        f"\nloads: vector envs at N = {n} against CartPoleVectorEnv under each load "
        f"(env-steps/s; {rounds} rounds of turns of about {TURN_SECONDS * 1e3:g} ms, "
        "median [quartiles]; ratio per round)"
    )
    lines = [
        f"Vector envs beside other work (N = {thousands(n)}; {rounds} rounds, each a turn of "
        f"about {TURN_SECONDS * 1e3:g} ms of every variant in a new random order; median "
        "[quartiles] over rounds; ratio = ours / CartPoleVectorEnv in env-steps/s, per round, "
        "both under the same load; threads' gain = a balanced compiled loop's rate on numba's "
        "threads / on one thread, per round, 2 for a perfect split, for a loop of scalar code "
        "and one of SIMD code):",
        "",
        "| load | CartPoleVectorEnv, env-steps/s | "
        + " | ".join(f"`{e}`, env-steps/s | ratio" for e in envs)
        + " | threads' gain, scalar | threads' gain, SIMD |",
        "|---|---|" + "---|---|" * len(envs) + "---|---|",
    ]
    verdicts = []
    for load in loads:
        ids = ("CartPole-v1", *envs)
        made = [make_runner(e, n) for e in ids]
        variants = [Timed(e, run, n) for e, (run, _) in zip(ids, made, strict=True)]
        probes = [
            [Timed(name, run, n) for name, run in _balanced_runners(n, kind)] for kind in BALANCED
        ]
        with _load.competing(load):
            measure_in_turns([*variants, *chain(*probes)], seconds, burn_in=512)
        ref = variants[0]
        cells = [quartile_stats(ref.rates, si)]
        for v, (_, adaptive) in zip(variants[1:], made[1:], strict=True):
            ratios = paired_ratios(v, ref)
            cells += [quartile_stats(v.rates, si), quartile_stats(ratios)]
            target = LEARNER_TARGET if load == "learner" else QUIET_TARGET
            if load in ("quiet", "learner"):
                met = statistics.median(ratios) >= target
                totals = _mean_time(ref.rates) / _mean_time(v.rates)
                verdicts.append(
                    f"{v.name.removeprefix('frictiongym/')} {load}: {quartile_stats(ratios)}, "
                    f"ratio of totals {totals:.3g}{_threaded(adaptive)} (target {target:g}x: "
                    f"{'meets' if met else 'misses'})"
                )
        gains = [quartile_stats(paired_ratios(threads, one)) for threads, one in probes]
        cells += gains
        print(
            f"  {load:8s} "
            + "  ".join(cells[: -len(gains)])
            + "  threads' gain "
            + ", ".join(f"{kind} {gain}" for kind, gain in zip(BALANCED, gains, strict=True))
        )
        lines.append(f"| {load} | " + " | ".join(cells) + " |")
    summary = "targets of issue J (median of the per-round ratios): " + "; ".join(verdicts)
    print(f"  {summary}")
    return "\n".join([*lines, "", summary])


def _threaded(adaptive: AdaptiveKernel | None) -> str:
    """``, 96% of calls threaded`` for an adaptive kernel, else nothing."""
    if adaptive is None:
        return ""
    serial, threaded = adaptive.calls
    return f", {threaded / max(serial + threaded, 1):.0%} of calls threaded"


def _mean_time(rates: Sequence[float]) -> float:
    """Mean time per env-step over rounds of equal steps: what the ratio of totals compares."""
    return float(np.mean(1.0 / np.asarray(rates)))


@numba.njit(cache=True)
def _chain_block(values: npt.NDArray[np.float64], lo: int, hi: int) -> None:
    """Elements ``lo`` to ``hi - 1`` one at a time, each a chain of 20 dependent steps (scalar)."""
    for i in range(lo, hi):
        x = values[0, i]
        for k in range(20):
            x = x * 0.999 + values[k % values.shape[0], i] * 1e-3
        values[1, i] = x


@numba.njit(cache=True, error_model="numpy")
def _lanes_block(values: npt.NDArray[np.float64], lo: int, hi: int) -> None:
    """Elements ``lo`` to ``hi - 1`` in SIMD lanes: 100 passes of a multiply, an add, a divide."""
    for _ in range(100):
        for i in range(np.uint64(lo), np.uint64(hi)):  # unsigned: SIMD code (as the kernels)
            values[1, i] = (values[1, i] * values[0, i] + 0.5) / (1.0 + values[0, i])


@numba.njit(cache=True)
def _one_thread(block: Callable[..., None], values: npt.NDArray[np.float64]) -> None:
    """``block`` over every block of 256 elements, on this thread."""
    for b in range(values.shape[1] // 256):
        block(values, b * 256, b * 256 + 256)


@numba.njit(cache=True, parallel=True)
def _threads(block: Callable[..., None], values: npt.NDArray[np.float64]) -> None:
    """:func:`_one_thread` with the blocks spread over numba's threads (as the envs')."""
    for b in numba.prange(values.shape[1] // 256):
        block(values, np.int64(b) * 256, np.int64(b) * 256 + 256)


#: The balanced loops of the threads' gain: the kind of code, and what one block does.
BALANCED = {"scalar": _chain_block, "SIMD": _lanes_block}


def _balanced_runners(n: int, kind: str) -> list[tuple[str, Runner]]:
    """The threaded and the one-thread balanced loop ``kind`` over ``n`` elements, as runners."""
    values = np.random.default_rng(0).random((20, max(n, 256)))
    block = BALANCED[kind]

    def runner(kernel: Callable[..., None]) -> Runner:
        def run(count: int) -> None:
            for _ in range(count):
                kernel(block, values)

        return run

    return [(f"{kind} threads", runner(_threads)), (f"{kind} one thread", runner(_one_thread))]


@numba.njit(cache=True)
def _touch(
    state: npt.NDArray[np.float64],
    command: npt.NDArray[np.float64],
    out: npt.NDArray[np.float64],
    obs: npt.NDArray[np.float32],
    flags: npt.NDArray[np.bool_],
) -> None:
    """Read and write every element once: the data movement of a step, no arithmetic."""
    for k in range(state.shape[0]):
        for i in range(state.shape[1]):
            state[k, i] = state[k, i] + command[i]
    for k in range(out.shape[0]):
        for i in range(out.shape[1]):
            out[k, i] = command[i]
    for i in range(obs.shape[0]):
        for k in range(obs.shape[1]):
            obs[i, k] = command[i]
    for k in range(flags.shape[0]):
        for i in range(flags.shape[1]):
            flags[k, i] = command[i] > 0.0


def split_part(
    args: argparse.Namespace,
    envs: Sequence[str],
    actions: Callable[[str, int, int], list[npt.NDArray[Any]]],
) -> str:
    """Time the pieces of a vector env step on one thread; print and return the markdown."""
    n = args.num_envs
    print(
        f"\nsplit: ns per env-step at N = {n}, one thread (serial kernels), median of "
        f"{args.repeats} rounds"
    )
    lines = [
        f"Where a vector env-step goes (N = {thousands(n)}, serial kernels, ns per env-step, "
        f"median [min, max] of {args.repeats} rounds):",
        "",
        "| env | vector step | env kernel | plant | observation | bookkeeping | memory floor |",
        "|---|---|---|---|---|---|---|",
    ]
    for env_id in envs:
        pieces = _pieces(env_id, n, actions(env_id, n, args.seed), args.seed)
        measure(pieces, args.repeats, args.seconds, burn_in=256)
        ns = {p.name: [1e9 / r for r in p.rates] for p in pieces}
        cells = {
            "vector step": ns["vector step"],
            "env kernel": ns["env kernel"],
            "plant": ns["plant"],
            "observation": [k - p for k, p in zip(ns["env kernel"], ns["plant"], strict=True)],
            "bookkeeping": [
                v - k for v, k in zip(ns["vector step"], ns["env kernel"], strict=True)
            ],
            "memory floor": ns["memory floor"],
        }
        text = {k: ns_stats(v) for k, v in cells.items()}
        name = env_id.removeprefix("frictiongym/")
        print(f"  {name:18s} " + "  ".join(f"{k} {v}" for k, v in text.items()))
        lines.append(f"| {name} | " + " | ".join(text.values()) + " |")
    return "\n".join(lines)


def _pieces(env_id: str, n: int, table: list[npt.NDArray[Any]], seed: int) -> list[Timed]:
    """The timed pieces of one env's vector step (see the module docstring)."""
    env = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", parallel=False)
    env.reset(seed=seed)
    sim = env.unwrapped.sim
    steps = cycle(table)
    commands = cycle([a.astype(np.float64).reshape(n) for a in table])
    fresh = np.zeros(n, dtype=bool)
    obs = np.zeros((n, sim.observation_size), np.float32)
    out = np.zeros((env_kernel.OUT_SIZE, n))
    flags = np.zeros((env_kernel.FLAG_SIZE, n), dtype=bool)
    # the kernel's arguments after ``fresh``: no autoreset in it (sources before 5900f26 have
    # neither argument)
    autoreset = (False, sim._start) if hasattr(sim, "_start") else ()
    task = (sim.rows, sim.noise_state, sim.config, fresh, *autoreset, obs, out, flags)
    plant = Plant(sim.plant, sim.friction, sim.dt, n, parallel=False)
    state = sim.plants.state.copy()

    def vector_step(count: int) -> None:
        for a in islice(steps, count):
            env.step(a)

    def kernel_call(count: int) -> None:
        for c in islice(commands, count):
            sim.plants.run(c, *task)

    def plant_only(count: int) -> None:
        for c in islice(commands, count):
            plant.run(c)

    def floor(count: int) -> None:
        for c in islice(commands, count):
            _touch(state, c, out, obs, flags)

    return [
        Timed("vector step", vector_step, n),
        Timed("env kernel", kernel_call, n),
        Timed("plant", plant_only, n),
        Timed("memory floor", single_threaded(floor), n),
    ]
