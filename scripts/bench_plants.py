"""Benchmark: plant steps per second of frictiongym's compiled Plant against a numpy loop.

For each batch size N the script times, interleaved in one process:

* ``numpy ref``: the frictionless linear plant ``J x'' + B x' = u`` written as a user would
  write it in numpy: x and v arrays of size N, stepped exactly over the zero-order-hold period
  with precomputed coefficients (``x += c1*v + c2*u; v *= e; v += c3*u``). No saturation,
  no friction, no bookkeeping.
* ``Plant`` with the paper's rotary friction (``ROTARY_PAPER``: linear Stribeck decay,
  event-exact step), with the sub-stepped ``exponential`` decay (default substeps), and with
  ``NoFriction``, so the cost of each law is visible. These run on ``Plant``'s default kernel:
  for batches of at least ``PARALLEL_MIN_PLANTS`` when numba has more than one thread the
  adaptive choice (``frictiongym.plants.threads``: the serial or the parallel kernel, numba
  ``prange`` over the plants, whichever is faster at the moment), the serial one otherwise.
* ``ROTARY_PAPER`` once more on each forced kernel (``parallel=False`` and ``parallel=True``),
  so the gain or cost of the threads is visible at every batch size. The kernels give
  bit-identical results. Where the default may use threads, ``ROTARY_PAPER`` is also timed on
  the parallel kernel restricted to one thread (``numba.set_num_threads(1)`` around the run),
  which splits the parallel / serial ratio into what the parallel kernel's code gains on one
  core and what the other threads add.

Every variant is driven by the same pre-generated commands: per plant an AR(1) process
(correlation time 20 ms, standard deviation 0.2 V) around the break-away level of
±0.21 V / -0.19 V, so that about half the plants are stuck at any time and about one plant
in ten switches between stick and slip at every step. The commands are stored in a
``(T, N)`` table that the loops cycle through, so drawing them is not timed.

Timing: one burn-in run (which also triggers numba's compile or cache load), a short run to
calibrate the step count to ``--seconds``, then ``--repeats`` rounds in which each variant
runs once, in an order rotated every round. Rates are medians over rounds. The ratio of a
variant to the numpy reference is the median of the per-round ratios, so drift of the
machine between rounds (up to 1.5x here, docs/benchmarks.md) cancels out.

As context only, gymnasium's ``CartPoleVectorEnv`` at 4 096 envs is timed against the Plant
(default kernel and serial kernel) at the same batch size. That compares a full env step
(physics, observation, reward, termination, autoreset) with a bare plant step, so it is a
reference point, not a verdict.

**Threads** (``--part threads``): the Plant (``ROTARY_PAPER``) at several batch sizes and the
tuner's ``simulate`` on a chunk of 32 768 candidates, each on the serial kernel, the default
and the threaded kernel, under each competing load of ``_load.py`` (quiet, a busy process, a
torch learner process, torch work in this process; the tuner runs without the last).

Run ``python scripts/bench_plants.py --help`` for the options.
"""

from __future__ import annotations

import argparse
import datetime
import math
import shlex
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import cycle, islice
from typing import Any

import _load
import numba
import numpy as np
import numpy.typing as npt
from _bench import (
    Runner,
    machine_line,
    measure,
    paired_ratios,
    ratio_stats,
    run_parts,
    single_threaded,
    source_revision,
    stats,
    thousands,
    timed,
)

from frictiongym.friction import ROTARY_PAPER, FrictionModel, NoFriction
from frictiongym.plants import Plant, PlantParams
from frictiongym.plants.threads import PARALLEL_MIN_PLANTS, AdaptiveKernel
from frictiongym.tuning import DEFAULT_HORIZON, GainBounds, StepSpecs, TuningModel, simulate
from frictiongym.tuning.search import DEFAULT_CHUNK

FloatArray = npt.NDArray[np.float64]

PARAMS = PlantParams(inertia=7.143e-3, damping=0.0446, command_limit=10.0)
DT = 0.002  #: control period, s
COMMAND_STD = 0.2  #: standard deviation of the commands, V
COMMAND_TAU = 0.02  #: correlation time of the commands, s
TABLE_BYTES = 16 * 2**20  #: memory budget of one command table
REF = "numpy ref"
PAPER = "ROTARY_PAPER linear (exact)"
ONE_THREAD = "parallel, 1 thread"
CONTEXT_ENVS = 4096


@dataclass
class Variant:
    """One timed configuration: a label, a runner and what it steps.

    ``kernel`` is ``"serial"``, ``"parallel"`` or ``"adaptive"`` for a Plant (empty otherwise)
    and ``default`` tells whether that is the kernel ``Plant`` picks by itself at this size.
    """

    label: str
    run: Runner
    batch: int
    substeps: int | None = None
    kernel: str = ""
    default: bool = True
    rates: list[float] = field(default_factory=list)

    @property
    def kernel_note(self) -> str:
        """Kernel with ``(default)`` or ``(forced)``, or ``-`` for a non-Plant variant."""
        if not self.kernel:
            return "-"
        return f"{self.kernel} ({'default' if self.default else 'forced'})"


def plant_variant(
    label: str,
    friction: FrictionModel,
    table: FloatArray,
    parallel: bool | None = None,
    one_thread: bool = False,
) -> Variant:
    """A Plant variant on the default kernel (``parallel=None``) or on a forced one.

    With ``one_thread`` the parallel kernel runs with numba restricted to one thread.
    """
    run, plant = make_plant(friction, table, True if one_thread else parallel)
    default = parallel is None or kernel_name(Plant(PARAMS, friction, DT, table.shape[1])) == (
        "parallel" if parallel else "serial"
    )
    kernel = kernel_name(plant)
    if one_thread:
        run, kernel, default = single_threaded(run), ONE_THREAD, False
    return Variant(label, run, table.shape[1], plant.substeps, kernel, default)


def kernel_name(plant: Plant) -> str:
    """``adaptive``, ``parallel`` or ``serial``: the kernel a Plant steps with."""
    if isinstance(plant._step_kernel, AdaptiveKernel):
        return "adaptive"
    return "parallel" if plant.parallel else "serial"


def command_table(batch: int, seed: int) -> FloatArray:
    """Pre-generated commands, shape ``(T, batch)``: one stationary AR(1) process per plant.

    ``T`` is chosen so the table stays within ``TABLE_BYTES`` (at least 32 rows, at most
    1 024), which keeps the memory traffic of reading commands the same order for all
    variants; the loops cycle through the rows.
    """
    rows = int(min(1024, max(32, TABLE_BYTES // (8 * batch))))
    rng = np.random.default_rng(seed)
    a = math.exp(-DT / COMMAND_TAU)
    table = np.empty((rows, batch))
    table[0] = rng.normal(0.0, COMMAND_STD, batch)
    for t in range(1, rows):
        table[t] = a * table[t - 1] + math.sqrt(1.0 - a * a) * COMMAND_STD * rng.standard_normal(
            batch
        )
    return table


def zoh_coefficients(
    inertia: float, damping: float, dt: float
) -> tuple[float, float, float, float]:
    """Exact ZOH coefficients ``(c1, c2, c3, e)`` of ``J v' = u - B v``, ``x' = v``.

    Over one period with ``u`` held: ``x+ = x + c1 v + c2 u`` and ``v+ = e v + c3 u``.
    """
    rate = damping / inertia
    e = math.exp(-rate * dt)
    c1 = -math.expm1(-rate * dt) / rate
    c3 = c1 / inertia
    c2 = (dt - c1) / damping
    return c1, c2, c3, e


def make_reference(table: FloatArray) -> tuple[Runner, FloatArray, FloatArray]:
    """The numpy baseline: a frictionless linear plant stepped in a plain Python loop.

    Returns the runner and the position and velocity arrays it updates in place.
    """
    batch = table.shape[1]
    c1, c2, c3, e = zoh_coefficients(PARAMS.inertia, PARAMS.damping, DT)
    position = np.zeros(batch)
    velocity = np.zeros(batch)
    rows = list(table)

    def run(steps: int) -> None:
        x, v = position, velocity
        for u in islice(cycle(rows), steps):
            x += c1 * v + c2 * u
            v *= e
            v += c3 * u

    return run, position, velocity


def make_plant(
    friction: FrictionModel, table: FloatArray, parallel: bool | None = None
) -> tuple[Runner, Plant]:
    """A frictiongym Plant of the table's batch size, stepped with the table's rows.

    ``parallel`` is passed to ``Plant``: ``None`` keeps its default kernel choice.
    """
    plant = Plant(PARAMS, friction, dt=DT, num_plants=table.shape[1], parallel=parallel)
    rows = list(table)
    step = plant.step

    def run(steps: int) -> None:
        for u in islice(cycle(rows), steps):
            step(u)

    return run, plant


def make_cartpole(num_envs: int, seed: int) -> Runner:
    """Gymnasium's CartPoleVectorEnv stepped with pre-generated actions (default autoreset)."""
    import gymnasium

    env = gymnasium.make_vec(
        "CartPole-v1", num_envs=num_envs, vectorization_mode="vector_entry_point"
    )
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    rows = list(rng.integers(0, 2, size=(256, num_envs)))
    step = env.step

    def run(steps: int) -> None:
        for action in islice(cycle(rows), steps):
            step(action)

    return run


def check_reference(seed: int, steps: int = 500, batch: int = 64) -> float:
    """Largest state difference between the numpy reference and ``Plant`` with NoFriction.

    Both integrate the same linear ODE exactly, so they agree to rounding; this guards the
    reference against a wrong coefficient.
    """
    table = command_table(batch, seed)
    run, x, v = make_reference(table)
    _, plant = make_plant(NoFriction(), table)
    run(steps)
    for u in islice(cycle(list(table)), steps):
        plant.step(u)
    scale = max(1.0, float(np.max(np.abs(x))), float(np.max(np.abs(v))))
    return (
        max(float(np.max(np.abs(plant.position - x))), float(np.max(np.abs(plant.velocity - v))))
        / scale
    )


def stick_slip_mix(
    friction: FrictionModel, seed: int, steps: int, batch: int = 4096
) -> tuple[float, float]:
    """Mean stuck fraction and stick<->slip switches per plant-step under the bench commands.

    Measured after a burn-in of one table length (at least 200 steps), untimed.
    """
    table = command_table(batch, seed)
    rows = list(table)
    plant = Plant(PARAMS, friction, dt=DT, num_plants=batch)
    burn_in = max(200, len(rows))
    for u in islice(cycle(rows), burn_in):
        plant.step(u)
    stuck_sum = 0.0
    switches = 0
    previous = plant.stuck.copy()
    for u in islice(cycle(rows), burn_in, burn_in + steps):
        plant.step(u)
        now = plant.stuck
        stuck_sum += float(now.mean())
        switches += int(np.count_nonzero(now != previous))
        previous = now.copy()
    return stuck_sum / steps, switches / (steps * batch)


#: Kernel comparisons of ROTARY_PAPER: (numerator, denominator, description).
KERNEL_RATIOS = (
    ("adaptive", "serial", "adaptive (default) / serial"),
    ("parallel", "serial", "parallel / serial"),
    (ONE_THREAD, "serial", "parallel on 1 thread / serial"),
    ("parallel", ONE_THREAD, "parallel / parallel on 1 thread"),
)


def kernel_ratios(variants: Sequence[Variant]) -> list[list[float] | None]:
    """Per-round ratios of the ROTARY_PAPER kernels in ``KERNEL_RATIOS`` (None if not timed)."""
    paper = {v.kernel: v for v in variants if v.label == PAPER and v.kernel}
    return [
        paired_ratios(paper[a], paper[b]) if a in paper and b in paper else None
        for a, b, _ in KERNEL_RATIOS
    ]


def print_kernel_ratios(variants: Sequence[Variant]) -> None:
    """Print the kernel comparisons that were timed."""
    for (_, _, what), ratios in zip(KERNEL_RATIOS, kernel_ratios(variants), strict=True):
        if ratios is not None:
            print(f"  ROTARY_PAPER {what:33s} {ratio_stats(ratios)}")


def build_parser() -> argparse.ArgumentParser:
    """Command-line options."""
    parser = argparse.ArgumentParser(
        prog="bench_plants.py",
        description=(
            "Plant steps per second of frictiongym's compiled Plant (ROTARY_PAPER exact on "
            "the default and on the other kernel, serial or parallel; exponential sub-stepped "
            "and NoFriction on the default kernel) against a bare numpy loop of the "
            "frictionless linear plant at the same batch size, timed interleaved in one "
            "process. Ratios to the numpy loop are the meaningful figure: absolute rates drift "
            "by up to 1.5x between runs on the project machine."
        ),
    )
    parser.add_argument(
        "--batches",
        type=int,
        nargs="+",
        default=None,
        metavar="N",
        help="batch sizes (number of plants stepped per call) to time (default: 1 64 128 1024 "
        "65536; with --quick: 1 1024)",
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="timed rounds per batch size; each round runs every variant once and the "
        "tables report medians (default: 5; with --quick: 2)",
    )
    parser.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="target wall time of one timed run of one variant, s; the step count is "
        "calibrated to it after warm-up (default: 0.5; with --quick: 0.05)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="fast smoke run (--part plants: a few seconds; the threads part: a minute or two): "
        "smaller defaults for --batches, --repeats, --seconds and --thread-sizes (explicit "
        "values still win) and a short stick/slip characterisation; the figures are then too "
        "noisy to quote",
    )
    parser.add_argument(
        "--markdown",
        action="store_true",
        help="also print the results as markdown tables ready for docs/benchmarks.md",
    )
    parser.add_argument(
        "--no-context",
        action="store_true",
        help=f"skip the context comparison with gymnasium's CartPoleVectorEnv at "
        f"{CONTEXT_ENVS} envs",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the pre-generated commands and CartPole actions (default: 0)",
    )
    parser.add_argument(
        "--part",
        choices=("all", "plants", "threads"),
        default="all",
        help="plants: the Plant against the numpy loop (and the CartPole context); threads: "
        "the Plant and the tuner on the serial, default and threaded kernel under each "
        "--loads case; all: both (default)",
    )
    parser.add_argument(
        "--tuner-chunk",
        type=int,
        default=DEFAULT_CHUNK,
        metavar="N",
        help=f"candidates of the tuner's simulate() in the threads part (default: "
        f"{DEFAULT_CHUNK}, a chunk of frictiongym tune; 0: skip the tuner)",
    )
    _load.add_arguments(parser, "plants (the tuner skips the torch load)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the results; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    defaults = ([1, 1024], 2, 0.05) if args.quick else ([1, 64, 128, 1024, 65536], 5, 0.5)
    if args.batches is None:
        args.batches = defaults[0]
    if args.repeats is None:
        args.repeats = defaults[1]
    if args.seconds is None:
        args.seconds = defaults[2]
    if any(n < 1 for n in args.batches) or args.repeats < 1 or args.seconds <= 0.0:
        parser.error("batches and repeats must be positive and seconds > 0")
    shown_argv = sys.argv[1:] if argv is None else argv
    command = shlex.join(["python", "scripts/bench_plants.py", *shown_argv])
    today = datetime.date.today().isoformat()

    print(f"command: {command}")
    print(f"date:    {today}")
    print(f"machine: {machine_line()}")
    print(f"source:  frictiongym {source_revision()}")
    print(
        f"plant:   J={PARAMS.inertia} B={PARAMS.damping} dt={DT} s; commands AR(1), "
        f"std {COMMAND_STD} V, correlation time {COMMAND_TAU * 1e3:g} ms"
    )
    if _load.needs_torch(args) and not _load.import_torch_first():
        parser.error("the learner and torch loads need torch; use --loads quiet busy")
    parts = {"plants": lambda: plants_part(args), "threads": lambda: threads_part(args)}
    return run_parts(
        [run for name, run in parts.items() if args.part in ("all", name)], args.markdown
    )


def plant_threads_runner(
    size: int, parallel: bool | None, policy: _load.TorchPolicy | None, seed: int
) -> tuple[Runner, object]:
    """ROTARY_PAPER on ``size`` plants on ``parallel``; ``policy`` gets (x, v) after each step."""
    table = command_table(size, seed)
    run, plant = make_plant(ROTARY_PAPER, table, parallel)
    if policy is None:
        return run, plant._step_kernel
    rows = list(table)
    step, state = plant.step, plant.state

    def run_with_policy(steps: int) -> None:
        policy.hold_threads()
        for u in islice(cycle(rows), steps):
            step(u)
            policy(state[:2].T.astype(np.float32))

    return run_with_policy, plant._step_kernel


def tune_runner(
    size: int, parallel: bool | None, policy: _load.TorchPolicy | None, seed: int
) -> tuple[Runner, object]:
    """``simulate`` of ``size`` candidates as ``frictiongym tune`` judges a chunk (one step)."""
    gains = GainBounds().sample(np.random.default_rng(seed), size)
    model, specs = TuningModel(), StepSpecs()

    def run(steps: int) -> None:
        for _ in range(steps):
            simulate(gains, model, specs, DEFAULT_HORIZON, parallel=parallel)

    return run, None


def adaptive_overhead(calls: int = 200_000, repeats: int = 5) -> float:
    """Seconds an ``AdaptiveKernel`` adds to a call: no-op twins against the bare no-op (best)."""

    def noop(*args: object) -> int:
        return -1

    arguments = (0,) * 7  # as many as step_batch takes
    best = []
    for kernel in (noop, AdaptiveKernel(noop, noop)):

        def run(steps: int, kernel: Any = kernel) -> None:
            for _ in range(steps):
                kernel(*arguments)

        best.append(min(timed(run, calls) for _ in range(repeats)) / calls)
    return best[1] - best[0]


def threads_part(args: argparse.Namespace) -> str:
    """Time the Plant and the tuner on each kernel under each load; returns the markdown."""
    overhead = (
        f"The adaptive kernel's own cost per call: {adaptive_overhead() * 1e6:.2f} µs (no-op "
        "twins against the bare no-op, best of 5 runs of 200 000 calls)."
    )
    print(f"\n{overhead}")
    parts = [
        overhead,
        _load.section(
            args,
            "the Plant (`ROTARY_PAPER`, the commands above; the torch load feeds each step's "
            "(x, v) to the MLP)",
            lambda size, parallel, policy: plant_threads_runner(size, parallel, policy, args.seed),
            unit="plant-steps",
            features=2,
            burn_in=100,
        ),
    ]
    if args.tuner_chunk > 0:
        parts.append(
            _load.section(
                args,
                f"the tuner's `simulate` on {thousands(args.tuner_chunk)} candidates (a chunk of "
                "`frictiongym tune`: paper specs, nominal model, 3 s horizon, early stop)",
                lambda size, parallel, policy: tune_runner(size, parallel, policy, args.seed),
                unit="candidates",
                features=0,
                burn_in=1,
                sizes=[args.tuner_chunk],
                loads=[load for load in args.loads if load != "torch"],
            )
        )
    return "\n\n".join(parts)


def plants_part(args: argparse.Namespace) -> str | None:
    """The Plant against the numpy loop, and the context; the markdown, or None on an error."""
    start = time.perf_counter()
    probe = Plant(PARAMS, ROTARY_PAPER, dt=DT)
    probe.step(0.0)
    print(
        f"first Plant.step in this process (numba compile or cache load): "
        f"{time.perf_counter() - start:.3f} s"
    )
    start_parallel = time.perf_counter()
    probe = Plant(PARAMS, ROTARY_PAPER, dt=DT, num_plants=PARALLEL_MIN_PLANTS, parallel=True)
    probe.step(0.0)
    print(
        f"first parallel step (compile or cache load, thread pool start): "
        f"{time.perf_counter() - start_parallel:.3f} s; threading layer "
        f"{numba.threading_layer()}, {numba.get_num_threads()} threads; Plant's default is "
        f"adaptive for N >= {PARALLEL_MIN_PLANTS}"
    )
    error = check_reference(args.seed)
    print(f"numpy ref vs Plant(NoFriction), 500 steps: max relative state difference {error:.1e}")
    if error > 1e-9:
        print("error: the numpy reference does not match the frictionless Plant", file=sys.stderr)
        return None

    laws: list[tuple[str, FrictionModel]] = [
        (PAPER, ROTARY_PAPER),
        ("ROTARY_PAPER exponential", ROTARY_PAPER.replace(shape="exponential")),
        ("NoFriction", NoFriction()),
    ]
    mix_steps = 200 if args.quick else 1000
    print(f"\nstick/slip mix under these commands (4096 plants, {mix_steps} steps, untimed):")
    mixes: dict[str, tuple[float, float]] = {}
    for label, law in laws:
        mixes[label] = stick_slip_mix(law, args.seed, mix_steps)
        stuck, switches = mixes[label]
        print(
            f"  {label:28s} stuck {stuck:6.1%}   stick<->slip switches {switches:6.1%} "
            "of plant-steps"
        )

    results: dict[int, list[Variant]] = {}
    for batch in args.batches:
        table = command_table(batch, args.seed)
        ref_run, _, _ = make_reference(table)
        variants = [Variant(REF, ref_run, batch)]
        for label, law in laws:
            variants.append(plant_variant(label, law, table))
            if law is ROTARY_PAPER:  # the same law on the other kernel(s)
                default = variants[-1].kernel
                for forced in (False, True):
                    if default != ("parallel" if forced else "serial"):
                        variants.append(plant_variant(label, law, table, parallel=forced))
                if default != "serial" and numba.get_num_threads() > 1:
                    variants.append(plant_variant(label, law, table, one_thread=True))
        burn_in = max(100, table.shape[0])
        measure(variants, args.repeats, args.seconds, burn_in)
        results[batch] = variants
        print(
            f"\nN = {batch}  ({table.shape[0]}-row command table; plant-steps/s, median "
            f"[min, max] of {args.repeats} rounds)"
        )
        ref = variants[0]
        for variant in variants:
            ns = 1e9 / statistics.median(variant.rates)
            line = (
                f"  {variant.label:28s} {variant.kernel_note:27s} {stats(variant.rates):28s} "
                f"{ns:9.1f} ns/plant-step"
            )
            if variant is not ref:
                line += f"   x ref {ratio_stats(paired_ratios(variant, ref))}"
            print(line)
        print_kernel_ratios(variants)

    context: list[Variant] = []
    if not args.no_context:
        table = command_table(CONTEXT_ENVS, args.seed)
        ref_run, _, _ = make_reference(table)
        context = [
            Variant(
                "gymnasium CartPoleVectorEnv", make_cartpole(CONTEXT_ENVS, args.seed), CONTEXT_ENVS
            ),
            plant_variant(PAPER, ROTARY_PAPER, table),
            plant_variant(PAPER, ROTARY_PAPER, table, parallel=False),
            Variant(REF, ref_run, CONTEXT_ENVS),
        ]
        if context[1].kernel == "parallel" and numba.get_num_threads() > 1:
            context.insert(3, plant_variant(PAPER, ROTARY_PAPER, table, one_thread=True))
        measure(context, args.repeats, args.seconds, burn_in=max(100, table.shape[0]))
        print(
            f"\ncontext only, N = {CONTEXT_ENVS}: env-steps/s of a full CartPole env step vs "
            "plant-steps/s of a bare plant step"
        )
        for variant in context:
            line = f"  {variant.label:28s} {variant.kernel_note:27s} {stats(variant.rates):28s}"
            if variant is not context[0]:
                line += f"   x CartPole {ratio_stats(paired_ratios(variant, context[0]))}"
            print(line)
        print_kernel_ratios(context)
    return markdown(results, mixes, context, args.repeats)


def markdown(
    results: dict[int, list[Variant]],
    mixes: dict[str, tuple[float, float]],
    context: Sequence[Variant],
    repeats: int,
) -> str:
    """Results as markdown tables."""
    lines = [
        f"| N | variant | kernel | substeps | plant-steps/s, median [min, max] of {repeats} | "
        "ns per plant-step | ratio to numpy ref, median [min, max] | stuck (mean) |",
        "|---:|---|---|---:|---|---:|---|---:|",
    ]
    for batch, variants in results.items():
        ref = variants[0]
        for variant in variants:
            ns = 1e9 / statistics.median(variant.rates)
            if variant is ref:
                ratio, substeps, stuck = "1 (reference)", "exact", "-"
            else:
                ratio = ratio_stats(paired_ratios(variant, ref))
                substeps = str(variant.substeps)
                stuck = f"{mixes[variant.label][0]:.0%}"
            lines.append(
                f"| {thousands(batch)} | {variant.label} | {variant.kernel_note} | {substeps} | "
                f"{stats(variant.rates)} | {ns:.1f} | {ratio} | {stuck} |"
            )
    kernels = [(f"{thousands(batch)}", variants) for batch, variants in results.items()]
    if context:
        kernels.append((f"{thousands(CONTEXT_ENVS)} (context run)", list(context)))
    lines += [
        "",
        "Kernels compared (ROTARY_PAPER linear; median [min, max] of the per-round ratios):",
        "",
        "| N | default kernel | " + " | ".join(what for _, _, what in KERNEL_RATIOS) + " |",
        "|---:|---|" + "---|" * len(KERNEL_RATIOS),
    ]
    for name, variants in kernels:
        default = next(v.kernel for v in variants if v.label == PAPER and v.default)
        cells = [ratio_stats(r) if r is not None else "-" for r in kernel_ratios(variants)]
        lines.append(f"| {name} | {default} | " + " | ".join(cells) + " |")
    if context:
        lines += [
            "",
            f"Context only (N = {thousands(CONTEXT_ENVS)}; a full CartPole env step against a "
            "bare plant step):",
            "",
            "| variant | kernel | steps/s, median [min, max] | "
            "ratio to CartPoleVectorEnv, median [min, max] |",
            "|---|---|---|---|",
        ]
        for variant in context:
            ratio = (
                "1 (reference)"
                if variant is context[0]
                else ratio_stats(paired_ratios(variant, context[0]))
            )
            lines.append(
                f"| {variant.label} | {variant.kernel_note} | {stats(variant.rates)} | {ratio} |"
            )
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
