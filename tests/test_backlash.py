"""Backlash between motor and load: analytic oracles, conservation laws, batches, refusals.

The plant with play ``W`` is two bodies (docs/physics.md, "Backlash"). Oracles written here
without the kernel: the time the motor takes to cross the play at a known speed, the momentum
an inelastic impact keeps, the rest rules of an engaged pair, energy never created; and a
plant with no play is the rigid plant bit for bit. The independent reference solver's
comparison is in tests/test_backlash_reference.py.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from _backlash_reference import BacklashReference
from _plants import DT, asym, open_loop_commands
from _reference import PID

from frictiongym.friction import (
    ROTARY_LUGRE,
    ROTARY_PAPER,
    CoulombViscous,
    NoFriction,
    StictionCoulomb,
)
from frictiongym.plants import Plant, PlantParams
from frictiongym.plants._kernel import I_GAP, I_LOAD_FRICTION, I_LOAD_INERTIA


def pair(
    friction: object,
    backlash: float,
    load_inertia: float = 0.6,
    load_friction: float = 0.3,
    inertia: float = 1.0,
    damping: float = 0.0,
    num_plants: int = 1,
    parallel: bool | None = None,
) -> Plant:
    params = PlantParams(
        inertia,
        damping,
        100.0,
        backlash=backlash,
        load_inertia=load_inertia,
        load_friction=load_friction,
    )
    return Plant(params, friction, DT, num_plants=num_plants, parallel=parallel)


@pytest.mark.parametrize(("speed", "share"), [(1.5, 0.6), (-0.7, 0.25), (3.1, 0.9)])
def test_the_motor_crosses_the_play_in_its_width_over_its_speed(speed, share):
    width = 0.2
    plant = pair(NoFriction(), width, load_inertia=share)
    side = -1.0 if speed > 0 else 1.0  # start on the face it moves away from
    plant.gap[:] = side * width / 2
    plant.motor_velocity[:] = speed
    contact = width / abs(speed)
    n = int(contact / DT) + 40
    for k in range(1, n + 1):
        plant.step(0.0)
        t = k * DT
        if t < contact - 1e-12:  # the load rests; the motor coasts
            assert plant.position[0] == 0.0
            assert plant.gap[0] == pytest.approx(side * width / 2 + speed * t, abs=1e-12)
            assert plant.motor_velocity[0] == speed
        elif t > contact + 1e-12:  # engaged on the far face, at the momentum average
            common = (1.0 - share) * speed
            assert plant.gap[0] == -side * width / 2
            assert plant.velocity[0] == pytest.approx(common, rel=1e-13)
            assert plant.motor_velocity[0] == plant.velocity[0]
            assert plant.position[0] == pytest.approx(common * (t - contact), rel=1e-9, abs=1e-13)


def test_without_friction_momentum_is_kept_and_energy_only_lost():
    rng = np.random.default_rng(3)
    share, width = 0.35, 0.05
    plant = pair(NoFriction(), width, load_inertia=share, num_plants=64)
    plant.gap[:] = rng.uniform(-width / 2, width / 2, 64)
    plant.motor_velocity[:] = rng.normal(0.0, 1.0, 64)
    plant.velocity[:] = rng.normal(0.0, 1.0, 64)
    plant.state[6] = 0.0  # nothing is stuck

    def momentum() -> np.ndarray:
        return (1.0 - share) * plant.motor_velocity + share * plant.velocity

    def energy() -> np.ndarray:
        return 0.5 * ((1.0 - share) * plant.motor_velocity**2 + share * plant.velocity**2)

    p0, e0 = momentum(), energy()
    contacts = 0
    for _ in range(300):
        before = energy()
        plant.step(0.0)
        assert np.all(energy() <= before * (1.0 + 1e-14) + 1e-300)
        contacts += np.count_nonzero(np.abs(plant.gap) == width / 2)
    np.testing.assert_allclose(momentum(), p0, rtol=1e-13, atol=1e-15)
    assert contacts > 0
    assert np.all(energy() <= e0)
    assert np.any(energy() < 0.9 * e0)  # impacts took energy


def law() -> StictionCoulomb:
    return StictionCoulomb(0.5, 0.4, 0.3, 0.2, 0.3, 0.2, viscous=0.05, shape="linear")


@pytest.mark.parametrize("phi", [0.0, 0.3, 0.7, 1.0])
def test_an_engaged_pair_at_rest_obeys_the_rest_rules(phi):
    width, us_pos, us_neg = 0.1, 0.5, 0.4
    motor_neg = (1.0 - phi) * us_neg
    cases = {  # command: (the load moves, the motor moves)
        us_pos * 0.999: (False, False),
        us_pos * 1.001: (True, True),
        0.0: (False, False),
        -motor_neg * 0.999: (False, False),
        -motor_neg * 1.001 - 1e-9: (False, True),
        -us_neg * 1.5: (False, True),
    }
    for command, (load_moves, motor_moves) in cases.items():
        plant = pair(law(), width, load_friction=phi)
        plant.gap[:] = width / 2  # pressing on the face that drives the load forward
        plant.step(command)
        assert (plant.position[0] != 0.0) == load_moves, command
        assert (plant.gap[0] != width / 2 or plant.position[0] != 0.0) == motor_moves, command
        if load_moves:
            assert plant.gap[0] == width / 2
            assert plant.motor_velocity[0] == plant.velocity[0]


@pytest.mark.parametrize(("psi", "phi", "stays"), [(0.3, 0.7, True), (0.7, 0.3, False)])
def test_a_coasting_pair_separates_when_the_load_has_less_friction_than_inertia(psi, phi, stays):
    # F = psi u + (phi - psi) (f + b v): with u = 0 the motor pushes a load that brakes harder
    width = 0.1
    plant = pair(law(), width, load_inertia=psi, load_friction=phi, damping=0.1)
    plant.gap[:] = width / 2
    plant.velocity[:] = plant.motor_velocity[:] = 2.0
    plant.state[6] = 0.0
    plant.step(0.0)
    assert (plant.gap[0] == width / 2) == stays
    assert (plant.motor_velocity[0] == plant.velocity[0]) == stays


def test_energy_is_never_created():
    rng = np.random.default_rng(11)
    n, width = 2000, 0.02
    plant = pair(law(), width, damping=0.2, num_plants=8)
    shares = rng.uniform(0.1, 0.9, (2, 8))
    plant.own_rows()
    plant.rows[:, I_LOAD_INERTIA], plant.rows[:, I_LOAD_FRICTION] = shares
    commands = np.cumsum(rng.normal(0.0, 0.2, (n, 8)), axis=0)
    psi = shares[0]
    for k in range(n):
        e0 = 0.5 * ((1 - psi) * plant.motor_velocity**2 + psi * plant.velocity**2)
        xm0 = plant.position + plant.gap
        plant.step(commands[k])
        e1 = 0.5 * ((1 - psi) * plant.motor_velocity**2 + psi * plant.velocity**2)
        work = plant.command * (plant.position + plant.gap - xm0)
        assert np.all(e1 - e0 <= work + 1e-12 * (e0 + e1 + np.abs(work))), k


def test_no_play_is_the_rigid_plant_bit_for_bit():
    rng = np.random.default_rng(5)
    commands = np.cumsum(rng.normal(0.0, 0.15, (500, 16)), axis=0)
    rigid = Plant(PlantParams(1.0, 0.3, 100.0), ROTARY_PAPER, DT, num_plants=16)
    split = Plant(
        PlantParams(1.0, 0.3, 100.0, load_inertia=0.2, load_friction=0.9),
        ROTARY_PAPER,
        DT,
        num_plants=16,
    )
    for u in commands:
        rigid.step(u)
        split.step(u)
        np.testing.assert_array_equal(split.state, rigid.state)


@pytest.mark.parametrize("parallel", [False, True])
def test_a_batch_with_play_steps_each_plant_as_alone(parallel):
    rng = np.random.default_rng(2)
    m, n = 300, 300
    params = [
        PlantParams(
            rng.uniform(0.5, 2.0),
            rng.uniform(0.0, 0.5),
            3.0,
            backlash=rng.choice([0.0, rng.uniform(1e-3, 0.1)]),
            load_inertia=rng.uniform(0.05, 0.95),
            load_friction=rng.uniform(0.0, 1.0),
            lag=rng.choice([0.0, 0.005]),
        )
        for _ in range(m)
    ]
    laws = [rng.choice([law(), asym("step", 0.1), NoFriction(), ROTARY_PAPER]) for _ in range(m)]
    batch = Plant(params, laws, DT, num_plants=m, parallel=parallel)
    alone = [Plant(p, f, DT, substeps=batch.substeps) for p, f in zip(params, laws, strict=True)]
    commands = np.cumsum(rng.normal(0.0, 0.3, (n, m)), axis=0)
    for u in commands:
        batch.step(u)
        for i, plant in enumerate(alone):
            plant.step(u[i])
    for i, plant in enumerate(alone):
        np.testing.assert_array_equal(batch.state[:, i], plant.state[:, 0])
    assert np.any(np.abs(batch.gap) > 0.0)


def test_backlash_is_refused_where_the_step_is_not_exact_and_with_bad_shares():
    with pytest.raises(ValueError, match=r"backlash=0\.1 needs a friction law"):
        pair(ROTARY_LUGRE, 0.1)
    with pytest.raises(ValueError, match="needs a friction law"):
        pair(StictionCoulomb(0.5, 0.4, 0.3, 0.2, 0.3, 0.2, shape="smooth"), 0.1)
    for share in (0.0, 1.0, -0.1, math.nan):
        with pytest.raises(ValueError, match="load_inertia"):
            PlantParams(1.0, 0.0, 1.0, backlash=0.1, load_inertia=share)
    for share in (-0.1, 1.5, math.inf):
        with pytest.raises(ValueError, match="load_friction"):
            PlantParams(1.0, 0.0, 1.0, backlash=0.1, load_friction=share)
    with pytest.raises(ValueError, match="backlash"):
        PlantParams(1.0, 0.0, 1.0, backlash=-0.1)


# == against the independent reference solver (tests/_backlash_reference.py) ================
REFERENCE_CASES = [  # law, J, B, play, load's inertia share, load's friction share
    (law(), 1.0, 0.2, 0.02, 0.6, 0.3),
    (law(), 0.5, 0.0, 0.05, 0.3, 0.8),
    (asym("step", 0.1), 1.0, 0.3, 0.01, 0.8, 0.5),
    (asym("linear"), 1.2, 0.1, 0.02, 0.5, 0.5),
    (NoFriction(), 1.0, 0.1, 0.03, 0.4, 0.0),
]


def sine(t: float) -> float:
    return 0.3 * math.sin(2.0 * math.pi * 1.5 * t)


@pytest.mark.parametrize("case", range(len(REFERENCE_CASES)))
def test_a_pid_loop_through_the_play_matches_the_reference_solver(case):
    friction, inertia, damping, width, psi, phi = REFERENCE_CASES[case]
    n = 1500
    plant = pair(friction, width, psi, phi, inertia=inertia, damping=damping)
    reference = BacklashReference(inertia, damping, friction, DT, width, psi, phi)
    gains = {"kp": 8.0, "ki": 12.0, "kd": 0.6, "reference": sine, "dt": DT}
    want = reference.run(n, controller=PID(**gains))
    got = run_with(plant, n, PID(**gains))
    assert len(want.contacts) >= 4
    assert len(want.separations) >= 4
    np.testing.assert_allclose(got["x"], want.x, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(
        got["v"], want.v, rtol=0.0, atol=1e-9 * max(1.0, np.abs(want.v).max())
    )
    np.testing.assert_allclose(got["gap"], want.gap, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(got["friction"], want.friction, rtol=0.0, atol=1e-6)


@pytest.mark.parametrize("case", range(len(REFERENCE_CASES)))
def test_open_loop_pushes_and_holds_match_the_reference_solver(case):
    friction, inertia, damping, width, psi, phi = REFERENCE_CASES[case]
    n = 1500
    commands = open_loop_commands(n, case, 1.0, 0.8)
    plant = pair(friction, width, psi, phi, inertia=inertia, damping=damping)
    reference = BacklashReference(inertia, damping, friction, DT, width, psi, phi)
    want = reference.run(n, commands=commands)
    got = run_with(plant, n, None, commands)
    assert len(want.contacts) >= 3
    assert len(want.separations) >= 3
    np.testing.assert_allclose(got["x"], want.x, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(got["gap"], want.gap, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(got["motor_v"], want.motor_v, rtol=0.0, atol=1e-9)


def run_with(
    plant: Plant, n: int, controller: object, commands: np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """Step one plant n times; sample the load, the gap, the motor and the friction."""
    out = {name: np.empty(n + 1) for name in ("x", "v", "gap", "motor_v")}
    out["friction"] = np.empty(n)
    for k in range(n + 1):
        out["x"][k], out["v"][k] = plant.position[0], plant.velocity[0]
        out["gap"][k], out["motor_v"][k] = plant.gap[0], plant.motor_velocity[0]
        if k == n:
            break
        if controller is None:
            plant.step(commands[k])
        else:
            plant.step(controller(k * DT, plant.position[0], plant.velocity[0]))
        out["friction"][k] = plant.friction_force[0]
    return out


def test_a_pair_that_separates_inside_a_step_matches_the_reference_solver():
    # Braking (u < 0) an engaged pair whose load has more friction than inertia: the contact
    # force psi u + (phi - psi)(f + b v) falls with the speed and turns at v = 0.02, 0.162 s in.
    friction, inertia, damping, width, psi, phi = (
        CoulombViscous(0.2, 0.2),
        1.0,
        20.0,
        0.02,
        0.3,
        0.8,
    )
    n, commands = 300, np.full(300, -1.0)
    reference = BacklashReference(inertia, damping, friction, DT, width, psi, phi)
    want = reference.run(n, v0=2.0, gap0=width / 2, commands=commands)
    (t_sep,) = want.separations
    assert abs(t_sep / DT - round(t_sep / DT)) > 0.05  # inside a step
    plant = pair(friction, width, psi, phi, inertia=inertia, damping=damping)
    plant.reset(velocity=2.0)
    plant.gap[:] = width / 2
    got = run_with(plant, n, None, commands)
    assert got["gap"][-1] < width / 2  # the motor left the face
    for name in ("x", "v", "gap", "motor_v"):
        np.testing.assert_allclose(got[name], getattr(want, name), rtol=0.0, atol=1e-12)


# == the envs' backlash= argument ===========================================================
SERVO, ALTINO = "frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1"


@pytest.mark.parametrize(("env_id", "width"), [(SERVO, 0.05), (ALTINO, 2.0)])  # steps to cross
def test_the_envs_take_a_play_the_motor_crosses_before_the_load_moves(env_id, width):
    env = gym.make(env_id, backlash=width, delay=0.0)
    sim = env.unwrapped.sim
    assert sim.plant.backlash == width
    push = np.array([1.5 * max(sim.friction.breakaway)], np.float32)
    env.reset(seed=0)
    plants = sim.plants
    start, crossing = plants.position[0], 0
    while plants.gap[0] < width / 2:  # the motor crosses the play: the load stays put
        info = env.step(push)[4]
        crossing += 1
        assert crossing < 50
        if plants.gap[0] < width / 2:
            assert plants.position[0] == start
            assert info["velocity"] == 0.0
    assert crossing >= 2
    for _ in range(5):
        env.step(push)
    assert plants.gap[0] == width / 2  # engaged, pushing the load
    assert plants.velocity[0] > 0.0


@pytest.mark.parametrize("env_id", [SERVO, ALTINO])
def test_a_vector_env_with_random_play_steps_the_same_serial_and_threaded(env_id):
    runs = []
    for parallel in (False, True):
        env = gym.make_vec(
            env_id,
            num_envs=300,
            vectorization_mode="vector_entry_point",
            backlash=0.02 if env_id == SERVO else 0.3,
            randomize={"backlash": (0.5, 1.5), "friction": (0.8, 1.2)},
            parallel=parallel,
        )
        env.reset(seed=4)
        rng = np.random.default_rng(0)
        limit = env.single_action_space.high
        observations = [
            env.step(rng.uniform(-limit, limit, (300, 1)).astype(np.float32))[0] for _ in range(60)
        ]
        plays = env.unwrapped.sim.plants.rows[:, I_GAP]
        assert len(set(plays)) == 300
        runs.append((np.array(observations), env.unwrapped.sim.plants.state.copy()))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"backlash": -0.1}, "backlash must be >= 0"),
        ({"backlash": math.nan}, "backlash"),
        ({"backlash": 0.1, "friction": "lugre"}, "event-exact"),
        ({"backlash": 0.1, "friction": "stribeck"}, "event-exact"),
        ({"randomize": {"backlash": (0.5, 1.5)}}, "give the env backlash"),
    ],
)
def test_a_bad_backlash_argument_gets_a_message_that_names_it(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(SERVO, **kwargs)


def test_a_device_refuses_a_simulated_play():
    with pytest.raises(ValueError, match="backlash"):
        gym.make(SERVO, backend="emulator://rotary", log=False, backlash=0.05)


# == regressions found by an independent review ============================================
def servo_pair(width: float) -> Plant:
    params = PlantParams(
        7.143e-3, 0.0446, 10.0, backlash=width, load_inertia=0.8, load_friction=0.3
    )
    return Plant(params, ROTARY_PAPER, 0.002)


def test_a_separation_at_the_end_of_a_step_far_from_the_origin_keeps_the_gap_in_the_play():
    # (xl - x) rounds to the float spacing at x = 3 rad: the gap came out 1.8e-16 past the
    # face, no contact was found on it afterwards and the motor ran through the load
    width = 0.01
    plant = servo_pair(width)
    plant.reset(position=3.0, velocity=-0.3491257334865249)
    plant.gap[:] = width / 2  # engaged on face +1, moving back
    plant.step(-0.12092979014779326)  # separates just before the step ends
    for _ in range(4):
        plant.step(0.6)  # drives the motor back onto the face
        assert abs(plant.gap[0]) <= width / 2
    assert plant.gap[0] == width / 2
    assert plant.motor_velocity[0] == plant.velocity[0]


@pytest.mark.parametrize("width", [4e-6, 0.01])
def test_a_gap_that_leaves_a_face_by_less_than_its_rounding_finds_the_contact_again(width):
    plant = servo_pair(width)
    plant.reset(velocity=-1.5540495894463209)
    plant.gap[:] = width / 2
    plant.motor_velocity[:] = -1.5540495894463209 - 2.4e-10  # a hair faster away from the face
    for _ in range(3):
        plant.step(0.41)  # pulls the motor back onto it
        assert abs(plant.gap[0]) <= width / 2


def test_placing_a_pair_with_a_stop_halts_both_bodies():
    plant = pair(law(), 0.02)
    plant.velocity[:] = plant.motor_velocity[:] = 3.0
    plant.place(0.5, stop=True)
    assert plant.motor_velocity[0] == 0.0
    plant.step(0.0)
    assert plant.position[0] == 0.5
    assert plant.stuck[0]
