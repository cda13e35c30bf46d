"""The plant's rigid end stop (the Altino's wall): contact located inside the step, held, left."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym.friction import ALTINO_PAPER, NoFriction
from frictiongym.plants import Plant, PlantParams

CAR = PlantParams(inertia=2.2, damping=0.0, command_limit=1000.0, end_stop=0.0)


def test_frictionless_contact_lands_on_the_stop_inside_the_step() -> None:
    # From rest 1 cm before the stop under u = 1000: x(t) = -1 + u t^2 / (2 M) reaches the stop
    # at t_c = sqrt(2 M / u) = 66.3 ms, inside the second 50 ms step.
    plant = Plant(CAR, NoFriction(), 0.05)
    plant.reset(position=-1.0)
    plant.step(1000.0)
    assert plant.position[0] == pytest.approx(-1.0 + 1000.0 * 0.05**2 / 4.4, rel=1e-14)
    plant.step(1000.0)
    assert plant.position[0] == 0.0
    assert plant.velocity[0] == 0.0
    assert plant.stuck[0]
    for _ in range(5):  # pressed on the stop: it stays, bit for bit
        plant.step(1000.0)
        assert (plant.position[0], plant.velocity[0]) == (0.0, 0.0)


def _contact_time(u: float, x0: float) -> float:
    """Reference: integrate the paper's sliding law from rest to the stop with scipy.

    Two phases (the decay range, then the Coulomb range from ``v0``), so the integrator never
    steps across the law's kink.
    """
    f = ALTINO_PAPER
    slope = (f.us_pos - f.uc_pos) / f.v0_pos

    def decay(_t: float, y: np.ndarray) -> list[float]:
        return [y[1], (u - f.us_pos + slope * y[1] - f.viscous * y[1]) / CAR.inertia]

    def coulomb(_t: float, y: np.ndarray) -> list[float]:
        return [y[1], (u - f.uc_pos - f.viscous * y[1]) / CAR.inertia]

    def hit(_t: float, y: np.ndarray) -> float:
        return float(y[0])

    def leaves_decay(_t: float, y: np.ndarray) -> float:
        return float(y[1] - f.v0_pos)

    hit.terminal = True  # type: ignore[attr-defined]
    leaves_decay.terminal = True  # type: ignore[attr-defined]
    tol = {"rtol": 1e-12, "atol": 1e-14, "method": "DOP853"}
    first = solve_ivp(decay, (0.0, 5.0), [x0, 0.0], events=(hit, leaves_decay), **tol)
    if first.t_events[0].size:
        return float(first.t_events[0][0])
    t1, y1 = float(first.t_events[1][0]), first.y_events[1][0]
    second = solve_ivp(coulomb, (t1, t1 + 5.0), y1, events=hit, **tol)
    return float(second.t_events[0][0])


@pytest.mark.parametrize("u", [400.0, 1000.0])
def test_contact_time_matches_an_independent_integration(u: float) -> None:
    t_c = _contact_time(u, -2.0)
    for dt, reaches in ((t_c * (1.0 - 1e-7), False), (t_c * (1.0 + 1e-7), True)):
        plant = Plant(CAR, ALTINO_PAPER, dt)
        plant.reset(position=-2.0)
        plant.step(u)
        assert bool(plant.position[0] == 0.0) is reaches
        assert bool(plant.velocity[0] == 0.0) is reaches


def test_the_body_leaves_the_stop_only_when_pulled_beyond_breakaway() -> None:
    plant = Plant(CAR, ALTINO_PAPER, 0.05)
    plant.reset(position=-0.5)
    for _ in range(10):
        plant.step(600.0)
    assert plant.position[0] == 0.0
    # Pressed on: friction at its break-away level, the stop takes the rest.
    assert plant.friction_force[0] == pytest.approx(ALTINO_PAPER.us_pos, rel=1e-12)
    plant.step(-0.9 * ALTINO_PAPER.us_neg)  # inside the band: held by friction
    assert plant.position[0] == 0.0
    plant.step(-1.5 * ALTINO_PAPER.us_neg)
    assert plant.position[0] < 0.0
    assert plant.velocity[0] < 0.0


@pytest.mark.parametrize("shape", ["exponential", "smooth"])
def test_substepped_laws_stop_at_the_wall_too(shape: str) -> None:
    plant = Plant(CAR, ALTINO_PAPER.replace(shape=shape), 0.05)
    plant.reset(position=-3.0)
    positions = []
    for _ in range(20):
        plant.step(1000.0)
        positions.append(plant.position[0])
    assert max(positions) == 0.0
    assert positions[-1] == 0.0
    assert plant.velocity[0] == 0.0


def test_lugre_stops_at_the_wall() -> None:
    from frictiongym.friction import ALTINO_LUGRE

    plant = Plant(CAR, ALTINO_LUGRE, 0.05)
    plant.reset(position=-3.0)
    for _ in range(20):
        plant.step(1000.0)
        assert plant.position[0] <= 0.0
    assert plant.position[0] == 0.0


def test_contact_never_creates_energy() -> None:
    # Over the contact step the work of the input cannot exceed the kinetic energy gained.
    plant = Plant(CAR, NoFriction(), 0.05)
    plant.reset(position=-1.0)
    plant.step(1000.0)
    x0, v0 = plant.position[0], plant.velocity[0]
    plant.step(1000.0)
    work = 1000.0 * (plant.position[0] - x0)
    gained = 0.5 * CAR.inertia * (plant.velocity[0] ** 2 - v0**2)
    assert gained <= work


def test_reset_beyond_the_stop_is_refused() -> None:
    plant = Plant(CAR, NoFriction(), 0.05)
    with pytest.raises(ValueError, match="beyond the plant's end stop"):
        plant.reset(position=0.5)


def test_end_stop_must_be_a_position() -> None:
    with pytest.raises(ValueError, match="end_stop"):
        PlantParams(1.0, 0.0, 1.0, end_stop=math.nan)


@pytest.mark.parametrize("friction", ["paper", "none", "lugre", "stribeck"])
def test_altino_full_forward_ends_in_contact_at_zero_cm(friction: str) -> None:
    env = gym.make("frictiongym/AltinoDistance-v1", friction=friction)
    env.reset(seed=0)
    for _ in range(100):
        obs, reward, terminated, _, info = env.step(np.array([1000.0], np.float32))
        assert info["position"] >= 0.0
        if terminated:
            break
    assert terminated
    assert info["position"] == 0.0
    assert not math.copysign(1.0, info["position"]) < 0.0  # +0.0, not -0.0
    assert info["velocity"] == 0.0
    assert obs[0] == 800.0  # the IR's nearest reading
    # The terminal reward describes the contact: the whole target distance, full effort and
    # the limit penalty, then (v1) a worst whole episode of the registered 400 steps.
    rest = (40.0 / 5.0 + 0.01) * 400
    assert reward == pytest.approx(-(5.0 / 5.0 + 0.01 * 1.0 + 100.0 + rest), rel=1e-12)


def test_vector_env_contacts_like_the_single_env() -> None:
    vec = gym.make_vec(
        "frictiongym/AltinoDistance-v1", num_envs=3, vectorization_mode="vector_entry_point"
    )
    single = gym.make("frictiongym/AltinoDistance-v1")
    vec.reset(seed=0)
    single.reset(seed=0)
    for _ in range(30):
        _, _, terminated, _, info = vec.step(np.full((3, 1), 1000.0, np.float32))
        _, _, single_terminated, _, single_info = single.step(np.array([1000.0], np.float32))
        assert info["position"][0] == single_info["position"]
        if single_terminated:
            assert terminated.all()
            break
    assert single_terminated
