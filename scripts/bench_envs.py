"""Benchmark: step time and throughput of frictiongym's Gymnasium envs against CartPole.

Two comparisons, each timed interleaved in one process against a gymnasium reference:

**Single env** (``gym.make``, the full wrapper stack ``TimeLimit(OrderEnforcing(
PassiveEnvChecker(env)))``). Each variant runs the loop a user writes::

    obs, reward, terminated, truncated, info = env.step(action)
    if terminated or truncated:
        env.reset()

so the time per step includes the wrappers, the ``info`` dict and the resets at episode ends
(counted in that branch, which costs nothing measurable). Variants:

* ``CartPole-v1`` (the reference), with random actions 0/1: it resets every ~22 steps;
* ``frictiongym/RotaryServo-v1`` and ``frictiongym/AltinoDistance-v1`` with default kwargs
  (paper friction, quantised sensors, full ``info``), with ``sensor_noise=True`` and with
  ``reference="random_steps"`` plus ``randomize={"friction": (0.5, 1.5), "inertia": (0.8,
  1.2)}`` (so each reset draws from the env's generator);
* as context, the servo and CartPole stepped through ``env.unwrapped`` (no wrappers; no
  ``TimeLimit``, so the servo's episode ends only if the disk drifts past its 4π guard),
  which shows the wrappers' share.

The figure is µs per step; the ratio is ours / CartPole in time per step (below 1 is faster
than CartPole; target <= 1).

**Vector env**, N = ``--num-envs`` (default 4 096): env-steps/s of
``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` stepped with
``env.step(actions)`` (autoreset ``NEXT_STEP``, nothing else in the loop) against gymnasium's
``CartPoleVectorEnv`` made the same way. Variants: both ids with default kwargs (numba's
threads for N >= 128, ``parallel=False`` forced for context, and for the servo the default
kernel restricted to one thread, ``numba.set_num_threads(1)`` around the run), and the servo
with ``sensor_noise=True`` and with ``random_steps`` plus ``randomize``. The ratio is ours /
CartPoleVectorEnv in env-steps/s (target >= 1.5).

**Actions** are pre-generated and cycled, so drawing them is not timed (``action_space.sample()``
costs 30+ µs for a Box). Per env an AR(1) command process around the friction break-away band:
servo std 0.2 V, correlation time 20 ms (band -0.19 … +0.21 V); Altino std 200 motor units,
correlation time 0.5 s (break-away ±200), zero mean, so the car, starting 30 cm from the wall,
wanders and only some episodes end at the wall. Single env: a list of 16 384 float32 arrays of
shape (1,), CartPole a list of random ints; vector env: a (256, N, 1) float32 table (CartPole:
(256, N) int64) whose rows are cycled. Each runner keeps its place in the cycle between calls.
Episode ends are reported: single env from the timed loops, vector env from an untimed run of
two episodes' length on a separate env with the same seed and actions (with the mean fraction of
stuck envs from ``info["stuck"]``).

**Timing** (helpers in ``_bench.py``): a burn-in run (which also loads or compiles numba's
kernels), a short run to calibrate each variant's turn to about 5 ms, then rounds in which each
variant runs one turn, in a new random order every round, for ``--repeats`` x ``--seconds`` s of
turns per variant (default 2.5 s: 500 rounds). Figures are medians over rounds with
[quartiles]; a ratio is the median of the per-round ratios to the reference timed in the same
round, a few ms apart: the machine's spells, which last seconds here (a slow second core, a
learner's bursts), fall on both alike, where rounds of 0.5 s each (before issue J's ninth
round) gave per-round ratios from 1.0 to 3.4 beside a learner. The threads part keeps rounds of
``--seconds`` each, in an order rotated every round. A summary prints the two headline ratios
(default kwargs) and whether each meets its target; the script only reports, it never fails on
a target.

Run ``python scripts/bench_envs.py --help`` for the options.
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

import _bench_autoreset
import _bench_kernel
import _bench_passes
import _load
import gymnasium as gym
import numba
import numpy as np
import numpy.typing as npt
from _bench import (
    Runner,
    cycled_runner,
    machine_line,
    measure_in_turns,
    paired_ratios,
    quartile_stats,
    run_parts,
    si,
    single_threaded,
    source_revision,
    thousands,
    turn_rounds,
)

import frictiongym  # noqa: F401  (registers the frictiongym ids)
from frictiongym.plants.threads import AdaptiveKernel

SERVO = "frictiongym/RotaryServo-v1"
ALTINO = "frictiongym/AltinoDistance-v1"
CARTPOLE = "CartPole-v1"
OURS = (SERVO, ALTINO)


@dataclass(frozen=True)
class Commands:
    """An AR(1) command process: standard deviation, correlation time (s) and env period (s)."""

    std: float
    tau: float
    dt: float
    unit: str


COMMANDS = {
    SERVO: Commands(std=0.2, tau=0.02, dt=0.002, unit="V"),
    ALTINO: Commands(std=200.0, tau=0.5, dt=0.05, unit="motor units"),
}
RANDOMIZE = {"friction": (0.5, 1.5), "inertia": (0.8, 1.2)}
SINGLE_ROWS = 16384  #: length of a single env's action list
VECTOR_ROWS = 256  #: rows of a vector env's action table
SINGLE_TARGET = 1.0  #: single env: time per step, ours / CartPole, at most
VECTOR_TARGET = 1.5  #: vector env: env-steps/s, ours / CartPoleVectorEnv, at least
DEFAULT = "default"
NO_WRAPPERS = "default, env.unwrapped (no wrappers)"
ONE_THREAD = "parallel, 1 thread"

#: Settings timed for each frictiongym id (single env) and for the servo (vector env).
SETTINGS: tuple[tuple[str, dict[str, Any]], ...] = (
    (DEFAULT, {}),
    ("sensor_noise=True", {"sensor_noise": True}),
    ("random_steps + randomize", {"reference": "random_steps", "randomize": RANDOMIZE}),
)


@dataclass
class Episodes:
    """Episode ends seen by a runner or by an untimed run."""

    ended: int = 0
    terminated: int = 0
    stuck: float | None = None  #: mean fraction of stuck envs (vector envs only)

    def note(self) -> str:
        """Like ``1234 ended, 25% terminated``."""
        if not self.ended:
            return "none ended"
        return f"{thousands(self.ended)} ended, {self.terminated / self.ended:.0%} terminated"


@dataclass
class Variant:
    """One timed configuration: env id, setting, runner, batch size and what it measured."""

    env: str
    setting: str
    run: Runner
    batch: int
    kernel: str = "-"
    episodes: Episodes = field(default_factory=Episodes)
    rates: list[float] = field(default_factory=list)
    adaptive: AdaptiveKernel | None = None  #: the vector env's kernel, if adaptive

    @property
    def name(self) -> str:
        """The id without the ``frictiongym/`` namespace."""
        return self.env.removeprefix("frictiongym/")


def ar1_table(rows: int, batch: int, commands: Commands, seed: int) -> npt.NDArray[np.float32]:
    """``rows`` steps of ``batch`` independent stationary AR(1) processes, float32 (rows, batch)."""
    rng = np.random.default_rng(seed)
    a = math.exp(-commands.dt / commands.tau)
    b = math.sqrt(1.0 - a * a) * commands.std
    table = np.empty((rows, batch))
    table[0] = rng.normal(0.0, commands.std, batch)
    for t in range(1, rows):
        table[t] = a * table[t - 1] + b * rng.standard_normal(batch)
    return table.astype(np.float32)


def check_period(env_id: str, dt: float) -> None:
    """Stop if an env's period is not the one its AR(1) commands were scaled to."""
    if not math.isclose(dt, COMMANDS[env_id].dt):
        raise SystemExit(
            f"error: {env_id} has dt = {dt} s but the benchmark's commands assume "
            f"{COMMANDS[env_id].dt} s; update COMMANDS in scripts/bench_envs.py"
        )


def single_actions(env_id: str, seed: int) -> list[Any]:
    """Pre-generated actions of a single env: float32 arrays of shape (1,) or CartPole ints."""
    if env_id == CARTPOLE:
        return [int(a) for a in np.random.default_rng(seed).integers(0, 2, SINGLE_ROWS)]
    return list(ar1_table(SINGLE_ROWS, 1, COMMANDS[env_id], seed))


def vector_actions(env_id: str, num_envs: int, seed: int) -> list[npt.NDArray[Any]]:
    """Pre-generated action rows of a vector env: (N, 1) float32, or (N,) int64 for CartPole."""
    if env_id == CARTPOLE:
        return list(np.random.default_rng(seed).integers(0, 2, size=(VECTOR_ROWS, num_envs)))
    return list(ar1_table(VECTOR_ROWS, num_envs, COMMANDS[env_id], seed)[:, :, None])


def single_variant(
    env_id: str, setting: str, kwargs: dict[str, Any], seed: int, unwrapped: bool = False
) -> Variant:
    """A ``gym.make`` env (or its unwrapped env) run by the user's loop, counting episode ends."""
    env: Any = gym.make(env_id, **kwargs)
    if env_id in COMMANDS:
        check_period(env_id, env.unwrapped.dt)
    if unwrapped:
        env = env.unwrapped
    env.reset(seed=seed)
    actions = cycle(single_actions(env_id, seed))
    episodes = Episodes()

    def run(steps: int) -> None:
        for action in islice(actions, steps):
            _obs, _reward, terminated, truncated, _info = env.step(action)
            if terminated or truncated:
                episodes.ended += 1
                episodes.terminated += terminated
                env.reset()

    return Variant(env_id, setting, run, 1, episodes=episodes)


def make_vector(env_id: str, num_envs: int, kwargs: dict[str, Any], seed: int) -> Any:
    """``gym.make_vec`` with the native vector env, reset with ``seed``."""
    env = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs)
    env.reset(seed=seed)
    return env


def loads_runner(seed: int) -> Any:
    """``make_runner`` of the loads part: a default vector env's runner and adaptive kernel."""

    def make(env_id: str, num_envs: int) -> tuple[Runner, AdaptiveKernel | None]:
        variant = vector_variant(env_id, DEFAULT, {}, num_envs, seed)
        return variant.run, variant.adaptive

    return make


def kernel_of(env: Any) -> str:
    """``adaptive``, ``parallel`` or ``serial`` for a frictiongym vector env, ``-`` otherwise."""
    sim = getattr(env, "sim", None)
    if sim is None:
        return "-"
    if isinstance(sim.plants._step_kernel, AdaptiveKernel):
        return "adaptive"
    return "parallel" if sim.plants.parallel else "serial"


def vector_variant(
    env_id: str,
    setting: str,
    kwargs: dict[str, Any],
    num_envs: int,
    seed: int,
    one_thread: bool = False,
) -> Variant:
    """A native vector env stepped with cycled pre-generated actions (nothing else timed)."""
    env = make_vector(env_id, num_envs, kwargs, seed)
    run = cycled_runner(env, vector_actions(env_id, num_envs, seed))
    kernel = kernel_of(env)
    if "parallel" in kwargs:
        kernel += " (forced)"
    elif kernel != "-":
        kernel += " (default)"
    if one_thread:
        run, kernel = single_threaded(run), ONE_THREAD
    adaptive = env.unwrapped.sim.plants._step_kernel if kernel.startswith("adaptive") else None
    return Variant(env_id, setting, run, num_envs, kernel, adaptive=adaptive)


def episode_mix(
    env_id: str, kwargs: dict[str, Any], num_envs: int, seed: int, steps: int
) -> Episodes:
    """Episode ends and mean stuck fraction of a vector variant over ``steps`` untimed steps.

    Uses a separate env with the variant's seed and actions, so it sees the same episodes as
    the timed env's first ``steps`` steps.
    """
    env = make_vector(env_id, num_envs, kwargs, seed)
    rows = vector_actions(env_id, num_envs, seed)
    episodes = Episodes()
    stuck = 0.0
    for actions in islice(cycle(rows), steps):
        _, _, terminated, truncated, info = env.step(actions)
        episodes.ended += int(np.count_nonzero(terminated | truncated))
        episodes.terminated += int(np.count_nonzero(terminated))
        if "stuck" in info:
            stuck += float(np.mean(info["stuck"]))
    if env_id != CARTPOLE:
        episodes.stuck = stuck / steps
    env.close()
    return episodes


def episode_steps(env_id: str) -> int:
    """Registered episode length of an id."""
    steps = gym.spec(env_id).max_episode_steps
    return int(steps) if steps else 500


def first_calls(num_envs: int, seed: int) -> tuple[float, float]:
    """Wall time of the first single servo make/reset/step and of the first vector one, s.

    The first includes importing the env modules and loading (or compiling) the serial env
    kernel, the second the parallel kernel and numba's thread pool when N >= 128.
    """
    start = time.perf_counter()
    env = gym.make(SERVO)
    env.reset(seed=seed)
    env.step(np.zeros(1, dtype=np.float32))
    single = time.perf_counter() - start
    start = time.perf_counter()
    vec = make_vector(SERVO, num_envs, {}, seed)
    vec.step(np.zeros((num_envs, 1), dtype=np.float32))
    return single, time.perf_counter() - start


def find(variants: Sequence[Variant], env_id: str, setting: str = DEFAULT) -> Variant:
    """The variant of ``env_id`` with ``setting`` (on the default kernel for vector envs)."""
    for v in variants:
        default_kernel = "forced" not in v.kernel and v.kernel != ONE_THREAD
        if v.env == env_id and v.setting == setting and default_kernel:
            return v
    raise LookupError(f"no variant {env_id} {setting}")


def single_ratios(variant: Variant, ref: Variant) -> list[float]:
    """Per-round time per step of ``variant`` over the reference's (ours / CartPole)."""
    return paired_ratios(ref, variant)


def headlines(
    single: Sequence[Variant], vector: Sequence[Variant]
) -> list[tuple[str, str, list[tuple[str, list[float], bool]]]]:
    """The two headline comparisons: (what, target, [(env, per-round ratios, met)])."""
    out = []
    if single:
        rows = []
        for env_id in OURS:
            ratios = single_ratios(find(single, env_id), single[0])
            rows.append((env_id, ratios, statistics.median(ratios) <= SINGLE_TARGET))
        out.append(
            (
                "single env, time per step ours / CartPole-v1",
                f"<= {SINGLE_TARGET:g}",
                rows,
            )
        )
    if vector:
        rows = []
        for env_id in OURS:
            ratios = paired_ratios(find(vector, env_id), vector[0])
            rows.append((env_id, ratios, statistics.median(ratios) >= VECTOR_TARGET))
        out.append(
            (
                f"vector env N = {thousands(vector[0].batch)}, env-steps/s ours / "
                "CartPoleVectorEnv",
                f">= {VECTOR_TARGET:g}",
                rows,
            )
        )
    return out


def threads_runner(
    size: int, parallel: bool | None, policy: _load.TorchPolicy | None, seed: int = 0
) -> tuple[Runner, Any]:
    """The servo's vector env of ``size`` envs on ``parallel``, with ``policy`` after each step.

    Returns the runner and the env's kernel (an ``AdaptiveKernel`` on the default for large N).
    """
    kwargs = {} if parallel is None else {"parallel": parallel}
    env = make_vector(SERVO, size, kwargs, seed)
    rows = cycle(vector_actions(SERVO, size, seed))
    step = env.step

    def run(steps: int) -> None:
        if policy is None:
            for actions in islice(rows, steps):
                step(actions)
            return
        policy.hold_threads()
        for actions in islice(rows, steps):
            obs = step(actions)[0]
            policy(obs)

    return run, env.sim.plants._step_kernel


def build_parser() -> argparse.ArgumentParser:
    """Command-line options."""
    parser = argparse.ArgumentParser(
        prog="bench_envs.py",
        description=(
            "Step time of frictiongym's single envs (gym.make, full wrapper stack) against "
            "gym.make('CartPole-v1'), and env-steps/s of its native vector envs "
            "(gym.make_vec, vector_entry_point) against gymnasium's CartPoleVectorEnv, each "
            "timed interleaved with its reference in one process, with pre-generated AR(1) "
            "actions around the friction break-away band. Ratios to the reference are the "
            "meaningful figure: absolute rates drift by up to 1.5x between runs on the project "
            "machine. Targets (reported, never enforced): single env time per step <= 1.0x "
            "CartPole's, vector env throughput >= 1.5x CartPoleVectorEnv's."
        ),
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="the cartpole and loads parts run --repeats x --seconds s of turns of about 5 ms "
        "per variant; the threads part --repeats rounds of --seconds per variant; the autoreset "
        "part 300 x --repeats rounds of 40-step turns (default: 5; with --quick: 2)",
    )
    parser.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="see --repeats; for the threads part, the target wall time of one timed run of "
        "one variant, s, to which its step count is calibrated after warm-up (default: 0.5; "
        "with --quick: 0.05)",
    )
    parser.add_argument(
        "--num-envs",
        type=int,
        default=None,
        metavar="N",
        help="number of envs of the vector envs, frictiongym's and CartPoleVectorEnv "
        "(default: 4096; with --quick: 256)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="fast smoke run (--part cartpole: about 5 s with numba's cache warm, 15 s cold; the "
        "threads part, 2 sizes under 4 loads: up to a minute): smaller defaults for --repeats, "
        "--seconds, --num-envs and --thread-sizes (explicit values still win); the figures are "
        "then too noisy to quote",
    )
    parser.add_argument(
        "--markdown",
        action="store_true",
        help="also print the results as markdown (header lines and tables) ready for "
        "docs/benchmarks.md",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the pre-generated actions and of the envs' resets (default: 0)",
    )
    parser.add_argument(
        "--part",
        choices=("all", "cartpole", "threads", "loads", "split", "passes", "autoreset"),
        default="all",
        help="cartpole: the comparisons with CartPole; threads: the servo's vector env on the "
        "serial, default and threaded kernel under each --loads case; loads: the vector envs "
        "against CartPoleVectorEnv under each --loads case (quiet, busy, learner); split: "
        "where the time of a vector env-step goes, on one thread; passes: where its plant "
        "step goes, pass by pass (scripts/_bench_passes.py); autoreset: the vector "
        "envs' autoreset in the kernel against one before the call, in short turns "
        "(scripts/_bench_autoreset.py); all: every part (default)",
    )
    _load.add_arguments(parser, "envs")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the results; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    defaults = (2, 0.05, 256) if args.quick else (5, 0.5, 4096)
    if args.repeats is None:
        args.repeats = defaults[0]
    if args.seconds is None:
        args.seconds = defaults[1]
    if args.num_envs is None:
        args.num_envs = defaults[2]
    if args.repeats < 1 or args.seconds <= 0.0 or args.num_envs < 1:
        parser.error("repeats and num-envs must be positive and seconds > 0")
    shown_argv = sys.argv[1:] if argv is None else argv
    command = shlex.join(["python", "scripts/bench_envs.py", *shown_argv])
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    header = {
        "command": command,
        "date": now,
        "machine": machine_line(),
        "source": f"frictiongym {source_revision()}",
        "actions": "AR(1) per env; "
        + "; ".join(
            f"{env_id.removeprefix('frictiongym/')} std {c.std:g} {c.unit}, correlation time "
            f"{c.tau * 1e3:g} ms (dt {c.dt * 1e3:g} ms)"
            for env_id, c in COMMANDS.items()
        )
        + "; CartPole random 0/1",
    }
    for key, value in header.items():
        print(f"{key + ':':9s}{value}")

    if _load.needs_torch(args) and not _load.import_torch_first():
        parser.error("the learner and torch loads need torch; use --loads quiet busy")
    parts = {
        "cartpole": lambda: cartpole_part(args, header),
        "threads": lambda: threads_part(args),
        "loads": lambda: _bench_kernel.loads_part(args, OURS, loads_runner(args.seed)),
        "split": lambda: _bench_kernel.split_part(args, OURS, vector_actions),
        "passes": lambda: _bench_passes.passes_part(args, OURS, vector_actions),
        "autoreset": lambda: _bench_autoreset.autoreset_part(
            args, OURS, vector_actions, make_vector
        ),
    }
    return run_parts(
        [run for name, run in parts.items() if args.part in ("all", name)], args.markdown
    )


def threads_part(args: argparse.Namespace) -> str:
    """Time the servo's vector env on each kernel under each load; returns the markdown."""
    return _load.section(
        args,
        f"`{SERVO}` vector env (default kwargs, the actions above; the torch load feeds each "
        "step's observations to the MLP)",
        lambda size, parallel, policy: threads_runner(size, parallel, policy, args.seed),
        unit="env-steps",
        features=3,
        burn_in=VECTOR_ROWS,
    )


def cartpole_part(args: argparse.Namespace, header: dict[str, str]) -> str:
    """The single and vector comparisons with CartPole; returns the markdown."""
    n = args.num_envs
    single_first, vector_first = first_calls(n, args.seed)
    print(
        f"first servo gym.make + reset + step in this process (env modules, numba compile or "
        f"cache load): {single_first:.3f} s; first make_vec + step at N = {n}: "
        f"{vector_first:.3f} s; threading layer {numba.threading_layer()}, "
        f"{numba.get_num_threads()} threads"
    )

    single = [single_variant(CARTPOLE, DEFAULT, {}, args.seed)]
    for env_id in OURS:
        for setting, kwargs in SETTINGS:
            single.append(single_variant(env_id, setting, kwargs, args.seed))
    single.append(single_variant(SERVO, NO_WRAPPERS, {}, args.seed, unwrapped=True))
    single.append(single_variant(CARTPOLE, "env.unwrapped (no wrappers)", {}, args.seed, True))
    seconds = args.repeats * args.seconds  # of turns, per variant
    rounds = turn_rounds(seconds)
    measure_in_turns(single, seconds, burn_in=1000)
    ref = single[0]
    print(
        f"\nsingle env, gym.make (µs per step, median [quartiles] of {rounds} rounds; "
        "ratio = ours / CartPole-v1 in time per step)"
    )
    for variant in single:
        line = (
            f"  {variant.name:18s} {variant.setting:37s} {us_stats(variant.rates):24s}"
            f"{'  x CartPole ' + quartile_stats(single_ratios(variant, ref)):34s}"
            f"  episodes: {variant.episodes.note()}"
        )
        print(line)

    vector = [vector_variant(CARTPOLE, "gymnasium CartPoleVectorEnv", {}, n, args.seed)]
    mix_settings: list[tuple[Variant, str, dict[str, Any]]] = []
    for env_id in OURS:
        vector.append(vector_variant(env_id, DEFAULT, {}, n, args.seed))
        mix_settings.append((vector[-1], env_id, {}))
        default_kernel = vector[-1].kernel
        vector.append(vector_variant(env_id, "parallel=False", {"parallel": False}, n, args.seed))
        if env_id == SERVO and not default_kernel.startswith("serial"):
            if numba.get_num_threads() > 1:
                vector.append(vector_variant(env_id, DEFAULT, {}, n, args.seed, one_thread=True))
        if env_id == SERVO:
            for setting, kwargs in SETTINGS[1:]:
                vector.append(vector_variant(env_id, setting, kwargs, n, args.seed))
                mix_settings.append((vector[-1], env_id, kwargs))
    mix_settings.append((vector[0], CARTPOLE, {}))
    for variant, env_id, kwargs in mix_settings:  # untimed: episode ends and stuck fraction
        variant.episodes = episode_mix(env_id, kwargs, n, args.seed, 2 * episode_steps(env_id))
    for variant in vector:  # the kernel duplicates share their default variant's episodes
        if variant.kernel.endswith("(forced)") or variant.kernel == ONE_THREAD:
            variant.episodes = find(vector, variant.env).episodes
    measure_in_turns(vector, seconds, burn_in=2 * VECTOR_ROWS)
    for variant in vector:  # how often the adaptive kernel ran its threads: a low figure is a
        if variant.adaptive is not None:  # machine whose second core was busy or slow then
            serial, threaded = variant.adaptive.calls
            variant.kernel += f", {threaded / max(serial + threaded, 1):.0%} threaded"
    ref = vector[0]
    print(
        f"\nvector env, N = {n}, gym.make_vec vector_entry_point (env-steps/s, median "
        f"[quartiles] of {rounds} rounds; ratio = ours / CartPoleVectorEnv)"
    )
    for variant in vector:
        ns = 1e9 / statistics.median(variant.rates)
        line = (
            f"  {variant.name:18s} {variant.setting:28s} {variant.kernel:21s} "
            f"{quartile_stats(variant.rates, si):24s} {ns:7.1f} ns/env-step"
            f"{'  x CartPole ' + quartile_stats(paired_ratios(variant, ref)):34s}"
            f"  {mix_note(variant.episodes)}"
        )
        print(line)

    heads = headlines(single, vector)
    print("\nsummary (targets of issue B; reported, not enforced):")
    for what, target, rows in heads:
        cells = "; ".join(
            f"{env_id.removeprefix('frictiongym/')} {quartile_stats(ratios)} "
            f"({'meets' if met else 'misses'} target)"
            for env_id, ratios, met in rows
        )
        print(f"  {what} (target {target}): {cells}")
    return markdown(header, single, vector, heads, rounds)


def us_stats(rates: Sequence[float]) -> str:
    """``median [quartiles]`` of the time per step, µs, from rates in steps/s."""
    return quartile_stats([1e6 / r for r in rates])


def mix_note(episodes: Episodes) -> str:
    """Episode ends (and stuck fraction) of an untimed vector run."""
    note = f"untimed: {episodes.note()}"
    if episodes.stuck is not None:
        note += f", stuck {episodes.stuck:.0%}"
    return note


def markdown(
    header: dict[str, str],
    single: Sequence[Variant],
    vector: Sequence[Variant],
    heads: Sequence[tuple[str, str, list[tuple[str, list[float], bool]]]],
    rounds: int,
) -> str:
    """Header lines and results as markdown."""
    lines = [f"- **{key.capitalize()}:** {value}" for key, value in header.items()]
    lines += [
        "",
        "Headline ratios (median [quartiles] of the per-round ratios; default kwargs):",
        "",
        "| comparison | target | " + " | ".join(f"`{e}`" for e in OURS) + " |",
        "|---|---|" + "---|" * len(OURS),
    ]
    for what, target, rows in heads:
        cells = [
            f"{quartile_stats(ratios)} ({'meets' if met else 'misses'})" for _, ratios, met in rows
        ]
        lines.append(f"| {what} | {target} | " + " | ".join(cells) + " |")
    ref = single[0]
    lines += [
        "",
        "Single env (`gym.make`; ratio = ours / CartPole-v1 in time per step):",
        "",
        f"| env | setting | µs per step, median [quartiles] of {rounds} | ratio to "
        "CartPole-v1, median [quartiles] | episodes ended in the runs | terminated |",
        "|---|---|---|---|---:|---:|",
    ]
    for v in single:
        ratio = "1 (reference)" if v is ref else quartile_stats(single_ratios(v, ref))
        ended = v.episodes.ended
        term = f"{v.episodes.terminated / ended:.0%}" if ended else "-"
        lines.append(
            f"| {v.name} | {v.setting} | {us_stats(v.rates)} | {ratio} | {thousands(ended)} | "
            f"{term} |"
        )
    ref = vector[0]
    lines += [
        "",
        f"Vector env (N = {thousands(ref.batch)}, `gym.make_vec(..., "
        'vectorization_mode="vector_entry_point")`; episodes and stuck fraction from an '
        "untimed run of two episodes' length):",
        "",
        f"| env | setting | kernel | env-steps/s, median [quartiles] of {rounds} | "
        "ns per env-step | ratio to CartPoleVectorEnv, median [quartiles] | episodes ended | "
        "terminated | stuck (mean) |",
        "|---|---|---|---|---:|---|---:|---:|---:|",
    ]
    for v in vector:
        ratio = "1 (reference)" if v is ref else quartile_stats(paired_ratios(v, ref))
        ns = 1e9 / statistics.median(v.rates)
        ended = v.episodes.ended
        term = f"{v.episodes.terminated / ended:.0%}" if ended else "-"
        stuck = "-" if v.episodes.stuck is None else f"{v.episodes.stuck:.0%}"
        lines.append(
            f"| {v.name} | {v.setting} | {v.kernel} | {quartile_stats(v.rates, si)} | {ns:.1f} | "
            f"{ratio} | "
            f"{thousands(ended)} | {term} | {stuck} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
