"""The threading policy: which twin of a batched kernel runs, and that the choice changes nothing.

The adaptive policy is driven here by a fake clock, so every test is deterministic and none is
timed: each fake twin advances the clock by the cost the test gives it.
"""

from __future__ import annotations

import types
from typing import Any

import gymnasium as gym
import numba
import numpy as np
import pytest

from frictiongym.envs import _kernel as env_kernel
from frictiongym.friction import ROTARY_PAPER
from frictiongym.plants import Plant, PlantParams, threads
from frictiongym.plants import _batch as plant_batch
from frictiongym.plants.threads import PARALLEL_MIN_PLANTS, AdaptiveKernel, select_kernel
from tests._envs import IDS, RANDOM_KWARGS, commands

THREADS = numba.config.NUMBA_NUM_THREADS > 1
needs_threads = pytest.mark.skipif(not THREADS, reason="numba has one thread")
PARAMS = PlantParams(7.143e-3, 0.0446, 10.0)
US = 1e-6  #: a microsecond: fake call costs are of the size of real ones


class FakeClock:
    """A clock that only the fake kernels move."""

    def __init__(self) -> None:
        self.now = 0.0

    def perf_counter(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> FakeClock:
    fake = FakeClock()
    monkeypatch.setattr(threads, "time", types.SimpleNamespace(perf_counter=fake.perf_counter))
    return fake


class Twins:
    """Two fake kernels whose call costs (µs) a test can change as it runs."""

    def __init__(self, clock: FakeClock, serial: float, threaded: float) -> None:
        self.clock, self.cost = clock, [serial * US, threaded * US]
        self.spent = [0.0, 0.0]

    def twin(self, which: int):
        def kernel(*args: object) -> int:
            self.clock.now += self.cost[which]
            self.spent[which] += self.cost[which]
            return -1

        return kernel

    def adaptive(self) -> AdaptiveKernel:
        return AdaptiveKernel(self.twin(0), self.twin(1))


def run(kernel: AdaptiveKernel, calls: int) -> list[bool]:
    """Call ``kernel`` ``calls`` times; which calls ran threaded."""
    ran = []
    for _ in range(calls):
        ran.append(kernel.parallel)
        assert kernel() == -1
    return ran


def test_small_batches_and_one_thread_run_serially() -> None:
    serial, threaded = plant_batch.step_batch, plant_batch.step_batch_parallel
    assert select_kernel(serial, threaded, PARALLEL_MIN_PLANTS - 1, None) is serial
    assert select_kernel(serial, threaded, 1, None) is serial
    large = select_kernel(serial, threaded, PARALLEL_MIN_PLANTS, None)
    assert isinstance(large, AdaptiveKernel) if THREADS else large is serial


def test_parallel_true_or_false_forces_a_twin() -> None:
    serial, threaded = plant_batch.step_batch, plant_batch.step_batch_parallel
    for size in (1, PARALLEL_MIN_PLANTS, 65536):
        assert select_kernel(serial, threaded, size, True) is threaded
        assert select_kernel(serial, threaded, size, False) is serial
        assert select_kernel(serial, threaded, size, np.bool_(True)) is threaded
    with pytest.raises(TypeError, match="parallel must be True, False or None"):
        select_kernel(serial, threaded, 1, "yes")  # type: ignore[arg-type]


def test_plant_and_envs_take_their_kernel_from_the_policy() -> None:
    small = Plant(PARAMS, ROTARY_PAPER, 0.002, num_plants=PARALLEL_MIN_PLANTS - 1)
    large = Plant(PARAMS, ROTARY_PAPER, 0.002, num_plants=PARALLEL_MIN_PLANTS)
    assert small._step_kernel is plant_batch.step_batch
    assert not small.parallel
    assert isinstance(large._step_kernel, AdaptiveKernel) == THREADS
    forced = Plant(PARAMS, ROTARY_PAPER, 0.002, num_plants=PARALLEL_MIN_PLANTS, parallel=False)
    assert forced._step_kernel is plant_batch.step_batch
    assert not forced.parallel
    assert (
        Plant(PARAMS, ROTARY_PAPER, 0.002, parallel=True)._step_kernel
        is plant_batch.step_batch_parallel
    )
    vec = gym.make_vec(
        IDS[0], num_envs=PARALLEL_MIN_PLANTS, vectorization_mode="vector_entry_point"
    )
    assert isinstance(vec.unwrapped.sim.plants._step_kernel, AdaptiveKernel) == THREADS
    serial = gym.make_vec(IDS[0], 8, vectorization_mode="vector_entry_point", parallel=True)
    assert serial.unwrapped.sim.plants._step_kernel is env_kernel.step_envs_parallel


def test_the_faster_twin_runs_once_both_are_measured(clock: FakeClock) -> None:
    for serial, threaded, want in ((200.0, 110.0, True), (200.0, 400.0, False)):
        twins = Twins(clock, serial, threaded)
        kernel = twins.adaptive()
        ran = run(kernel, 2000)
        assert ran[:4] == [False] * 4  # first the serial twin: a warm-up and three measured
        assert ran[4] is True  # then the threaded one
        assert np.mean(ran[-1000:]) == pytest.approx(1.0 if want else 0.0, abs=0.02)


def test_a_slow_threaded_twin_costs_at_most_a_few_percent(clock: FakeClock) -> None:
    """Beside a learner the threaded twin can take 20 times as long: it is rarely retried."""
    twins = Twins(clock, serial=200.0, threaded=4000.0)
    kernel = twins.adaptive()
    run(kernel, 20)  # the first trials
    twins.spent = [0.0, 0.0]
    calls = 50000  # 10 s
    run(kernel, calls)
    assert sum(twins.spent) <= 1.03 * calls * 200.0 * US
    assert kernel.switches == 0


def test_it_follows_the_load_both_ways(clock: FakeClock) -> None:
    twins = Twins(clock, serial=200.0, threaded=120.0)
    kernel = twins.adaptive()
    assert np.mean(run(kernel, 500)[-200:]) > 0.95  # (serial trials now and then)
    twins.cost[1] = 2000.0 * US  # a learner starts: the threaded twin stalls
    ran = run(kernel, 5000)
    assert not any(ran[16:200])  # it left the threaded twin within two blocks
    assert np.mean(ran[16:]) < 0.01  # and retries it rarely
    twins.cost[1] = 120.0 * US  # the learner stops: back within MAX_WAIT of serial calls
    ran = run(kernel, int(threads.MAX_WAIT / (200.0 * US)) + 100)
    assert np.mean(ran[-200:]) > 0.95  # (serial trials now and then)


def test_a_lucky_trial_is_undone_after_one_slow_call(clock: FakeClock) -> None:
    twins = Twins(clock, serial=200.0, threaded=1000.0)
    kernel = twins.adaptive()
    run(kernel, 200)
    twins.cost[1] = 100.0 * US  # the next trial is lucky ...
    while not kernel.parallel:
        kernel()
    run(kernel, 1 + threads.TRIAL_CALLS)
    assert kernel.switches == 1
    twins.cost[1] = 1000.0 * US  # ... and the calls after it are not
    ran = run(kernel, 3)
    assert ran == [True, False, False]


def test_one_stalled_call_in_a_trial_hands_nothing_to_a_slower_twin(clock: FakeClock) -> None:
    """A trial's figure is its median call: one stall does not make its twin look slow.

    Beside a learner one serial call can stall for tens of ms (the main thread descheduled);
    taken into the serial trial's mean, such a stall handed the kernel to threads whose every
    call took 8 ms, for a second of calls (docs/benchmarks.md, "Eighth round").
    """
    twins = Twins(clock, serial=100.0, threaded=8000.0)
    kernel = twins.adaptive()
    kernel()  # the serial trial's warm-up
    twins.cost[0] = 40_000.0 * US  # its first measured call stalls
    kernel()
    twins.cost[0] = 100.0 * US
    ran = run(kernel, 2000)
    assert kernel.switches == 0
    assert sum(ran) <= 1 + threads.TRIAL_CALLS  # the threads' trial only


def test_a_stalled_call_in_a_trial_of_the_serial_twin_does_not_keep_the_threads(
    clock: FakeClock,
) -> None:
    """The threads in use, a trial of the serial twin ends only once its median cannot win."""
    twins = Twins(clock, serial=1000.0, threaded=100.0)
    kernel = twins.adaptive()
    run(kernel, 50)
    assert kernel.parallel
    twins.cost[1] = 8000.0 * US  # a learner starts: the threads stall ...
    while kernel.parallel:
        kernel()
    kernel()  # the serial trial's warm-up
    twins.cost[0] = 40_000.0 * US  # ... and so does the trial's first serial call
    kernel()
    twins.cost[0] = 1000.0 * US
    ran = run(kernel, 200)
    assert not any(ran[threads.TRIAL_CALLS :])  # the serial twin took over


def test_a_trial_of_the_threads_stops_at_its_first_call_too_slow_to_win(
    clock: FakeClock,
) -> None:
    twins = Twins(clock, serial=100.0, threaded=5000.0)
    kernel = twins.adaptive()
    ran = run(kernel, 1 + threads.TRIAL_CALLS + 3)
    assert ran == [False] * (1 + threads.TRIAL_CALLS) + [True, True, False]


@needs_threads
@pytest.mark.parametrize("env_id", IDS)
def test_switching_twins_mid_run_changes_no_trajectory(
    clock: FakeClock, env_id: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Switches every few calls (fake costs that flip) give the serial kernel's run."""
    monkeypatch.setattr(threads, "MAX_WAIT", 0.0)  # a trial every MIN_GAP calls
    n, steps = PARALLEL_MIN_PLANTS, 150
    kwargs = {"max_episode_steps": 40, **RANDOM_KWARGS}
    make = gym.make_vec
    reference = make(env_id, n, vectorization_mode="vector_entry_point", parallel=False, **kwargs)
    switching = make(env_id, n, vectorization_mode="vector_entry_point", **kwargs)
    sim = switching.unwrapped.sim
    cost = [100.0 * US, 200.0 * US]
    twins = (env_kernel.step_envs, env_kernel.step_envs_parallel)
    sim.plants._step_kernel = AdaptiveKernel(
        *(flipping(twin, i, cost, clock) for i, twin in enumerate(twins))
    )
    actions = commands(env_id, steps, shape=(n,), seed=3)
    obs_ref, _ = reference.reset(seed=4)
    obs, _ = switching.reset(seed=4)
    np.testing.assert_array_equal(obs, obs_ref)
    for t, a in enumerate(actions):
        if t % 25 == 0:  # the faster twin changes: the next trial switches
            cost.reverse()
        expected = reference.step(a)
        got = switching.step(a)
        for e, g in zip(expected[:4], got[:4], strict=True):
            np.testing.assert_array_equal(g, e)
    assert sim.plants._step_kernel.switches >= 3
    assert min(sim.plants._step_kernel.calls) >= 20


def flipping(twin, which: int, cost: list[float], clock: FakeClock):
    def kernel(*args: object) -> int:
        clock.now += cost[which]
        return twin(*args)

    return kernel


@needs_threads
def test_the_adaptive_plant_matches_the_serial_one(monkeypatch: pytest.MonkeyPatch) -> None:
    """The real clock: whatever the adaptive kernel picks, the states are the serial ones."""
    # Nothing learnt by earlier tests' batches (on a busy machine that can be "stay serial
    # for a while"), so this batch tries both twins from its first calls.
    monkeypatch.setattr(threads, "_LEARNT", {})
    n = PARALLEL_MIN_PLANTS
    u = np.random.default_rng(0).normal(0.0, 0.3, (300, n))
    adaptive = Plant(PARAMS, ROTARY_PAPER, 0.002, num_plants=n)
    serial = Plant(PARAMS, ROTARY_PAPER, 0.002, num_plants=n, parallel=False)
    for row in u:
        adaptive.step(row)
        serial.step(row)
    np.testing.assert_array_equal(adaptive.state, serial.state)
    assert min(adaptive._step_kernel.calls) >= 2  # both twins ran (the first trials at least)


def test_keep_drops_plants_and_the_others_go_on_exactly() -> None:
    """``Plant.keep`` (the tuner's early stop): per-plant laws, dead time, kernel carried over."""
    n = PARALLEL_MIN_PLANTS + 100
    rng = np.random.default_rng(1)
    params = [
        PlantParams(7.143e-3 * f, 0.0446, 10.0, dead_time=0.004) for f in rng.uniform(0.8, 1.2, n)
    ]
    laws = [ROTARY_PAPER.replace(shape=s) for s in ("linear", "exponential")] * (n // 2)
    u = rng.normal(0.0, 0.3, (150, n))
    full = Plant(params, laws, 0.002, num_plants=n)
    part = Plant(params, laws, 0.002, num_plants=n)
    kernel = part._step_kernel
    kept = np.arange(n)
    for t, row in enumerate(u):
        if t in (50, 100):
            mask = rng.random(kept.size) < (0.9 if t == 50 else 0.02)
            part.keep(mask)
            kept = kept[mask]
        full.step(row)
        part.step(row[kept])
        np.testing.assert_array_equal(part.state, full.state[:, kept])
        if t == 60:
            assert part._step_kernel is (kernel if THREADS else plant_batch.step_batch)
    assert part.num_plants == kept.size < PARALLEL_MIN_PLANTS
    assert part._step_kernel is plant_batch.step_batch
    assert not part.parallel
    assert part.params == [params[i] for i in kept]


def test_keep_rejects_a_wrong_mask() -> None:
    plant = Plant(PARAMS, ROTARY_PAPER, 0.002, num_plants=4)
    with pytest.raises(ValueError, match=r"mask must have shape \(4,\)"):
        plant.keep([True, False])
    with pytest.raises(ValueError, match="at least one plant"):
        plant.keep([False] * 4)


def test_the_tuners_result_does_not_depend_on_the_kernel() -> None:
    from frictiongym.tuning import StepSpecs, TuningModel, simulate

    specs = StepSpecs(rise_time=0.1, peak_time=0.3, settling_time=0.3, overshoot_pct=40.0)
    gains = np.random.default_rng(2).uniform((0.0, 0.0, 0.0), (20.0, 5.0, 1.0), (1500, 3))
    model = TuningModel.paper(with_friction=True)
    runs = [simulate(gains, model, specs, 0.6, parallel=p) for p in (False, None, True)]
    assert runs[0].feasible.any()
    for other in runs[1:]:
        np.testing.assert_array_equal(other.feasible, runs[0].feasible)
        np.testing.assert_array_equal(other.stopped_at, runs[0].stopped_at)
        np.testing.assert_array_equal(other.metrics.settling_time, runs[0].metrics.settling_time)


@pytest.mark.parametrize(
    ("serial", "threaded", "expected"), [(10.0, 200.0, False), (10.0, 5.0, True)]
)
def test_a_new_batch_starts_from_what_earlier_batches_learnt(
    clock: FakeClock, serial: float, threaded: float, expected: bool
) -> None:
    """A tuner's next chunk or a fresh vector env of the same kernels pays no trial at first."""
    twins = Twins(clock, serial, threaded)
    pair = (twins.twin(0), twins.twin(1))
    run(AdaptiveKernel(*pair, size=1000), 400)
    second = AdaptiveKernel(*pair, size=2000)  # twice the size: the learnt costs scale
    assert run(second, 20) == [expected] * 20
    assert second._mean[0] == pytest.approx(2.0 * serial * US, rel=0.3)
    # Without a size nothing is shared: the batch measures both twins first.
    fresh = run(AdaptiveKernel(*pair), 20)
    assert True in fresh
    assert False in fresh


def test_short_batches_in_a_row_still_try_the_threads_again(clock: FakeClock) -> None:
    """Batches too short to reach a trial alone share the time since the last one."""
    twins = Twins(clock, 10.0, 200.0)  # beside a learner: the threads lose
    pair = (twins.twin(0), twins.twin(1))
    for _ in range(20):
        run(AdaptiveKernel(*pair, size=1000), 30)
    twins.cost[1] = 5.0 * US  # the machine is idle again: the threads win
    ran = []
    for _ in range(300):
        ran += run(AdaptiveKernel(*pair, size=1000), 30)
    assert sum(ran[-3000:]) >= 0.95 * 3000  # on the threads again, but for short trials


def test_trials_that_keep_losing_back_off(clock: FakeClock) -> None:
    """A threaded twin that stalls badly (beside a learner) is retried ever more rarely."""
    twins = Twins(clock, 100.0, 20_000.0)  # each threaded call stalls 200 times longer
    kernel = twins.adaptive()
    run(kernel, 300_000)  # 30 s of serial calls
    assert twins.spent[1] <= 0.02 * twins.spent[0]
    assert kernel._wait == threads.MAX_BACKOFF


@pytest.mark.parametrize(
    "kernel", [plant_batch.step_batch, env_kernel.step_envs], ids=lambda k: k.__name__
)
def test_the_serial_kernels_never_enter_the_thread_pool(kernel: Any) -> None:
    """A serial kernel is compiled with ``parallel=True`` for numba's pipeline alone.

    An array expression in it (``np.zeros``) becomes a parallel loop that wakes the thread pool
    on every call: one plant stepped 18x slower with a core busy, and 3 700x slower beside a
    torch learner (docs/benchmarks.md). The cached kernels cannot be inspected, so a fresh copy
    of the source is compiled and its code searched for numba's scheduler.
    """
    # The first step of a plant and of an env compiles (or loads) each kernel's signature.
    Plant(PlantParams(inertia=1.0, damping=1.0, command_limit=1.0), ROTARY_PAPER, 0.002).step(0.0)
    env = gym.make("frictiongym/RotaryServo-v0")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    copy = numba.njit(parallel=True)(kernel.py_func)
    for signature in kernel.signatures:
        copy.compile(signature)
        assert "do_scheduling" not in copy.inspect_llvm(signature)
