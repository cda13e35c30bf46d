"""Competing load for the threading benchmarks: what a learner, a second seed or CI does.

Used by ``bench_plants.py`` and ``bench_envs.py`` (the kernels' threading beside a learner) and
``bench_rl_loops.py`` (training loops beside a learner). The cases of ``LOADS``:

* ``quiet``: nothing started by the script (other work on the machine is not controlled);
* ``busy``: another process spinning on one core (``while True: pass``);
* ``learner``: another process running torch on 2 threads, in a loop: 8 products of 256 x 256
  matrices (about 0.1 ms each on 2 threads here) then a 1 ms sleep, as a learner alternates
  its updates with waits for data;
* ``torch``: torch work in this process between the steps (:class:`TorchPolicy`): the forward
  pass of a 64-64 tanh MLP on 2 threads over each step's batch, as an on-policy rollout does.

For the kernels' threading, each case times four variants of one batch, interleaved round by
round: the serial kernel (``parallel=False``), the default, the threaded kernel
(``parallel=True``) and a second copy of the serial one. The figures are the per-round ratios to
the serial kernel; the copy's ratio shows how far two identical variants differ under that load,
the noise against which the default's ratio is read.

Imported by the scripts as ``_load`` (the scripts' folder is first on ``sys.path``); not part of
the package.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import subprocess
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from _bench import Runner, measure, paired_ratios, ratio_stats, stats, thousands

LOADS = ("quiet", "busy", "learner", "torch")
LOAD_NOTES = {
    "quiet": "nothing else started",
    "busy": "a process spinning on one core",
    "learner": "a torch process on 2 threads (matmuls, 1 ms sleeps)",
    "torch": "torch forward pass on 2 threads in this process after every step",
}
#: The default must stay within this fraction of the serial kernel (issue 16).
TOLERANCE = 0.05

#: The learner process: torch on 2 threads, bursts of matrix products separated by short sleeps.
LEARNER_CODE = """
import time
import torch

torch.set_num_threads(2)
a = torch.randn(256, 256)
b = torch.randn(256, 256) / 16.0
print("ready", flush=True)
while True:
    for _ in range(8):
        a = torch.tanh(a @ b)
    time.sleep(0.001)
"""


def add_arguments(parser: argparse.ArgumentParser, batch: str) -> None:
    """``--thread-sizes`` and ``--loads`` of a script's threads part; ``batch`` names a unit."""
    parser.add_argument(
        "--thread-sizes",
        type=int,
        nargs="+",
        default=None,
        metavar="N",
        help=f"numbers of {batch} of the threads part (default: 64 512 4096 65536; with "
        "--quick: 512 4096)",
    )
    parser.add_argument(
        "--loads",
        nargs="+",
        choices=LOADS,
        default=list(LOADS),
        help="competing load of the threads part: "
        + "; ".join(f"{k}: {v}" for k, v in LOAD_NOTES.items())
        + " (default: all)",
    )


def needs_torch(args: argparse.Namespace) -> bool:
    """Whether the threads part will run a load that needs torch."""
    return (
        args.part != "cartpole"
        and args.part != "plants"
        and bool({"learner", "torch"} & set(args.loads))
    )


def section(
    args: argparse.Namespace,
    title: str,
    make: MakeRunner,
    *,
    unit: str,
    features: int,
    burn_in: int,
    sizes: Sequence[int] | None = None,
    loads: Sequence[str] | None = None,
) -> str:
    """Time ``make``'s runners on each kernel under each load; print and return the markdown."""
    if sizes is None:
        sizes = args.thread_sizes or ([512, 4096] if args.quick else [64, 512, 4096, 65536])
    print(
        f"\nthreads: {title}; on the serial kernel, the default and the threaded kernel; "
        f"{unit}/s, ratios per round to the serial kernel, {args.repeats} rounds of "
        f"{args.seconds} s"
    )
    cases = run_cases(
        make,
        sizes,
        args.loads if loads is None else loads,
        features=features,
        repeats=args.repeats,
        seconds=args.seconds,
        burn_in=burn_in,
    )
    print(f"  {summary(cases)}")
    return "\n".join(
        [f"Threads: {title}:", "", markdown(cases, unit, args.repeats), "", summary(cases)]
    )


def import_torch_first() -> bool:
    """Import torch before numba starts its threads, as a training script does; False if absent.

    Import order decides whether the two share an OpenMP runtime: when torch comes first it
    loads its own ``libgomp`` and numba later loads the system's, so each keeps its own thread
    pool (two pools of 2 threads on 2 cores); when numba's threads start first, torch reuses
    numba's ``libgomp`` and one pool serves both. A user's script imports torch (or
    Stable-Baselines3) at the top, before any env steps, so the benchmarks do the same.
    """
    try:
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


@contextlib.contextmanager
def competing(load: str) -> Iterator[None]:
    """Run the other process of ``load`` (if any) for the duration of the block."""
    processes: list[subprocess.Popen[str]] = []
    try:
        if load == "busy":
            processes.append(subprocess.Popen([sys.executable, "-c", "while True: pass"]))
        elif load == "learner":
            learner = subprocess.Popen(
                [sys.executable, "-c", LEARNER_CODE], stdout=subprocess.PIPE, text=True
            )
            processes.append(learner)
            assert learner.stdout is not None
            if learner.stdout.readline().strip() != "ready":
                raise RuntimeError("the learner process did not start (is torch installed?)")
        elif load not in LOADS:
            raise ValueError(f"unknown load {load!r}; use one of {LOADS}")
        yield
    finally:
        for process in processes:
            process.kill()
            process.wait()


class TorchPolicy:
    """A 64-64 tanh MLP's forward pass, torch on ``threads`` threads, on a float32 batch."""

    def __init__(self, features: int, threads: int = 2, seed: int = 0) -> None:
        import torch

        torch.manual_seed(seed)
        self.torch = torch
        self.threads = threads
        self.net = torch.nn.Sequential(
            torch.nn.Linear(features, 64),
            torch.nn.Tanh(),
            torch.nn.Linear(64, 64),
            torch.nn.Tanh(),
            torch.nn.Linear(64, 1),
        )

    def hold_threads(self) -> None:
        """Set torch's thread count again (numba's OpenMP start may have reset it)."""
        if self.torch.get_num_threads() != self.threads:
            self.torch.set_num_threads(self.threads)

    def __call__(self, batch: npt.NDArray[np.float32]) -> None:
        with self.torch.no_grad():
            self.net(self.torch.from_numpy(batch))


#: Builds a runner of ``size`` plants or envs on ``parallel`` (None: the default), with the
#: torch work to do after each step (or None); returns the runner and the kernel it calls.
MakeRunner = Callable[[int, "bool | None", "TorchPolicy | None"], tuple[Runner, Any]]

KERNELS = (("serial", False), ("default", None), ("threaded", True), ("serial copy", False))


@dataclass
class KernelVariant:
    """One kernel choice timed under one load."""

    name: str
    run: Runner
    batch: int
    kernel: Any
    rates: list[float] = field(default_factory=list)

    def threaded_share(self) -> str:
        """Share of calls the default ran threaded (all calls, calibration included)."""
        calls = getattr(self.kernel, "calls", None)
        if calls is None:
            return "-"
        return f"{calls[1] / max(1, sum(calls)):.0%}"


@dataclass
class LoadCase:
    """The kernel variants of one batch size under one load."""

    load: str
    size: int
    variants: list[KernelVariant]

    def ratios(self, name: str) -> list[float]:
        """Per-round ratios of variant ``name``'s rate to the serial kernel's."""
        by_name = {v.name: v for v in self.variants}
        return paired_ratios(by_name[name], by_name["serial"])

    def default_ok(self) -> bool:
        """Whether the default's median is within ``TOLERANCE`` of the serial kernel or above."""
        return statistics.median(self.ratios("default")) >= 1.0 - TOLERANCE


def run_cases(
    make: MakeRunner,
    sizes: Sequence[int],
    loads: Sequence[str],
    features: int,
    repeats: int,
    seconds: float,
    burn_in: int,
) -> list[LoadCase]:
    """Time serial, default and threaded at each size under each load; prints as it goes."""
    cases = []
    for load in loads:
        with competing(load):
            for size in sizes:
                policy = TorchPolicy(features) if load == "torch" else None
                variants = []
                for name, parallel in KERNELS:
                    run, kernel = make(size, parallel, policy)
                    variants.append(KernelVariant(name, run, size, kernel))
                measure(variants, repeats, seconds, burn_in)
                case = LoadCase(load, size, variants)
                cases.append(case)
                print(
                    f"  {load:8s} N = {size:>6d}  serial {stats(variants[0].rates):22s} "
                    f"default/serial {ratio_stats(case.ratios('default')):22s} "
                    f"threaded/serial {ratio_stats(case.ratios('threaded')):22s} "
                    f"copy/serial {ratio_stats(case.ratios('serial copy')):22s} "
                    f"default ran threaded: {variants[1].threaded_share()}"
                )
    return cases


def summary(cases: Sequence[LoadCase]) -> str:
    """One line: whether the default stayed within the tolerance of serial in every case.

    A case below names its default / serial median and, for scale, the serial copy's.
    """
    bad = [
        f"{c.load} N={c.size} ({statistics.median(c.ratios('default')):.3g}; serial copy "
        f"{statistics.median(c.ratios('serial copy')):.3g})"
        for c in cases
        if not c.default_ok()
    ]
    verdict = "yes" if not bad else "no: " + ", ".join(bad)
    return (
        f"default within {TOLERANCE:.0%} of the serial kernel or faster (median) in every "
        f"case: {verdict}"
    )


def markdown(cases: Sequence[LoadCase], unit: str, repeats: int) -> str:
    """The cases as a markdown table."""
    lines = [
        f"| load | N | serial kernel, {unit}/s, median [min, max] of {repeats} | "
        "default / serial | threaded / serial | serial copy / serial (noise) | "
        "default's calls on threads |",
        "|---|---:|---|---|---|---|---:|",
    ]
    for case in cases:
        lines.append(
            f"| {case.load} | {thousands(case.size)} | {stats(case.variants[0].rates)} | "
            f"{ratio_stats(case.ratios('default'))} | {ratio_stats(case.ratios('threaded'))} | "
            f"{ratio_stats(case.ratios('serial copy'))} | {case.variants[1].threaded_share()} |"
        )
    lines += ["", "Loads: " + "; ".join(f"{k}: {v}" for k, v in LOAD_NOTES.items()) + "."]
    return "\n".join(lines)
