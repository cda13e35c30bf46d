"""The batch kernel's SIMD pass, its coefficient cache and the single env's bound step.

A batch steps most plants in a pass without branches and the rest (events, other laws) through
the element step; a plant alone always takes the element step. These tests hold them to the
same bits where each path is likely to differ: dead time, the end stop, per-plant rows, a stale
coefficient cache.
"""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.friction import ROTARY_LUGRE, ROTARY_PAPER, NoFriction, StictionCoulomb
from frictiongym.plants import Plant, PlantParams
from frictiongym.plants import _kernel as plant_kernel

DT = 0.002
SERVO = PlantParams(inertia=7.143e-3, damping=0.0446, command_limit=10.0)


def ar_commands(rng: np.random.Generator, steps: int, n: int, std: float) -> np.ndarray:
    """AR(1) commands around the break-away band, shape (steps, n)."""
    table = np.empty((steps, n))
    table[0] = rng.normal(0.0, std, n)
    for t in range(1, steps):
        table[t] = 0.9 * table[t - 1] + 0.44 * std * rng.standard_normal(n)
    return table


def test_batch_with_own_rows_stop_and_dead_time_equals_plants_alone() -> None:
    rng = np.random.default_rng(0)
    n = 300  # more than a block: a full block and a partial one
    params = [
        PlantParams(
            inertia=7.143e-3 * rng.uniform(0.5, 1.5),
            damping=0.0446 * rng.uniform(0.0, 2.0),
            command_limit=10.0,
            dead_time=2 * DT,
            end_stop=0.05,  # commands push many plants onto it
        )
        for _ in range(n)
    ]
    laws = [ROTARY_PAPER, ROTARY_PAPER.replace(shape="step"), NoFriction()] * (n // 3)
    batch = Plant(params, laws, DT, n, parallel=False)
    alone = [Plant(p, law, DT) for p, law in zip(params, laws, strict=True)]
    start = rng.uniform(-0.2, 0.0, n)
    batch.reset(position=start)
    for plant, x0 in zip(alone, start, strict=True):
        plant.reset(position=x0)
    pressed = 0
    for u in ar_commands(rng, 400, n, 0.3) + 0.05:
        batch.step(u)
        for i, plant in enumerate(alone):
            plant.step(u[i])
        pressed += int(np.count_nonzero(batch.position == 0.05))
    assert pressed > 1000, "the end stop was not exercised"
    together = np.stack([p.state[:, 0] for p in alone], axis=1)
    np.testing.assert_array_equal(batch.state, together)


def test_a_stale_coefficient_cache_changes_no_bit() -> None:
    rng = np.random.default_rng(1)
    n = 512
    law = StictionCoulomb(0.21, 0.19, 0.12, 0.1, 3.0, 2.5, 0.002, "linear")
    primed = Plant(SERVO, law, DT, n, parallel=False)
    unprimed = Plant(SERVO, law, DT, n, parallel=False)
    unprimed.rows[:, plant_kernel.K0 :] = np.nan  # no cache: every step computes E1, E2
    other_period = Plant(SERVO, law, DT, n, parallel=False)
    plant_kernel.prime_rows(other_period.rows, 2 * DT)  # a cache keyed for another period
    plants = (primed, unprimed, other_period)
    for u in ar_commands(rng, 300, n, 0.2):
        for plant in plants:
            plant.step(u)
    assert 0.2 < np.mean(primed.stuck) < 0.8  # a mix of held and sliding plants
    for plant in plants[1:]:
        np.testing.assert_array_equal(plant.state, primed.state)


@pytest.mark.parametrize("law", [ROTARY_PAPER, ROTARY_LUGRE], ids=["paper", "lugre"])
def test_threaded_blocks_equal_serial_and_alone(law: object) -> None:
    rng = np.random.default_rng(2)
    n = 700
    serial = Plant(SERVO, law, DT, n, parallel=False)
    threaded = Plant(SERVO, law, DT, n, parallel=True)
    alone = Plant(SERVO, law, DT, 1)
    for u in ar_commands(rng, 200, n, 0.2):
        serial.step(u)
        threaded.step(u)
        alone.step(u[n - 1])
    np.testing.assert_array_equal(threaded.state, serial.state)
    np.testing.assert_array_equal(alone.state[:, 0], serial.state[:, n - 1])


@pytest.mark.parametrize("env_id", ["frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1"])
def test_bound_single_env_steps_as_the_simulation_runs(env_id: str) -> None:
    bound = gym.make(env_id).unwrapped
    plain = gym.make(env_id).unwrapped
    bound.reset(seed=3)
    plain.reset(seed=3)
    rng = np.random.default_rng(3)
    scale = 0.3 if "Rotary" in env_id else 300.0
    for k in range(300):
        action = np.array([scale * rng.standard_normal()], np.float32)
        obs, reward, terminated, _, info = bound.step(action)
        plain._command[0] = action[0]  # what step does, through the unbound run
        plain.sim.run(plain._command, plain._fresh, plain._obs, plain._out, plain._flags)
        assert obs.tobytes() == plain._obs[0].tobytes()
        assert reward == plain._out[0, 0]
        if k == 150:  # a pickled env binds its own arrays, and goes on identically
            clone = pickle.loads(pickle.dumps(bound))
            assert clone.step(action)[0].tobytes() == bound.step(action)[0].tobytes()
            plain._command[0] = action[0]
            plain.sim.run(plain._command, plain._fresh, plain._obs, plain._out, plain._flags)
        if terminated:
            break
    assert info["time"] > 0.0


def test_a_non_finite_action_through_the_bound_step_changes_nothing() -> None:
    env = gym.make("frictiongym/RotaryServo-v1").unwrapped
    env.reset(seed=0)
    env.step(np.array([0.5], np.float32))
    before = env.sim.state.copy()
    with pytest.raises(ValueError, match="not a finite number"):
        env.step(np.array([np.nan], np.float32))
    np.testing.assert_array_equal(env.sim.state, before)


def test_contact_with_the_end_stop_inside_a_step_is_located_in_a_batch() -> None:
    # Frictionless bodies pushed onto the stop: the contact is the step's only event.
    n = 64
    params = PlantParams(inertia=7.143e-3, damping=0.0446, command_limit=10.0, end_stop=0.05)
    batch = Plant(params, NoFriction(), DT, n, parallel=False)
    alone = [Plant(params, NoFriction(), DT) for _ in range(n)]
    start = np.linspace(-0.3, 0.0, n)
    batch.reset(position=start)
    for plant, x0 in zip(alone, start, strict=True):
        plant.reset(position=x0)
    for _ in range(100):
        batch.step(np.full(n, 1.0))
        for plant in alone:
            plant.step(1.0)
    assert np.all(batch.position == 0.05)
    np.testing.assert_array_equal(batch.state, np.stack([p.state[:, 0] for p in alone], axis=1))


def test_held_plants_of_other_laws_in_a_batch_step_as_alone() -> None:
    # A body held at rest is finished by the SIMD pass only for the exact law without lag: a
    # lagged actuator's state moves, a LuGre body creeps (found by an independent review).
    from dataclasses import replace

    params = [SERVO, replace(SERVO, lag=0.05), SERVO]  # lag >= 4 dt: still one substep
    laws = [ROTARY_PAPER, ROTARY_PAPER, ROTARY_LUGRE]
    batch = Plant(params, laws, DT, 3, substeps=1, parallel=False)
    alone = [Plant(p, law, DT, substeps=1) for p, law in zip(params, laws, strict=True)]
    for k in range(300):
        u = 0.1 if k < 100 else 0.3  # 0.1 lies inside the break-away band
        batch.step(np.full(3, u))
        for plant in alone:
            plant.step(u)
    np.testing.assert_array_equal(batch.state, np.stack([p.state[:, 0] for p in alone], axis=1))


@pytest.mark.parametrize(
    ("dt", "damping", "end_stop", "bias", "decay_speed"),
    # the second: slow and damped, so that many stops need expm1 (left to the element step),
    # and pushed onto an end stop, so that many would come to rest beyond it; the third: a
    # narrow decay range, crossed in many steps
    [
        (DT, 0.0446, np.inf, 0.0, 3.0),
        (0.05, 0.3, 0.02, 0.1, 3.0),
        (DT, 0.0446, np.inf, 0.0, 0.05),
    ],
    ids=["servo-rate", "slow-damped-with-stop", "narrow-decay"],
)
def test_two_phase_steps_finished_in_simd_lanes_equal_plants_alone(
    dt: float, damping: float, end_stop: float, bias: float, decay_speed: float
) -> None:
    # Pass 1b finishes a step in which a body comes to rest and the command then holds it, or
    # crosses the edge of the decay range and slides on to the end of the step.
    rng = np.random.default_rng(4)
    n = 300
    law = StictionCoulomb(
        0.21, 0.19, 0.12, 0.1, decay_speed, 0.8 * decay_speed, 0.002, "linear"
    )  # asymmetric
    params = PlantParams(
        inertia=7.143e-3, damping=damping, command_limit=10.0, dead_time=dt, end_stop=end_stop
    )
    batch = Plant(params, law, dt, n, parallel=False)
    alone = [Plant(params, law, dt) for _ in range(n)]
    start = rng.uniform(-0.1, 0.0, n)
    batch.reset(position=start)
    for plant, x0 in zip(alone, start, strict=True):
        plant.reset(position=x0)
    stops = edges = 0
    for u in ar_commands(rng, 300, n, 0.25) + bias:
        moving, speed = batch.velocity != 0.0, np.abs(batch.velocity)
        batch.step(u)
        for i, plant in enumerate(alone):
            plant.step(u[i])
        stops += int(np.count_nonzero(moving & (batch.velocity == 0.0)))
        edges += int(
            np.count_nonzero((speed < decay_speed) != (np.abs(batch.velocity) < decay_speed))
        )
    assert stops > 1000, "too few stops to test the pass"
    assert decay_speed > 1.0 or edges > 1000, "too few crossings of the decay range's edge"
    together = np.stack([p.state[:, 0] for p in alone], axis=1)
    np.testing.assert_array_equal(batch.state, together)


def test_a_stop_beyond_the_end_stop_is_left_to_the_element_step() -> None:
    # Bodies sliding onto the stop, slowing under a command the friction holds: some would come
    # to rest beyond it, so the contact comes first (located by the element step).
    n = 64
    params = PlantParams(inertia=7.143e-3, damping=0.0446, command_limit=10.0, end_stop=0.0)
    batch = Plant(params, ROTARY_PAPER, DT, n, parallel=False)
    alone = [Plant(params, ROTARY_PAPER, DT) for _ in range(n)]
    start = -np.linspace(1e-6, 1e-4, n)
    batch.reset(position=start, velocity=0.05)
    for plant, x0 in zip(alone, start, strict=True):
        plant.reset(position=x0, velocity=0.05)
    batch.step(np.zeros(n))
    for plant in alone:
        plant.step(0.0)
    assert 0 < np.count_nonzero(batch.position == 0.0) < n  # contacts and stops short of it
    assert np.all(batch.velocity == 0.0)
    np.testing.assert_array_equal(batch.state, np.stack([p.state[:, 0] for p in alone], axis=1))
