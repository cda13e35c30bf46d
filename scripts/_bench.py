"""Timing and report helpers shared by the benchmark scripts in this folder.

Used by ``bench_plants.py`` and ``bench_envs.py``. The method, in short: every variant is
warmed up, its step count is calibrated to a target wall time, then ``repeats`` rounds run
every variant once each, in an order rotated every round. Rates are medians over rounds; the
ratio of two variants is the median of their per-round ratios, so drift of the machine
between rounds cancels out. :func:`measure_in_turns` (``bench_envs.py``'s cartpole and loads
parts) makes the rounds short instead: a turn of about 5 ms per variant, in a new random order
every round, so that spells of the machine lasting seconds fall on every variant alike.

This module is imported by the scripts as ``_bench`` (the scripts' folder is first on
``sys.path`` when they run as ``python scripts/<name>.py``); it is not part of the package.
"""

from __future__ import annotations

import os
import platform
import statistics
import subprocess
import time
from collections.abc import Callable, Sequence
from itertools import cycle, islice
from typing import Any, Protocol

import numba
import numpy as np
import numpy.typing as npt

import frictiongym

#: Length of one variant's turn in :func:`measure_in_turns`, s: a few ms, so that the machine's
#: spells (seconds here) fall on every variant of a round alike.
TURN_SECONDS = 0.005

#: Runs a given number of steps of one variant.
Runner = Callable[[int], None]


class Timed(Protocol):
    """What :func:`measure` needs of a variant: a runner, its batch size and a list of rates."""

    run: Runner
    batch: int
    rates: list[float]


def timed(run: Runner, steps: int) -> float:
    """Wall time of ``run(steps)``, s."""
    start = time.perf_counter()
    run(steps)
    return time.perf_counter() - start


def calibrate(run: Runner, seconds: float) -> int:
    """Number of steps for which ``run`` takes about ``seconds``."""
    steps = 1
    while True:
        elapsed = timed(run, steps)
        if elapsed >= min(0.05, seconds / 4) or steps >= 1 << 26:
            return max(1, round(steps * seconds / elapsed))
        steps *= 4


def measure(variants: Sequence[Timed], repeats: int, seconds: float, burn_in: int) -> None:
    """Warm up, calibrate and time the variants interleaved; fills each variant's ``rates``.

    A rate is ``batch * steps / wall time`` of one timed run.
    """
    steps = warm_up(variants, seconds, burn_in)
    order = list(range(len(variants)))
    for r in range(repeats):
        shift = r % len(variants)
        for i in order[shift:] + order[:shift]:
            variant, n = variants[i], steps[i]
            variant.rates.append(variant.batch * n / timed(variant.run, n))


def warm_up(variants: Sequence[Timed], seconds: float, burn_in: int) -> list[int]:
    """Run each variant ``burn_in`` steps; return the step count of a run of about ``seconds``."""
    steps = []
    for variant in variants:
        variant.run(burn_in)
        steps.append(calibrate(variant.run, seconds))
    return steps


def cycled_runner(env: Any, actions: Sequence[Any]) -> Runner:
    """Step ``env`` with the cycled ``actions``, going on where the last call stopped."""
    rows = cycle(actions)

    def run(steps: int) -> None:
        for action in islice(rows, steps):
            env.step(action)

    return run


def turn_rounds(seconds: float) -> int:
    """Rounds of :func:`measure_in_turns` that give each variant ``seconds`` s of turns."""
    return max(1, round(seconds / TURN_SECONDS))


def turns(runners: Sequence[Runner], steps: Sequence[int], rounds: int) -> npt.NDArray[Any]:
    """Run the runners in short turns; returns seconds per step, shape (runners, rounds).

    Every round runs each runner once for its ``steps``, in a new random order (seeded): the
    machine's spells, which last seconds here (a busy neighbour, a learner's bursts), then fall
    on every runner alike, and no runner always follows the same other.
    """
    times = np.empty((len(runners), rounds))
    shuffle = np.random.default_rng(0)
    for r in range(rounds):
        for k in shuffle.permutation(len(runners)):
            times[k, r] = timed(runners[k], steps[k]) / steps[k]
    return times


def measure_in_turns(variants: Sequence[Timed], seconds: float, burn_in: int) -> None:
    """:func:`measure` in turns of about ``TURN_SECONDS`` each, ``seconds`` s of turns per variant.

    Each variant's ``rates`` gets one rate per round (see :func:`turns`), so the per-round
    ratios of :func:`paired_ratios` compare two variants timed a few ms apart.
    """
    steps = warm_up(variants, TURN_SECONDS, burn_in)
    times = turns([variant.run for variant in variants], steps, turn_rounds(seconds))
    for variant, per_step in zip(variants, times, strict=True):
        variant.rates[:] = (variant.batch / per_step).tolist()


def run_parts(parts: Sequence[Callable[[], str | None]], markdown: bool) -> int:
    """Run a script's parts in turn; print the wall time and, if asked, their markdown.

    A part returns its markdown, or None after printing an error (the exit status is then 1).
    """
    start = time.perf_counter()
    texts = []
    for part in parts:
        text = part()
        if text is None:
            return 1
        texts.append(text)
    print(f"\nwall time of the benchmark: {time.perf_counter() - start:.0f} s")
    if markdown:
        print()
        print("\n\n".join(texts))
    return 0


def paired_ratios(variant: Timed, reference: Timed) -> list[float]:
    """Per-round ratios of a variant's rate to the reference's rate."""
    return [a / b for a, b in zip(variant.rates, reference.rates, strict=True)]


def single_threaded(run: Runner) -> Runner:
    """``run`` with numba's thread count set to 1 for its duration."""

    def run_one(steps: int) -> None:
        threads = numba.get_num_threads()
        numba.set_num_threads(1)
        try:
            run(steps)
        finally:
            numba.set_num_threads(threads)

    return run_one


def si(rate: float) -> str:
    """Format a rate like ``13.7 M``."""
    for scale, suffix in ((1e9, " G"), (1e6, " M"), (1e3, " k")):
        if rate >= scale:
            return f"{rate / scale:.3g}{suffix}"
    return f"{rate:.3g}"


def thousands(n: int) -> str:
    """Format an integer with space-separated thousands, like ``65 536``."""
    return f"{n:,}".replace(",", " ")


def ns_stats(values: Sequence[float], digits: int = 1) -> str:
    """``median [min, max]`` of times in ns, with ``digits`` decimals."""
    low, median, high = (
        f"{v:.{digits}f}" for v in (min(values), statistics.median(values), max(values))
    )
    return f"{median} [{low}, {high}]"


def stats(values: Sequence[float]) -> str:
    """``median [min, max]`` of rates."""
    return f"{si(statistics.median(values))} [{si(min(values))}, {si(max(values))}]"


def quartile_stats(
    values: Sequence[float], show: Callable[[float], str] = lambda v: f"{v:.3g}"
) -> str:
    """``median [first quartile, third quartile]``, formatted by ``show`` (default: 3 digits)."""
    q1, median, q3 = (show(float(v)) for v in np.percentile(values, [25, 50, 75]))
    return f"{median} [{q1}, {q3}]"


def ratio_stats(values: Sequence[float]) -> str:
    """``median [min, max]`` of ratios."""
    return f"{statistics.median(values):.3g} [{min(values):.3g}, {max(values):.3g}]"


def machine_line() -> str:
    """CPU, core count and software versions."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:
            for line in info:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        import gymnasium

        gym = f", gymnasium {gymnasium.__version__}"
    except ImportError:
        gym = ""
    return (
        f"{cpu}, {os.cpu_count()} CPUs, {platform.system()} {platform.release()}; "
        f"Python {platform.python_version()}, numpy {np.__version__}, numba {numba.__version__} "
        f"({numba.get_num_threads()} threads){gym}"
    )


def _git(root: str, *args: str) -> str:
    """Output of a read-only git command in ``root`` (no optional index locks)."""
    done = subprocess.run(
        ["git", "--no-optional-locks", "-C", root, *args],
        capture_output=True,
        text=True,
        check=True,
        timeout=10,
    )
    return done.stdout.strip()


def source_revision() -> str:
    """Git commit of the checkout holding frictiongym, with ``+dirty`` if its files differ."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(frictiongym.__file__)))
    try:
        commit = _git(root, "rev-parse", "--short", "HEAD")
        changed = _git(root, "status", "--porcelain", "--untracked-files=no", "--", "frictiongym")
    except (OSError, subprocess.SubprocessError):
        return "unknown (not a git checkout)"
    return commit + (" +dirty (uncommitted changes under frictiongym/)" if changed else "")
