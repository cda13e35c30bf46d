"""The stick/slip step against closed forms, analytic oracles (docs/physics.md) and the reference.

Physics: ``J x'' + B x' = u - F(x', u)``, friction in command units, the command held over each
control period. The reference solver (``_reference.py``) is an independent event-located
``solve_ivp`` solution of the same ZOH problem.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from _plants import (
    DT,
    PROPERTY_SETTINGS,
    ROTARY_B,
    ROTARY_J,
    SHAPES,
    asym,
    command_lists,
    energy_violation,
    make,
    open_loop_commands,
    plant_params,
    rest_episodes,
    run,
    static_laws,
)
from _reference import PID, ReferencePlant
from hypothesis import given
from hypothesis import strategies as st

from frictiongym.friction import (
    ROTARY_PAPER,
    CoulombViscous,
    LuGre,
    NoFriction,
    StictionCoulomb,
)
from frictiongym.friction.laws import FrictionModel
from frictiongym.plants import Plant, PlantParams

# == O1: exact hold below break-away ==========================================================
HOLD_LAWS = [asym(s, viscous=0.2) for s in SHAPES] + [
    CoulombViscous(0.3, 0.2, 0.1),
    ROTARY_PAPER,
    NoFriction(),
]


HOLD_IDS = [*SHAPES, "coulomb", "rotary", "none"]


@pytest.mark.parametrize("friction", HOLD_LAWS, ids=HOLD_IDS)
def test_hold_below_breakaway_is_bit_exact(friction: FrictionModel) -> None:
    us_pos, us_neg = friction.breakaway
    rng = np.random.default_rng(0)
    inside = rng.uniform(-us_neg, us_pos, 10) if us_pos + us_neg > 0 else np.zeros(10)
    commands = np.concatenate([[us_pos, -us_neg, 0.0, -0.0], inside])
    # also a band-edge value that is one ulp inside
    commands = np.append(commands, np.nextafter(us_pos, -1.0) if us_pos > 0 else 0.0)
    n = len(commands)
    x0 = rng.uniform(-3, 3, n)
    plant = make(friction, num_plants=n)
    plant.reset(position=x0)
    for _ in range(3000):
        plant.step(commands)
        assert np.array_equal(plant.position, x0)
        assert np.all(plant.velocity == 0.0)
        assert np.all(plant.stuck)
        assert np.array_equal(plant.friction_force, commands)
        assert np.array_equal(plant.command, commands)


@pytest.mark.parametrize("shape", SHAPES)
def test_hold_under_a_varying_command_inside_the_band(shape: str) -> None:
    plant = make(asym(shape), substeps=7)
    plant.reset(position=0.25)
    u = 0.44 * np.sin(np.arange(5000) * 0.01) + 0.05  # within [-0.39, 0.49]
    tr = run(plant, len(u), commands=u)
    assert np.all(tr.x == 0.25)
    assert np.all(tr.v == 0.0)
    assert np.all(tr.stuck)
    assert np.array_equal(tr.friction[:, 0], u)


# == O2: ramp break-away =======================================================================
@pytest.mark.parametrize("shape", ["step", "linear", "smooth"])
@pytest.mark.parametrize("rho", [0.02, 0.3, 4.0, 50.0])
@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_ramp_breakaway_starts_at_first_step_above_us(
    shape: str, rho: float, direction: float
) -> None:
    friction = asym(shape)
    us = friction.us_pos if direction > 0 else friction.us_neg
    n = int(us / (rho * DT)) + 20
    u = direction * rho * (np.arange(n) * DT)
    first = int(np.flatnonzero(direction * u > us)[0])
    plant = make(friction)
    plant.reset(position=1.5)
    tr = run(plant, n, commands=u)
    # held through step first - 1 (the command of that step is <= us) ...
    assert np.all(tr.x[: first + 1, 0] == 1.5)
    assert np.all(tr.stuck[: first + 1, 0])
    assert np.array_equal(tr.friction[:first, 0], u[:first])
    # ... and moving after step `first`, in the direction of the command, never stopping
    assert np.all(~tr.stuck[first + 1 :, 0])
    assert np.all(direction * tr.v[first + 1 :, 0] > 0.0)
    assert np.all(direction * np.diff(tr.x[first:, 0]) > 0.0)


@pytest.mark.parametrize("shape", SHAPES)
def test_breakaway_threshold_is_strict(shape: str) -> None:
    friction = asym(shape)
    plant = make(friction, num_plants=4)
    u = np.array([0.5, np.nextafter(0.5, 1.0), -0.4, np.nextafter(-0.4, -1.0)])
    plant.step(u)
    assert plant.stuck.tolist() == [True, False, True, False]
    assert plant.velocity[1] > 0.0 > plant.velocity[3]


@pytest.mark.parametrize("shape", SHAPES)
def test_stop_with_the_command_on_the_band_edge_sticks(shape: str) -> None:
    # §4.2: at v = 0 the closed band [-us_neg, us_pos] holds; only beyond it does the body
    # reverse. Slide against a command exactly on the edge, and one ulp beyond it.
    friction = asym(shape)
    edge = np.array([0.5, np.nextafter(0.5, 1.0), -0.4, np.nextafter(-0.4, -1.0)])
    plant = make(friction, inertia=0.1, num_plants=4)
    plant.reset(velocity=np.where(edge > 0, -0.05, 0.05))
    for _ in range(100):
        plant.step(edge)
    assert plant.stuck.tolist() == [True, False, True, False]
    assert plant.velocity[1] > 0.0 > plant.velocity[3]


# == O3: coast-down ============================================================================
@dataclass
class Coast:
    inertia: float
    damping: float  # plant B
    viscous: float  # the law's slope (adds to B)
    uc: float
    v0: float

    def closed_form(self) -> tuple[float, float, Callable[[np.ndarray], np.ndarray]]:
        m, b = self.inertia, self.damping + self.viscous
        s, w = math.copysign(1.0, self.v0), abs(self.v0)
        if b == 0.0:
            t_stop, dist = m * w / self.uc, m * w * w / (2 * self.uc)

            def vel(t: np.ndarray) -> np.ndarray:
                return s * (w - self.uc / m * t)

        else:
            tau = m / b
            t_stop = tau * math.log1p(b * w / self.uc)
            dist = tau * (w - self.uc / b * math.log1p(b * w / self.uc))

            def vel(t: np.ndarray) -> np.ndarray:
                return s * ((w + self.uc / b) * np.exp(-t / tau) - self.uc / b)

        return t_stop, s * dist, vel


COASTS = [
    Coast(2.0, 0.7, 0.0, 0.3, 1.5),
    Coast(0.5, 0.0, 0.0, 0.23, 0.9),  # B = 0
    Coast(1.3, 0.25, 0.0, 0.17, -2.1),  # backwards, uses uc_neg
    Coast(2.0, 0.0, 0.7, 0.3, 1.5),  # all damping in the law's viscous slope
    Coast(ROTARY_J, ROTARY_B, 0.0, 0.124, 4.0),  # rotary servo coasting from 4 rad/s
]


@pytest.mark.parametrize("case", COASTS, ids=lambda c: f"J{c.inertia}-B{c.damping}-v{c.v0}")
def test_coast_down_stop_time_and_distance(case: Coast) -> None:
    s = 1.0 if case.v0 > 0 else -1.0
    uc_pos, uc_neg = (case.uc, 0.05) if s > 0 else (0.05, case.uc)
    friction = StictionCoulomb(
        uc_pos * 1.3, uc_neg * 1.3, uc_pos, uc_neg, 1.0, 1.0, viscous=case.viscous, shape="step"
    )
    t_stop, x_stop, vel = case.closed_form()
    n = int(t_stop / DT) + 2000
    plant = make(friction, inertia=case.inertia, damping=case.damping)
    plant.reset(position=0.0, velocity=case.v0)
    tr = run(plant, n, commands=np.zeros(n))
    k_stop = int(np.flatnonzero(tr.stuck[:, 0])[0])  # first sample at rest
    assert k_stop == math.floor(t_stop / DT) + 1
    t = np.arange(k_stop) * DT
    np.testing.assert_allclose(tr.v[:k_stop, 0], vel(t), rtol=0, atol=1e-9)
    assert abs(tr.x[k_stop, 0] - x_stop) <= 1e-9
    # stop instant inside the last moving step, from the step-average friction:
    # friction * dt = s uc (t_stop - t_k) + viscous * dx
    kk = k_stop - 1
    dx = tr.x[k_stop, 0] - tr.x[kk, 0]
    t_rec = kk * DT + (tr.friction[kk, 0] * DT - case.viscous * dx) / (s * case.uc)
    assert abs(t_rec - t_stop) <= 1e-9
    # and it stays stuck afterwards, bit-exactly
    assert np.all(tr.stuck[k_stop:, 0])
    assert np.all(tr.x[k_stop:, 0] == tr.x[k_stop, 0])
    assert np.all(tr.friction[k_stop:, 0] == 0.0)


# == O5: P-control turning points ==============================================================
def p_control_turning_points(dt: float) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """Kp = 10, uc = 1, us = 1.2, m = 1, B = 0, from rest at e0 = 1."""
    friction = StictionCoulomb(1.2, 1.2, 1.0, 1.0, 1.0, 1.0, shape="step")
    plant = make(friction, damping=0.0, dt=dt)
    n = int(6.5 / dt)
    tr = run(plant, n, controller=PID(10.0, reference=1.0, dt=dt))
    e, v = 1.0 - tr.x[:, 0], tr.v[:, 0]
    points, times = [], []
    for i in range(1, n):
        if v[i] != 0.0 and (v[i] * v[i + 1] < 0.0 or v[i + 1] == 0.0):  # reversal or stop
            j = i + 1 if v[i + 1] == 0.0 or abs(v[i + 1]) < abs(v[i]) else i
            points.append(e[j])
            times.append(j * dt)
    return np.array(points), np.array(times), e[-1], bool(tr.stuck[-1, 0])


def test_p_control_turning_points() -> None:
    expected = np.array([-0.8, 0.6, -0.4, 0.2, 0.0])
    half_period = math.pi * math.sqrt(1.0 / 10.0)
    errors = []
    for dt in (1e-3, 5e-4):
        points, times, e_end, stuck = p_control_turning_points(dt)
        assert len(points) == 5  # four reversals, then rest
        assert stuck
        assert e_end == points[-1]
        assert abs(e_end) * 10.0 <= 1.2
        err = np.abs(points - expected)
        assert np.all(err <= 8 * dt), (dt, points)
        assert np.all(np.abs(times - half_period * np.arange(1, 6)) <= 2 * dt)
        errors.append(err)
    # the ZOH error is first order in dt: it halves with dt
    np.testing.assert_allclose(errors[1] / errors[0], 0.5, atol=0.05)


# == O7: P/PD rest band ========================================================================
def test_pd_rest_states_lie_in_the_band() -> None:
    rng = np.random.default_rng(7)
    rests = 0
    for _ in range(24):
        ucp, ucn = rng.uniform(0.05, 1.0, 2)
        usp, usn = ucp * rng.uniform(1.0, 2.0), ucn * rng.uniform(1.0, 2.0)
        shape = str(rng.choice(SHAPES))
        friction = StictionCoulomb(
            usp, usn, ucp, ucn, *rng.uniform(0.05, 1.0, 2), viscous=0.0, shape=shape
        )
        kp, kd = rng.uniform(2.0, 40.0), rng.uniform(0.0, 3.0) * (rng.random() < 0.7)
        plant = make(friction, inertia=rng.uniform(0.2, 3.0), damping=rng.uniform(0.0, 1.0))
        ref = rng.uniform(-1.0, 1.0)
        ctrl = PID(kp, kd=kd, reference=ref)
        held = 0
        for i in range(40000):
            plant.step(ctrl(i * DT, plant.position[0], plant.velocity[0]))
            held = held + 1 if plant.stuck[0] else 0
            if held == 1000:
                break
        assert held == 1000, "these seeded loops all come to rest within 40 s"
        rests += 1
        e = ref - plant.position[0]
        u = kp * e  # the command the loop holds at rest (v = 0): exactly inside the band
        assert -usn <= u <= usp
        assert -usn / kp * (1 + 1e-12) <= e <= usp / kp * (1 + 1e-12)
    assert rests == 24


def test_every_point_of_the_band_is_an_equilibrium() -> None:
    kp, kd, ref = 12.0, 2.0, 1.0
    friction = asym("linear")  # band [-0.4, 0.5]
    x0 = ref - np.array([0.5 / kp, -0.4 / kp, 0.0, 0.013, -0.02, 0.0411, -0.0333])
    x0 = np.array([x for x in x0 if -0.4 <= kp * (ref - x) <= 0.5])  # as the loop computes it
    assert len(x0) >= 6
    plant = make(friction, num_plants=len(x0))
    plant.reset(position=x0)
    for _ in range(2000):
        plant.step(kp * (ref - plant.position) - kd * plant.velocity)
    assert np.array_equal(plant.position, x0)
    assert np.all(plant.stuck)


@pytest.mark.parametrize(("shape", "edge"), [("step", 0.3), ("linear", 0.5)])
def test_overdamped_pd_creeps_to_the_band_edge_without_stopping(shape: str, edge: float) -> None:
    # Monotone approach from rest (O7): e -> the first band edge the sliding curve meets
    # (u_c/Kp for the jump, u_s/Kp for a continuous decay), from outside, asymptotically:
    # the velocity decays exponentially and never reaches zero, so the body never sticks.
    kp, kd = 4.0, 8.0
    friction = StictionCoulomb(0.5, 0.5, 0.3, 0.3, 0.1, 0.1, shape=shape)
    plant = make(friction, damping=0.5)
    tr = run(plant, 20000, controller=PID(kp, kd=kd, reference=1.0))
    assert np.all(np.diff(tr.x[:, 0]) > 0.0)  # no overshoot, no stop
    assert not np.any(tr.stuck[1:, 0])
    e = 1.0 - tr.x[:, 0]
    assert np.all(e[-5000:] > edge / kp)
    # slowest mode: J l^2 + (Kd + B - k) l + Kp = 0, k the decay slope near rest
    k_slope = (0.5 - 0.3) / 0.1 if shape == "linear" else 0.0
    c = kd + 0.5 - k_slope
    rate = (c - math.sqrt(c * c - 4 * kp)) / 2
    gap = e[-5000:] - edge / kp
    observed = math.log(gap[-1] / gap[0]) / (4999 * DT)
    assert observed == pytest.approx(-rate, rel=0.01)


# == O9: hunting ==============================================================================
def hunting(us: float, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """The LuGre-paper loop with a static law; rest errors and break-away instants."""
    friction = StictionCoulomb(us, us, 1.0, 1.0, 1.0, 1.0, shape="step")
    plant = make(friction, damping=0.4)
    ctrl = BackwardPID(3.0, 4.0, 6.0, 1.0)
    n = int(seconds / DT)
    tr = run(plant, n, controller=ctrl)
    starts, ends = rest_episodes(tr.stuck[:, 0])
    return 1.0 - tr.x[starts, 0], ends * DT


@dataclass
class BackwardPID:
    """``u_k = Kp e_k + Ki I_k - Kd v_k``, ``I_k = I_{k-1} + e_k dt`` (the O9 discretisation)."""

    kp: float
    ki: float
    kd: float
    reference: float
    integral: float = 0.0

    def __call__(self, t: float, x: float, v: float) -> float:
        e = self.reference - x
        self.integral += e * DT
        return self.kp * e + self.ki * self.integral - self.kd * v


def test_hunting_limit_cycle_with_stiction() -> None:
    rest_errors, breakaways = hunting(us=1.5, seconds=150.0)
    settled = rest_errors[6:]
    intervals = np.diff(breakaways)[6:]
    assert len(settled) >= 5  # sustained: a rest every ~12 s, for ever
    assert np.all(np.sign(settled[1:]) == -np.sign(settled[:-1]))  # symmetric, alternating
    # Hunting oracle, 1 ms ZOH discrete PID: rest errors +-0.0656, 12.009 s apart
    np.testing.assert_allclose(np.abs(settled), 0.0656, rtol=0, atol=1e-4)
    np.testing.assert_allclose(intervals, 12.009, rtol=0, atol=4 * DT)  # ZOH jitter
    assert abs(np.mean(intervals) - 12.009) <= 1.5 * DT
    # continuous-time PID values (O9: +-0.06565, 12.0065 s) within the ZOH error
    np.testing.assert_allclose(np.abs(settled), 0.06565, rtol=0, atol=0.1 * DT)
    np.testing.assert_allclose(intervals, 12.0065, rtol=0, atol=6 * DT)
    assert abs(settled[-1]) > 0.99 * abs(settled[0])  # not decaying


def test_no_limit_cycle_when_us_equals_uc() -> None:
    rest_errors, breakaways = hunting(us=1.0, seconds=150.0)
    e = rest_errors[1:]  # after the first overshoot
    # Hunting oracle (1 ms ZOH): 0.229, -0.105, 0.048, -0.022, 0.010, -0.0046
    # (quoted to 3 decimals, the last to 2 significant digits: half a unit of the last digit)
    quoted = [0.229, -0.105, 0.048, -0.022, 0.010, -0.0046]
    assert np.all(np.abs(e[:6] - quoted) <= [5e-4] * 5 + [5e-5]), e[:6]
    ratios = e[1:] / e[:-1]
    np.testing.assert_allclose(ratios, -0.46, rtol=0, atol=0.005)
    stick = np.diff(breakaways)[2:]
    assert np.all(stick[1:] > 1.5 * stick[:-1])  # stick intervals roughly doubling


# == LuGre =====================================================================================
LUGRE_1995 = LuGre(1.5, 1.5, 1.0, 1.0, 1e-3, 1e-3, 1e5, math.sqrt(1e5), 0.4)  # m = 1 kg


def test_lugre_presliding_follows_the_quasi_static_oracle() -> None:
    # O13 / §2.2: loading slowly from z = 0 gives x(F) = -(Fs/sigma0) ln(1 - F/Fs); under a
    # 0.01 N/s ramp |v| exceeds v_s at F = 1.4985 N.
    rho = 0.01
    n = int(1.52 / rho / DT)
    u = rho * np.arange(n) * DT
    tr = run(make(LUGRE_1995, inertia=1.0, damping=0.0), n, commands=u)
    for force in (0.5, 1.0, 1.3, 1.45):
        i = round(force / rho / DT) + 1
        predicted = -(1.5 / 1e5) * math.log(1 - force / 1.5)
        assert tr.x[i, 0] == pytest.approx(predicted, rel=5e-4)
    first_fast = int(np.flatnonzero(np.abs(tr.v[:, 0]) > 1e-3)[0])
    assert u[first_fast - 1] == pytest.approx(1.4985, abs=5e-4)


@pytest.mark.parametrize("command", [1.2, 2.0, -3.0])
def test_lugre_steady_sliding_is_its_force_curve(command: float) -> None:
    plant = make(LUGRE_1995, inertia=1.0, damping=0.3)
    tr = run(plant, 40000, commands=np.full(40000, command))
    v = tr.v[-1, 0]
    assert float(LUGRE_1995.force(v)) + 0.3 * v == pytest.approx(command, rel=1e-9)
    assert plant.friction_force[0] == pytest.approx(float(LUGRE_1995.force(v)), rel=1e-9)


# == the kernel against the solve_ivp reference ===============================================
def schedule(levels: list[float], period: float) -> Callable[[float], float]:
    def r(t: float) -> float:
        return levels[int(t / period) % len(levels)]

    return r


@dataclass
class Scenario:
    name: str
    friction: FrictionModel
    inertia: float
    damping: float
    gains: tuple[float, float, float]
    reference: object
    steps: int
    min_rests: int  #: stick events (moving -> stuck) the run must contain


LW = StictionCoulomb(1.0, 0.8, 0.3, 0.25, 0.2, 0.15, 0.0, "linear")  # velocity-weakening
FAST_LEVELS = [0.0, 0.3, 0.27, -0.1, -0.12, 0.4, 0.1, 0.15, -0.3, -0.29, 0.0, 0.05]
FAST = schedule(FAST_LEVELS, 0.25)
ROTARY_REF = schedule([0.0, 0.3, 0.25, -0.2, -0.22, 0.5, 0.52, 0.4, 0.1, 0.12, -0.1, 0.0], 0.25)
SCENARIOS = [
    Scenario("step-asym", asym("step", 0.1), 0.02, 0.3, (40.0, 200.0, 0.6), FAST, 3000, 5),
    Scenario("step-B0", asym("step"), 0.02, 0.0, (40.0, 200.0, 0.6), FAST, 3000, 8),
    Scenario("linear-weakening", LW, 0.02, 0.2, (40.0, 200.0, 0.6), FAST, 3000, 8),
    Scenario("linear-B0", LW, 0.02, 0.0, (40.0, 200.0, 0.6), FAST, 3000, 8),
    Scenario(
        "coulomb-viscous",
        CoulombViscous(0.3, 0.2, 0.2),
        0.02,
        0.1,
        (40.0, 200.0, 0.6),
        FAST,
        3000,
        8,
    ),
    Scenario(
        "rotary-linear", ROTARY_PAPER, ROTARY_J, ROTARY_B, (7.8, 30.0, 0.1), ROTARY_REF, 4000, 8
    ),
    Scenario(
        "rotary-step",
        ROTARY_PAPER.replace(shape="step"),
        ROTARY_J,
        ROTARY_B,
        (7.8, 30.0, 0.1),
        ROTARY_REF,
        4000,
        8,
    ),
]


@pytest.mark.parametrize("sc", SCENARIOS, ids=lambda s: s.name)
def test_closed_loop_matches_reference(sc: Scenario) -> None:
    kp, ki, kd = sc.gains
    plant = make(sc.friction, inertia=sc.inertia, damping=sc.damping, limit=10.0)
    tr = run(plant, sc.steps, controller=PID(kp, ki, kd, sc.reference, DT))
    ref = ReferencePlant(sc.inertia, sc.damping, sc.friction, DT, command_limit=10.0)
    rr = ref.run(sc.steps, controller=PID(kp, ki, kd, sc.reference, DT))
    kp_ki_stable = (kd + sc.damping + getattr(sc.friction, "viscous", 0.0)) * kp > sc.inertia * ki
    assert kp_ki_stable  # the linear loop is stable
    # many stick/slip events: rests, and stop events (rests and reversals) located in the reference
    assert len(rest_episodes(rr.stuck)[0]) >= sc.min_rests
    assert len(rr.stops) >= 12
    assert np.max(np.abs(tr.x[:, 0] - rr.x)) <= 1e-9
    assert np.max(np.abs(tr.v[:, 0] - rr.v)) <= 1e-9
    assert np.array_equal(tr.stuck[:, 0], rr.stuck)
    # step-average friction: the reference gets it from the momentum balance
    tol = 1e-9 * (sc.inertia + sc.damping * DT) / DT
    assert np.max(np.abs(tr.friction[:, 0] - rr.friction)) <= tol


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(12))
def test_random_closed_loops_match_reference(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    ucp, ucn = rng.uniform(0.05, 0.5, 2)
    usp, usn = ucp * rng.uniform(1.0, 1.8), ucn * rng.uniform(1.0, 1.8)
    friction = StictionCoulomb(
        usp,
        usn,
        ucp,
        ucn,
        *rng.uniform(0.02, 0.5, 2),
        viscous=rng.uniform(0.0, 0.3) * (seed % 2),
        shape=("step", "linear")[seed % 3 == 0],
    )
    inertia, damping = rng.uniform(0.01, 0.3), rng.uniform(0.0, 0.5) * (seed % 4 != 1)
    kp = rng.uniform(10.0, 60.0)
    kd = rng.uniform(0.2, 1.5)
    ki = rng.uniform(0.1, 0.9) * (kd + damping) * kp / inertia  # stable linear loop
    reference = schedule(list(rng.uniform(-0.5, 0.5, 16)), rng.uniform(0.1, 0.4))
    n = 6000
    tr = run(
        make(friction, inertia=inertia, damping=damping, limit=20.0),
        n,
        controller=PID(kp, ki, kd, reference, DT),
    )
    rr = ReferencePlant(inertia, damping, friction, DT, command_limit=20.0).run(
        n, controller=PID(kp, ki, kd, reference, DT)
    )
    assert len(rr.stops) >= 10
    assert np.max(np.abs(tr.x[:, 0] - rr.x)) <= 1e-9
    assert np.array_equal(tr.stuck[:, 0], rr.stuck)


@pytest.mark.parametrize("shape", ["step", "linear"])
@pytest.mark.parametrize("substeps", [1, 3])
def test_open_loop_matches_reference_with_any_substeps(shape: str, substeps: int) -> None:
    friction = StictionCoulomb(1.0, 0.8, 0.4, 0.3, 0.3, 0.2, 0.1, shape)
    n = 1500
    u = open_loop_commands(n, 3, 1.0, 0.8)
    rr = ReferencePlant(0.2, 0.5, friction, DT).run(n, commands=u, v0=0.7)
    plant = make(friction, inertia=0.2, damping=0.5, substeps=substeps)
    plant.reset(velocity=0.7)
    tr = run(plant, n, commands=u)
    assert len(rest_episodes(rr.stuck)[0]) >= 6
    assert len(rr.stops) >= 10
    assert np.max(np.abs(tr.x[:, 0] - rr.x)) <= 1e-9
    assert np.array_equal(tr.stuck[:, 0], rr.stuck)


@pytest.mark.parametrize("shape", ["smooth", "exponential"])
def test_split_scheme_converges_first_order(shape: str) -> None:
    friction = StictionCoulomb(1.0, 0.8, 0.4, 0.3, 0.3, 0.2, 0.1, shape)
    n = 2000
    u = open_loop_commands(n, 5, 1.0, 0.8)
    rr = ReferencePlant(0.2, 0.5, friction, DT).run(n, commands=u)
    assert len(rest_episodes(rr.stuck)[0]) >= 6
    assert len(rr.stops) >= 10
    errors = []
    for substeps in (4, 8, 16, 32):
        tr = run(make(friction, inertia=0.2, damping=0.5, substeps=substeps), n, commands=u)
        errors.append(np.max(np.abs(tr.x[:, 0] - rr.x)))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all((ratios > 1.8) & (ratios < 2.2)), (errors, ratios)
    assert errors[-1] < 5e-5


def test_reference_self_check_continuous_p_control() -> None:
    # The reference with a spring-like load u = Kp (r - x) applied continuously (not ZOH)
    # reproduces O5 exactly: turning points -0.8, 0.6, -0.4, 0.2, then rest at 0.
    friction = StictionCoulomb(1.2, 1.2, 1.0, 1.0, 1.0, 1.0, shape="step")
    ref = ReferencePlant(1.0, 0.0, friction, 0.05, load=lambda t, x: 10.0 * (1.0 - x))
    rr = ref.run(120, commands=np.zeros(120))
    assert len(rr.stops) == 5
    np.testing.assert_allclose(rr.stops, math.pi / math.sqrt(10.0) * np.arange(1, 6), atol=1e-9)
    assert abs(1.0 - rr.x[-1]) <= 1e-9
    assert rr.stuck[-1]


@pytest.mark.parametrize("shape", SHAPES)
def test_friction_never_does_positive_work(shape: str) -> None:
    friction = asym(shape, viscous=0.15)
    n = 4000
    u = open_loop_commands(n, 11, 0.5, 0.4)
    plant = make(friction, damping=0.2)
    tr = run(plant, n, commands=u)
    # energy inequality: kinetic energy grows by at most the input's work (exact: minus the
    # viscous loss, >= B dx^2/dt by Cauchy-Schwarz)
    assert energy_violation(tr, 1.0, 0.35, DT, tight=friction.exact) <= 1e-12
    # friction opposes the motion in every step without a stop event
    v0, v1 = tr.v[:-1, 0], tr.v[1:, 0]
    no_stop = (v1 != 0.0) & ((v0 == 0.0) | (np.sign(v0) == np.sign(v1)))
    assert no_stop.sum() > n // 4
    dx = np.diff(tr.x[:, 0])
    assert np.all(tr.friction[no_stop, 0] * dx[no_stop] >= 0.0)
    assert np.all(np.sign(tr.friction[no_stop, 0]) == np.sign(dx[no_stop]))


def test_step_average_friction_with_a_stop_inside_the_step() -> None:
    # A step that slides, stops and then holds against an opposing command reports the
    # step average (uc t1 + u (h - t1)) / h: it can oppose the displacement of that step, so
    # "friction * dx >= 0" holds only for steps without a stop (the test above).
    h = 0.2
    friction = StictionCoulomb(0.4, 0.4, 0.3, 0.3, 1.0, 1.0, shape="step")
    plant = make(friction, damping=0.0, dt=h)
    plant.reset(velocity=0.05)
    plant.step(-0.3)
    t1 = 0.05 / 0.6
    assert plant.stuck[0]
    assert plant.position[0] == pytest.approx(0.05 * t1 / 2, rel=1e-13)
    assert plant.friction_force[0] == pytest.approx((0.3 * t1 - 0.3 * (h - t1)) / h, rel=1e-12)
    assert plant.friction_force[0] * plant.position[0] < 0.0


@pytest.mark.parametrize("shape", SHAPES)
def test_mirror_symmetry(shape: str) -> None:
    friction = StictionCoulomb(0.6, 0.6, 0.35, 0.35, 0.25, 0.25, 0.1, shape)
    n = 3000
    u = open_loop_commands(n, 2, 0.6, 0.6)
    a = run(make(friction), n, commands=u)
    b = run(make(friction), n, commands=-u)
    assert np.array_equal(a.x, -b.x)
    assert np.array_equal(a.v, -b.v)
    assert np.array_equal(a.stuck, b.stuck)
    assert np.array_equal(a.friction, -b.friction)
    mirrored = schedule([-level for level in FAST_LEVELS], 0.25)
    pa = run(make(friction, inertia=0.02), n, controller=PID(40.0, 200.0, 0.6, FAST))
    pb = run(make(friction, inertia=0.02), n, controller=PID(40.0, 200.0, 0.6, mirrored))
    assert np.array_equal(pa.x, -pb.x)
    assert np.array_equal(pa.stuck, pb.stuck)
    assert len(rest_episodes(pa.stuck[:, 0])[0]) >= 5


# == hypothesis properties ====================================================================
@PROPERTY_SETTINGS
@given(
    friction=static_laws(),
    params=plant_params,
    commands=command_lists,
    v_init=st.floats(-3.0, 3.0),
    repeat=st.integers(1, 30),
)
def test_property_physics(
    friction: StictionCoulomb,
    params: PlantParams,
    commands: list[float],
    v_init: float,
    repeat: int,
) -> None:
    u = np.repeat(np.asarray(commands), repeat)[:600]
    plant = Plant(params, friction, DT)
    plant.reset(velocity=v_init)
    tr = run(plant, len(u), commands=u)
    assert np.all(np.isfinite(tr.x))
    assert np.all(np.isfinite(tr.v))
    assert np.all(np.isfinite(tr.friction))
    assert np.array_equal(tr.stuck, tr.v == 0.0)
    b_total = params.damping + friction.viscous
    assert energy_violation(tr, params.inertia, b_total, DT, tight=friction.exact) <= 1e-10
    # a stuck plant stays stuck, bit-exactly, while the command is inside the band; and
    # leaves rest in the command's direction as soon as it is outside
    applied = tr.command[:, 0]
    was_stuck = tr.stuck[:-1, 0]
    inside = (applied >= -friction.us_neg) & (applied <= friction.us_pos)
    hold = was_stuck & inside
    assert np.all(tr.stuck[1:, 0][hold])
    assert np.array_equal(tr.x[1:, 0][hold], tr.x[:-1, 0][hold])
    assert np.array_equal(tr.friction[hold, 0], applied[hold])
    go = was_stuck & ~inside
    assert np.all(np.sign(tr.v[1:, 0][go]) == np.sign(applied[go]))


def test_energy_check_at_the_rounding_limit_of_the_position() -> None:
    """Regression (found by hypothesis): a stop a hair before the step ends, then a creep of
    -2.2e-16 units with no friction that way, moves x by less than one ulp of x."""
    friction = StictionCoulomb(0.09375, 0.0, 0.09375, 0.0, 1.0, 1.0, 0.0, "step")
    params = PlantParams(inertia=1.0, damping=0.0, command_limit=0.125)
    tr = run(Plant(params, friction, DT), 6, commands=np.repeat([1.0, -2.220446049250313e-16], 3))
    assert tr.v[-1, 0] < 0.0  # broke away backwards: the band's negative edge is 0
    assert energy_violation(tr, 1.0, 0.0, DT, tight=True) <= 1e-10


def test_energy_check_when_a_coast_moves_one_ulp_per_step() -> None:
    """Regression (found by hypothesis): no friction, J/B = dt, a pulse then a long coast whose
    last steps move x by one ulp, which rounds dx and the tightening term B dx^2 / dt."""
    params = PlantParams(inertia=0.001, damping=1.0, command_limit=1.0)
    plant = Plant(params, StictionCoulomb(0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, "step"), DT)
    tr = run(plant, 51, commands=np.repeat([1.0, 0.0, 0.0], 17))
    assert 0.0 < tr.v[-1, 0] < 1e-14
    assert energy_violation(tr, 0.001, 1.0, DT, tight=True) <= 1e-10


@pytest.mark.parametrize("v_init", [-5e-324, 5e-324, -1e-310, 2.2e-308])
def test_friction_stops_a_denormal_velocity_without_pushing_it_back(v_init: float) -> None:
    """Regression (found by hypothesis): the stop-time test multiplied two tiny numbers, the
    product underflowed to zero and the stop was missed, so Coulomb friction drove the body
    backwards for a whole step."""
    friction = StictionCoulomb(0.5, 0.5, 0.5, 0.5, 1.0, 1.0, 0.0, "step")
    plant = Plant(PlantParams(inertia=1.0, damping=1.0, command_limit=1.0), friction, DT)
    plant.reset(velocity=v_init)
    plant.step(0.0)
    assert plant.stuck[0]
    assert plant.velocity[0] == 0.0
    assert abs(plant.position[0]) <= abs(v_init) * DT


def test_steep_velocity_weakening_breakaway_stays_finite() -> None:
    """Regression (found by hypothesis): friction falling from 1.5 to 0 within 1 mm/s is a
    negative damping of -1500; the phase evaluated over a whole step overflows, but the event
    (leaving the decay range) comes long before the step ends."""
    friction = StictionCoulomb(1.5, 0.0, 0.0, 0.0, 0.001, 1.0, 0.0, "linear")
    params = PlantParams(inertia=0.001953125, damping=0.0, command_limit=2.0)
    tr = run(Plant(params, friction, DT), 20, commands=np.full(20, 2.0))
    assert np.all(np.isfinite(tr.x))
    assert np.all(np.isfinite(tr.v))
    # beyond the decay range the only force is the 2.0 command: v grows by 2/J per second
    np.testing.assert_allclose(np.diff(tr.v[5:, 0]), 2.0 / params.inertia * DT, rtol=1e-9)
