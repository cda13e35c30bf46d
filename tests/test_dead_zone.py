"""The actuator's dead zone: the drive, the plant under it, the envs' ``deadzone=`` argument.

Oracles: a plant with a dead zone of half-width ``d`` is, bit for bit, the plant without one
driven by the dead zone's output (``0`` inside the band, ``u - d sign(u)`` outside); its
closed loop matches the independent reference solver; and analytic rest and steady states.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from _plants import DT, ROTARY_B, ROTARY_J, asym, make, run
from _reference import PID, ReferencePlant

from frictiongym.controllers import FrictionCompensator
from frictiongym.friction import ROTARY_PAPER, NoFriction
from frictiongym.identification.identify import identify, make_env
from frictiongym.plants import Plant, PlantParams
from frictiongym.plants._kernel import I_DEAD_ZONE, dead_zone

SERVO, ALTINO = "frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1"


def drive(command: float, width: float, limit: float) -> float:
    """The dead zone's output, written independently of the kernel (signed zero inside)."""
    u = min(max(command, -limit), limit)
    if abs(u) <= width:
        return math.copysign(0.0, u)
    return u - width if u > 0.0 else u + width


def test_without_a_dead_zone_the_drive_is_the_command_bit_for_bit():
    values = [0.0, -0.0, 5e-324, -5e-324, 1e-300, 0.3, -0.3, 10.0, -10.0, math.pi]
    for u in values:
        out = dead_zone(u, 0.0)
        assert out == u
        assert math.copysign(1.0, out) == math.copysign(1.0, u)


@pytest.mark.parametrize("width", [0.05, 0.3, 1.0])
def test_the_drive_is_zero_inside_the_band_and_shifted_outside(width):
    rng = np.random.default_rng(1)
    for u in [*rng.uniform(-3.0, 3.0, 500), width, -width, np.nextafter(width, 9.0)]:
        out = dead_zone(float(u), width)
        expected = drive(float(u), width, math.inf)
        assert out == expected
        assert math.copysign(1.0, out) == math.copysign(1.0, expected)


@pytest.mark.parametrize(
    "friction", [asym("linear", 0.2), asym("step"), ROTARY_PAPER, NoFriction()]
)
@pytest.mark.parametrize("dead_time", [0.0, 2 * DT])
def test_a_plant_with_a_dead_zone_is_the_plant_without_one_under_its_drive(friction, dead_time):
    width, limit, n = 0.35, 2.0, 600
    rng = np.random.default_rng(7)
    commands = np.cumsum(rng.normal(0.0, 0.15, (n, 40)), axis=0)  # in and out of the band
    commands[::37] = 0.2  # inside it, at rest and moving
    drives = np.vectorize(lambda c: drive(c, width, limit))(commands)
    delay = round(dead_time / DT)
    # the reference has no dead time of its own to apply the zone after: shift the drives
    shifted = np.vstack([np.zeros((delay, 40)), drives[: n - delay]]) if delay else drives
    for num_plants in (1, 40):  # the element step, and a batch (pass 1 in SIMD lanes)
        cols = slice(0, num_plants)
        zoned = make(
            friction, limit=limit, num_plants=num_plants, dead_time=dead_time, dead_zone=width
        )
        plain = make(friction, limit=limit, num_plants=num_plants)
        a = run(zoned, n, commands=commands[:, cols])
        b = run(plain, n, commands=shifted[:, cols])
        for got, want in ((a.x, b.x), (a.v, b.v), (a.stuck, b.stuck), (a.friction, b.friction)):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(a.command, np.clip(commands[:, cols], -limit, limit))
    assert np.any(np.abs(commands) < width)
    assert np.any(np.abs(commands) > width + 0.5)


def test_a_batch_with_its_own_rows_steps_each_plant_as_alone():
    widths = [0.0, 0.1, 0.4, 0.9]
    params = [PlantParams(ROTARY_J, ROTARY_B, 10.0, dead_zone=w) for w in widths]
    batch = Plant(params, ROTARY_PAPER, DT, num_plants=len(widths))
    alone = [Plant(p, ROTARY_PAPER, DT) for p in params]
    rng = np.random.default_rng(3)
    for _ in range(800):
        u = rng.normal(0.0, 1.0, len(widths))
        batch.step(u)
        for plant, command in zip(alone, u, strict=True):
            plant.step(command)
    for i, plant in enumerate(alone):
        assert batch.position[i] == plant.position[0]
        assert batch.velocity[i] == plant.velocity[0]


def test_closed_loop_with_a_dead_zone_matches_the_reference_solver():
    # PID on the servo's paper law: the dead zone widens the band where the loop rests
    width, n = 0.25, 4000
    gains = (40.0, 60.0, 0.4)
    reference = lambda t: 0.5 if (t % 1.0) < 0.5 else -0.3  # noqa: E731
    plant = make(ROTARY_PAPER, inertia=ROTARY_J, damping=ROTARY_B, limit=10.0, dead_zone=width)
    tr = run(plant, n, controller=PID(*gains, reference, DT))
    ref = ReferencePlant(ROTARY_J, ROTARY_B, ROTARY_PAPER, DT, command_limit=10.0, dead_zone=width)
    rr = ref.run(n, controller=PID(*gains, reference, DT))
    assert len(rr.stops) >= 4
    assert np.max(np.abs(tr.x[:, 0] - rr.x)) <= 1e-9
    assert np.max(np.abs(tr.v[:, 0] - rr.v)) <= 1e-9
    assert np.array_equal(tr.stuck[:, 0], rr.stuck)


def test_rest_and_steady_sliding_under_a_dead_zone():
    width, damping = 0.5, 0.25
    # at rest, a command inside the dead zone plus the break-away band moves nothing
    us_pos, _ = ROTARY_PAPER.breakaway
    held = make(ROTARY_PAPER, dead_zone=width)
    held.step(width + 0.999 * us_pos)
    assert held.velocity[0] == 0.0
    assert held.position[0] == 0.0
    # without friction a constant command settles at (u - d) / B
    u = 2.0
    free = make(NoFriction(), inertia=0.01, damping=damping, dead_zone=width)
    for _ in range(5000):
        free.step(u)
    assert free.velocity[0] == pytest.approx((u - width) / damping, rel=1e-12)
    # and a command inside the zone lets a moving body coast down as under no command
    coast, plain = (make(NoFriction(), damping=damping, dead_zone=w) for w in (width, 0.0))
    for p in (coast, plain):
        p.reset(velocity=1.0)
    for _ in range(300):
        coast.step(0.9 * width)
        plain.step(0.0)
    assert coast.velocity[0] == plain.velocity[0] > 0.0


def test_plant_params_refuse_a_bad_dead_zone():
    for bad in (-0.1, math.nan, math.inf):
        with pytest.raises(ValueError, match="dead_zone"):
            PlantParams(1.0, 0.1, 10.0, dead_zone=bad)
    with pytest.raises(ValueError, match="no command that drives"):
        PlantParams(1.0, 0.1, 10.0, dead_zone=10.0)


@pytest.mark.parametrize("env_id", [SERVO, ALTINO])
def test_the_envs_take_a_dead_zone_that_holds_small_commands(env_id):
    width = 1.5 * max(gym.make(env_id).unwrapped.sim.friction.breakaway)
    small = np.array([0.9 * width], np.float32)  # above the break-away level, inside the zone
    zoned, plain = gym.make(env_id, deadzone=width), gym.make(env_id)
    assert zoned.unwrapped.sim.plant.dead_zone == width
    moved = {}
    for name, env in (("zoned", zoned), ("plain", plain)):
        env.reset(seed=0)
        infos = [env.step(small)[4] for _ in range(10)]
        moved[name] = any(info["velocity"] != 0.0 for info in infos)
        assert infos[-1]["command"] == pytest.approx(small[0])  # the command sent, reported
    assert moved == {"zoned": False, "plain": True}


@pytest.mark.parametrize(
    ("value", "match"),
    [(-1.0, "deadzone"), (math.nan, "deadzone"), ("wide", "deadzone"), (10.0, "command limit")],
)
def test_a_bad_deadzone_argument_gets_a_message_that_names_it(value, match):
    with pytest.raises((ValueError, TypeError), match=match):
        gym.make(SERVO, deadzone=value)


def test_randomisation_scales_the_dead_zone_and_refuses_one_too_wide():
    env = gym.make_vec(
        SERVO,
        num_envs=64,
        vectorization_mode="vector_entry_point",
        deadzone=2.0,
        randomize={"deadzone": (0.5, 1.5)},
    )
    env.reset(seed=0)
    widths = env.unwrapped.sim.plants.rows[:, I_DEAD_ZONE]
    assert 1.0 <= widths.min() < widths.max() <= 3.0
    assert len(set(widths)) == 64
    with pytest.raises(ValueError, match="lower the upper factor"):
        gym.make(SERVO, deadzone=8.0, randomize={"deadzone": (0.5, 1.5)})


@pytest.mark.parametrize("env_id", [SERVO, ALTINO])
def test_a_compensator_that_models_the_dead_zone_drives_the_plant_as_without_one(env_id):
    # the zone's inverse, u + d sign(u), then the zone give u back (up to a rounding of
    # (|u| + d) - d), so the loop runs as the zone-free compensated loop
    width = max(gym.make(env_id).unwrapped.sim.friction.breakaway)
    runs = []
    for zone in (width, 0.0):
        env = gym.make(env_id, deadzone=zone)
        controller = FrictionCompensator.for_env(env, dead_zone=zone)
        obs, _ = env.reset(seed=0)
        controller.reset()
        positions = []
        for _ in range(300):
            obs, _, terminated, _, info = env.step(controller(obs))
            positions.append(info["position"])
            assert not terminated
        runs.append(np.array(positions))
    scale = np.max(np.abs(runs[1]))
    np.testing.assert_allclose(runs[0], runs[1], rtol=0.0, atol=1e-9 * scale)
    unmodelled = FrictionCompensator.for_env(gym.make(env_id, deadzone=width))
    assert unmodelled.dead_zone == 0.0  # nothing is assumed about the plant


def test_the_compensator_refuses_a_negative_dead_zone():
    env = gym.make(SERVO)
    with pytest.raises(ValueError, match="dead_zone"):
        FrictionCompensator.for_env(env, dead_zone=-0.1)


def test_identify_sees_a_dead_zone_as_friction_levels_raised_by_its_width():
    # ramps and constant levels drive in the direction of motion: there the zone's shift and
    # friction add, so every level grows by the zone's width; J, B and the decay speeds do not
    width = 0.105
    fitted = [
        identify(make_env(SERVO, deadzone=zone), seed=0, laws=("paper",)).fits["paper"].values
        for zone in (0.0, width)
    ]
    plain, zoned = fitted
    for key in ("us_pos", "us_neg", "uc_pos", "uc_neg"):
        assert zoned[key] - plain[key] == pytest.approx(width, abs=2e-3)
    for key in ("v0_pos", "v0_neg", "viscous"):
        assert zoned[key] == pytest.approx(plain[key], rel=1e-2)


def test_a_device_refuses_a_simulated_dead_zone():
    with pytest.raises(ValueError, match="deadzone"):
        gym.make(SERVO, backend="emulator://rotary", log=False, deadzone=0.5)


def test_randomising_a_dead_zone_the_plant_does_not_have_is_refused():
    with pytest.raises(ValueError, match="give the env deadzone"):
        gym.make(SERVO, randomize={"deadzone": (0.5, 1.5)})
