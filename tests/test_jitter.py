"""The drive's latency jitter: a new drive takes effect at a random instant inside the step.

Oracles: the switch instants recovered from a frictionless plant are uniform on
``[0, jitter]``; a jittered step is, bit for bit, the plant without jitter stepped under the
last drive up to the switch and under the new one for the rest; batches, threads and seeds
behave as everywhere else in the package.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from _plants import asym
from scipy import stats

from frictiongym.friction import ROTARY_PAPER, NoFriction
from frictiongym.plants import Plant, PlantParams
from frictiongym.plants import _batch as plant_batch
from frictiongym.plants import _kernel as plant_kernel

H = 0.01
ALTINO = "frictiongym/AltinoDistance-v1"


def test_the_switch_instants_are_uniform_up_to_the_jitter():
    n, late = 4000, 0.008
    plant = Plant(PlantParams(1.0, 0.0, 10.0, jitter=late), NoFriction(), H, num_plants=n)
    plant.step(np.zeros(n))
    plant.step(np.ones(n))  # from rest, no friction: v = (h - switch) exactly
    switch = H - plant.velocity
    np.testing.assert_allclose(plant.position, (H - switch) ** 2 / 2.0, rtol=1e-12)
    assert switch.min() >= 0.0
    assert switch.max() < late
    # Kolmogorov-Smirnov against U(0, late): the critical distance at the 1 % level is 1.63/sqrt(n)
    assert stats.kstest(switch / late, "uniform").statistic < 1.63 / math.sqrt(n)
    assert len(np.unique(switch)) == n  # a stream per plant


@pytest.mark.parametrize("friction", [asym("linear", 0.1), ROTARY_PAPER, NoFriction()])
def test_a_jittered_step_is_the_plain_plant_under_the_last_then_the_new_drive(friction):
    rng = np.random.default_rng(3)
    n, steps, late = 16, 150, 0.006
    jittered = Plant(PlantParams(1.0, 0.3, 5.0, jitter=late), friction, H, num_plants=n)
    plain = Plant(PlantParams(1.0, 0.3, 5.0), friction, H, num_plants=n)
    streams = np.arange(n, dtype=np.float64)  # Plant.reset seeds plant i with i
    drive, held = np.zeros(n), 0
    for u in 0.6 * np.sin(np.cumsum(rng.normal(0.0, 0.3, (steps, n)), axis=0)):
        jittered.step(u)
        u = np.clip(u, -5.0, 5.0)
        for i in range(n):
            streams[i], draw = plant_kernel.jitter_draw(streams[i])
            switch = late * draw
            for value, length in ((drive[i], switch), (u[i], H - switch)):
                if length > 0.0:
                    one = plain.state[:, i : i + 1].copy()
                    bad = plant_batch.step_batch(
                        one, plain.delay_buffer[:, :1], 0, np.array([value]), length, 1, plain.rows
                    )
                    assert bad == -1
                    plain.state[:, i] = one[:, 0]
        drive = u
        for column in ("position", "velocity", "stuck"):
            np.testing.assert_array_equal(getattr(jittered, column), getattr(plain, column))
        held += np.count_nonzero(jittered.stuck)
    assert held > 0 or isinstance(friction, NoFriction)  # stops and rests are crossed


@pytest.mark.parametrize("parallel", [False, True])
def test_a_batch_with_jitter_steps_each_plant_as_alone(parallel):
    rng = np.random.default_rng(8)
    m, n = 300, 150
    params = [
        PlantParams(
            1.0,
            0.2,
            3.0,
            jitter=rng.choice([0.0, rng.uniform(0.0, H)]),
            backlash=rng.choice([0.0, 0.01]),
        )
        for _ in range(m)
    ]
    batch = Plant(params, ROTARY_PAPER, H, num_plants=m, parallel=parallel)
    seeds = rng.integers(0, 2**52, m).astype(np.float64)
    batch.seed_jitter(seeds)
    alone = [Plant(p, ROTARY_PAPER, H) for p in params]
    for plant, seed in zip(alone, seeds, strict=True):
        plant.seed_jitter(seed)
    for u in np.cumsum(rng.normal(0.0, 0.3, (n, m)), axis=0):
        batch.step(u)
        for i, plant in enumerate(alone):
            plant.step(u[i])
    for i, plant in enumerate(alone):
        np.testing.assert_array_equal(batch.state[:, i], plant.state[:, 0])


def test_bad_jitter_is_refused_with_a_message():
    with pytest.raises(ValueError, match="jitter"):
        PlantParams(1.0, 0.0, 1.0, jitter=-0.001)
    with pytest.raises(ValueError, match="reaches the control period"):
        Plant(PlantParams(1.0, 0.0, 1.0, jitter=H), NoFriction(), H)
    plant = Plant(PlantParams(1.0, 0.0, 1.0, jitter=0.001), NoFriction(), H)
    for seed in (-1, 2.5, 2**53, "a", [1, 2]):
        with pytest.raises(ValueError, match="jitter seeds"):
            plant.seed_jitter(seed)


def test_only_plants_with_a_jitter_get_a_stream():
    params = [PlantParams(1.0, 0.0, 1.0), PlantParams(1.0, 0.0, 1.0, jitter=0.001)] * 2
    plant = Plant(params, NoFriction(), H, num_plants=4)
    np.testing.assert_array_equal(plant.state[plant_kernel.S_JITTER_RNG], [0.0, 1.0, 0.0, 3.0])


def altino_run(seed: int, **kwargs: object) -> np.ndarray:
    env = gym.make(ALTINO, jitter=0.03, **kwargs)
    env.reset(seed=seed)
    push = np.array([300.0], np.float32)
    return np.array([env.step(push)[4]["position"] for _ in range(30)])


def test_the_env_draws_its_jitter_from_its_seed():
    first, again, other = altino_run(0), altino_run(0), altino_run(1)
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)
    plain = gym.make(ALTINO)
    plain.reset(seed=0)
    push = np.array([300.0], np.float32)
    rigid = np.array([plain.step(push)[4]["position"] for _ in range(30)])
    assert np.all(30.0 - first[1:] < 30.0 - rigid[1:])  # each drive comes late: less travel


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"jitter": -0.01}, "jitter must be >= 0"),
        ({"jitter": 0.05}, "reaches the control period"),
        ({"jitter": 0.01, "backend": "emulator://altino", "log": False}, "jitter"),
    ],
)
def test_a_bad_jitter_argument_gets_a_message_that_names_it(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(ALTINO, **kwargs)


def test_a_vector_env_with_jitter_is_the_same_serial_and_threaded():
    runs = []
    for parallel in (False, True):
        env = gym.make_vec(
            ALTINO,
            num_envs=300,
            vectorization_mode="vector_entry_point",
            jitter=0.03,
            parallel=parallel,
        )
        env.reset(seed=2)
        positions = []
        for k in range(60):
            command = np.full((300, 1), 250.0 * math.sin(k / 5.0), np.float32)
            positions.append(env.step(command)[4]["position"].copy())
        runs.append(np.array(positions))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert np.std(runs[0][-1]) > 0.0  # the envs' streams differ
