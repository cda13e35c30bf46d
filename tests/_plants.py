"""Shared helpers of the plant tests: builders, trajectory recording, hypothesis strategies."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from frictiongym.friction import (
    ROTARY_LUGRE,
    ROTARY_PAPER,
    CoulombViscous,
    NoFriction,
    StictionCoulomb,
)
from frictiongym.friction.laws import FrictionModel
from frictiongym.plants import Plant, PlantParams

DT = 1e-3
SHAPES = ("step", "linear", "smooth", "exponential")
ASYM = dict(us_pos=0.5, us_neg=0.4, uc_pos=0.3, uc_neg=0.2, v0_pos=0.3, v0_neg=0.2)
ROTARY_J, ROTARY_B = 7.143e-3, 0.0446


def asym(shape: str = "linear", viscous: float = 0.0) -> StictionCoulomb:
    return StictionCoulomb(**ASYM, viscous=viscous, shape=shape)


def make(
    friction: FrictionModel | list[FrictionModel],
    inertia: float = 1.0,
    damping: float = 0.3,
    dt: float = DT,
    limit: float = 100.0,
    num_plants: int = 1,
    substeps: int | None = None,
    lag: float = 0.0,
    dead_time: float = 0.0,
    dead_zone: float = 0.0,
) -> Plant:
    params = PlantParams(inertia, damping, limit, lag=lag, dead_time=dead_time, dead_zone=dead_zone)
    return Plant(params, friction, dt, num_plants=num_plants, substeps=substeps)


@dataclass
class Traj:
    """Samples at the control instants: x, v, stuck have n + 1 rows, command/friction n."""

    x: np.ndarray
    v: np.ndarray
    stuck: np.ndarray
    command: np.ndarray
    friction: np.ndarray


def run(plant: Plant, n: int, commands: object = None, controller: object = None) -> Traj:
    """Step ``plant`` n times, open loop (commands[k], scalar or per plant) or with a controller."""
    m = plant.num_plants
    x, v = np.empty((n + 1, m)), np.empty((n + 1, m))
    stuck = np.empty((n + 1, m), dtype=bool)
    cmd, fr = np.empty((n, m)), np.empty((n, m))
    x[0], v[0], stuck[0] = plant.position, plant.velocity, plant.stuck
    for i in range(n):
        if controller is None:
            u = commands[i]
        else:
            u = controller(i * plant.dt, plant.position[0], plant.velocity[0])
        plant.step(u)
        x[i + 1], v[i + 1], stuck[i + 1] = plant.position, plant.velocity, plant.stuck
        cmd[i], fr[i] = plant.command, plant.friction_force
    return Traj(x, v, stuck, cmd, fr)


def rest_episodes(stuck: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample indices where a rest starts (moving -> stuck) and ends (stuck -> moving)."""
    d = np.diff(stuck.astype(int))
    return np.flatnonzero(d == 1) + 1, np.flatnonzero(d == -1) + 1


def energy_violation(
    tr: Traj, inertia: float, b_total: float, dt: float, tight: bool, plant: int = 0
) -> float:
    """Largest scaled violation of 0.5 J (v1^2 - v0^2) <= u dx - [B dx^2 / dt]."""
    x, v, u = tr.x[:, plant], tr.v[:, plant], tr.command[:, plant]
    dx = np.diff(x)
    de = 0.5 * inertia * (v[1:] ** 2 - v[:-1] ** 2)
    # dx comes from stored positions, each rounded to half its float64 spacing, so dx is only
    # known to within delta; propagate that through u*dx and B*dx^2/dt (|dx_true| <= |dx| +
    # delta). It matters only when a step moves the body by a few ulps of its position.
    delta = 0.5 * (np.spacing(np.abs(x[1:])) + np.spacing(np.abs(x[:-1])))
    rounding = np.abs(u) * delta
    if tight:
        rounding = rounding + b_total * (2.0 * np.abs(dx) + 3.0 * delta) * delta / dt
    lhs = de - u * dx + (b_total * dx * dx / dt if tight else 0.0) - rounding
    scale = 0.5 * inertia * (v[1:] ** 2 + v[:-1] ** 2) + np.abs(u * dx) + 1e-300
    return float(np.max(lhs / scale))


# == hypothesis properties ====================================================================
@st.composite
def static_laws(draw: st.DrawFn) -> StictionCoulomb:
    level = st.floats(0.0, 2.0, allow_subnormal=False)
    uc_pos, uc_neg = draw(level), draw(level)
    us_pos, us_neg = uc_pos + draw(level), uc_neg + draw(level)
    v0 = st.floats(1e-3, 5.0)
    return StictionCoulomb(
        us_pos,
        us_neg,
        uc_pos,
        uc_neg,
        draw(v0),
        draw(v0),
        viscous=draw(st.floats(0.0, 1.0, allow_subnormal=False)),
        shape=draw(st.sampled_from(SHAPES)),
    )


plant_params = st.builds(
    PlantParams,
    inertia=st.floats(1e-3, 10.0),
    damping=st.floats(0.0, 5.0, allow_subnormal=False),
    command_limit=st.floats(0.1, 10.0),
)
command_lists = st.lists(st.floats(-6.0, 6.0, allow_subnormal=False), min_size=1, max_size=120)
#: Example counts come from the hypothesis profile chosen in conftest.py.
PROPERTY_SETTINGS = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])


def open_loop_commands(n: int, seed: int, us_pos: float, us_neg: float) -> np.ndarray:
    """Alternate pushes beyond break-away (random sign) with opposing holds inside the band."""
    rng = np.random.default_rng(seed)
    parts = []
    while sum(len(p) for p in parts) < n:
        sign = rng.choice([-1.0, 1.0])
        push = sign * rng.uniform(1.1, 1.8) * (us_pos if sign > 0 else us_neg)
        hold = -sign * rng.uniform(0.0, 0.9) * (us_neg if sign > 0 else us_pos)
        parts += [np.full(rng.integers(20, 100), push), np.full(rng.integers(20, 150), hold)]
    return np.concatenate(parts)[:n]


BATCH_LAWS: list[FrictionModel] = [
    asym("step", 0.1),
    asym("linear"),
    asym("smooth", 0.2),
    asym("exponential"),
    CoulombViscous(0.3, 0.2, 0.05),
    NoFriction(),
    ROTARY_PAPER,
    ROTARY_LUGRE,
]
BATCH_PARAMS = [
    PlantParams(1.0, 0.3, 1.0),
    PlantParams(0.5, 0.0, 0.8),
    PlantParams(2.0, 0.7, 1.2, lag=0.004),
    PlantParams(1.0, 0.1, 1.0),
    PlantParams(0.3, 0.2, 1.0, lag=0.01),
    PlantParams(1.0, 0.5, 1.0),
    PlantParams(ROTARY_J, ROTARY_B, 10.0),
    PlantParams(ROTARY_J, ROTARY_B, 10.0),
]
