"""Self-checks of the backlash reference solver (``_backlash_reference.py``).

The reference is the oracle for the two-body plant, so it is checked here against things
known independently of it: the one-body reference (rigid pair, and each body alone in a wide
play), closed-form free flight and impact, the momentum balance with known friction levels,
the energy inequality, the rest rules and the sign of the contact force.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from _backlash_reference import BacklashReference, BacklashResult
from _reference import PID, Law, ReferencePlant
from scipy.optimize import brentq

from frictiongym.friction import CoulombViscous, NoFriction, StictionCoulomb

DT = 1e-3
FAST_LEVELS = [0.0, 0.3, 0.27, -0.1, -0.12, 0.4, 0.1, 0.15, -0.3, -0.29, 0.0, 0.05]
ASYM = dict(us_pos=0.5, us_neg=0.4, uc_pos=0.3, uc_neg=0.2, v0_pos=0.3, v0_neg=0.2)


def linear_law(viscous: float = 0.0, shape: str = "linear") -> StictionCoulomb:
    return StictionCoulomb(**ASYM, viscous=viscous, shape=shape)


def held_commands(rng: np.random.Generator, n: int, hold: int, amp: float) -> np.ndarray:
    """Random levels held for ``hold`` steps each (rests, reversals and impacts)."""
    levels = rng.uniform(-amp, amp, n // hold + 1)
    return np.repeat(levels, hold)[:n]


def kinetic(ref: BacklashReference, r: BacklashResult) -> np.ndarray:
    return 0.5 * (ref.Jm * r.motor_v**2 + ref.JL * r.v**2)


def input_work(r: BacklashResult) -> np.ndarray:
    """Cumulative work of the held input on the motor at each control instant."""
    xm = r.x + r.gap
    return np.concatenate([[0.0], np.cumsum(r.command * np.diff(xm))])


# -- 1. a rigid pair is the one-body plant ----------------------------------------------------
@pytest.mark.parametrize(("psi", "phi"), [(0.3, 0.7), (0.6, 0.1)])
def test_zero_backlash_closed_loop_matches_the_one_body_reference(psi: float, phi: float) -> None:
    # a velocity-weakening law in a stiff PID loop: a stick/slip trajectory with many rests
    law = StictionCoulomb(1.0, 0.8, 0.3, 0.25, 0.2, 0.15, 0.1, "linear")
    J, B, n = 0.02, 0.2, 3000

    def reference(t: float) -> float:
        return FAST_LEVELS[int(t / 0.25) % len(FAST_LEVELS)]

    rr = ReferencePlant(J, B, law, DT, command_limit=5.0).run(
        n, controller=PID(40.0, 200.0, 0.6, reference, DT)
    )
    ref = BacklashReference(J, B, law, DT, 0.0, psi, phi, command_limit=5.0)
    br = ref.run(n, controller=PID(40.0, 200.0, 0.6, reference, DT))
    assert len(rr.stops) >= 12
    assert np.sum(np.diff(rr.stuck.astype(int)) == 1) >= 8
    assert sum(kind == "stop" for _, kind in ref.events) == len(rr.stops)
    assert np.max(np.abs(br.x - rr.x)) <= 1e-9
    assert np.max(np.abs(br.v - rr.v)) <= 1e-9
    assert np.array_equal(br.v == 0.0, rr.stuck)
    assert np.all(br.gap == 0.0)
    assert np.array_equal(br.motor_v, br.v)
    assert np.max(np.abs(br.friction - rr.friction)) <= 1e-9 * (J + B * DT) / DT
    assert br.separations == []


@pytest.mark.parametrize("shape", ["step", "linear"])
def test_zero_backlash_open_loop_matches_the_one_body_reference(shape: str) -> None:
    law, J, B, n = linear_law(shape=shape), 0.5, 0.2, 2000
    u = held_commands(np.random.default_rng(3), n, 40, 1.2)
    rr = ReferencePlant(J, B, law, DT, dead_zone=0.05).run(n, commands=u, v0=0.4)
    ref = BacklashReference(J, B, law, DT, 0.0, 0.4, 0.5, dead_zone=0.05)
    br = ref.run(n, commands=u, v0=0.4)
    assert len(rr.stops) >= 8
    assert np.array_equal(br.command, rr.command)
    assert np.max(np.abs(br.x - rr.x)) <= 1e-9
    assert np.max(np.abs(br.v - rr.v)) <= 1e-9
    assert np.array_equal(br.v == 0.0, rr.stuck)


# -- FREE: each body is its own one-body plant while the play is wide enough --------------------
def test_free_bodies_follow_their_share_of_the_law() -> None:
    law, J, B, psi, phi, n = linear_law(viscous=0.05), 1.0, 0.2, 0.35, 0.6, 1500
    u = held_commands(np.random.default_rng(11), n, 20, 0.9)
    ref = BacklashReference(J, B, law, DT, 1e3, psi, phi)
    br = ref.run(n, commands=u, v0=-0.25, motor_v0=0.1)
    assert br.contacts == []
    total = Law.of(law)

    def share(w: float) -> Law:
        levels = (total.us_pos, total.us_neg, total.uc_pos, total.uc_neg)
        speeds = (total.v0_pos, total.v0_neg)
        return Law(*(w * a for a in levels), *speeds, w * total.viscous, total.shape)

    motor = ReferencePlant((1 - psi) * J, (1 - phi) * B, share(1 - phi), DT).run(
        n, commands=u, v0=0.1
    )
    load = ReferencePlant(psi * J, phi * B, share(phi), DT).run(n, commands=np.zeros(n), v0=-0.25)
    assert len(motor.stops) >= 12
    assert np.sum(np.diff(motor.stuck.astype(int)) == 1) >= 4
    assert load.stops  # the load coasts to rest and stays there
    assert np.max(np.abs(br.x + br.gap - motor.x)) <= 1e-9
    assert np.max(np.abs(br.motor_v - motor.v)) <= 1e-9
    assert np.array_equal(br.motor_v == 0.0, motor.stuck)
    assert np.max(np.abs(br.x - load.x)) <= 1e-9
    assert np.array_equal(br.v == 0.0, load.stuck)


# -- 2. free flight across the play, then the impact ------------------------------------------
@pytest.mark.parametrize(("psi", "c"), [(0.3, 0.7), (0.8, -1.3)])
def test_free_flight_crosses_the_play_in_2g_over_c_then_a_plastic_impact(
    psi: float, c: float
) -> None:
    J, W = 2.0, 0.02
    g = W / 2
    ref = BacklashReference(J, 0.0, NoFriction(), DT, W, psi, 0.5)
    side = -1.0 if c > 0 else 1.0  # start on the face the motor moves away from
    n = 40
    r = ref.run(n, gap0=side * g, v0=0.0, motor_v0=c, commands=np.zeros(n))
    crossing = 2 * g / abs(c)
    assert len(r.contacts) == 1
    assert abs(r.contacts[0] - crossing) <= 1e-9 * crossing
    before, after = r.t < crossing, r.t > crossing
    assert np.all(r.x[before] == 0.0)
    assert np.max(np.abs(r.gap[before] - (side * g + c * r.t[before]))) <= 1e-12
    common = (1 - psi) * J * c / J
    assert np.max(np.abs(r.v[after] - common)) <= 1e-12
    assert np.max(np.abs(r.motor_v[after] - common)) <= 1e-12
    assert np.all(r.gap[after] == -side * g)
    assert np.max(np.abs(r.x[after] - common * (r.t[after] - crossing))) <= 1e-12
    assert r.separations == []  # no friction: the contact force is 0, contact persists


# -- 3. the friction output is the friction impulse -------------------------------------------
def test_friction_output_is_the_share_weighted_impulse() -> None:
    uc_pos, uc_neg, visc, B, J, psi, phi = 0.3, 0.2, 0.1, 0.4, 1.0, 0.4, 0.3
    law = CoulombViscous(uc_pos=uc_pos, uc_neg=uc_neg, viscous=visc)
    ref = BacklashReference(J, B, law, DT, 0.01, psi, phi)
    n = 8
    # opposite slides close the play, collide in step 2 and leave together (common v > 0)
    r = ref.run(n, v0=-1.0, motor_v0=1.0, commands=np.full(n, 0.15))
    assert len(r.contacts) == 1
    te = r.contacts[0]
    k_hit = int(te // DT)
    assert k_hit == 2
    assert np.all(r.v[k_hit + 1 :] > 0.0)
    assert np.all(r.motor_v[k_hit + 1 :] > 0.0)
    coulomb = np.full(n, (1 - phi) * uc_pos - phi * uc_neg)  # motor +, load -
    part = (te - k_hit * DT) / DT
    coulomb[k_hit] = part * coulomb[k_hit] + (1 - part) * uc_pos
    coulomb[k_hit + 1 :] = uc_pos  # both slide + (engaged or not): the whole level
    viscous = visc * ((1 - phi) * np.diff(r.x + r.gap) + phi * np.diff(r.x)) / DT
    tol = 1e-9 * (J + B * DT) / DT
    assert np.max(np.abs(r.friction - (coulomb + viscous))) <= tol
    # the output must see the impact's momentum exchange as internal: a formula with the
    # velocity jump of one body only would be off by J_m dv / dt here
    assert abs(ref.Jm * (r.motor_v[k_hit + 1] - r.motor_v[k_hit])) / DT > 100 * tol


def test_friction_output_of_an_engaged_slide() -> None:
    law, J, B = CoulombViscous(uc_pos=0.3, uc_neg=0.2, viscous=0.2), 0.5, 0.3
    ref = BacklashReference(J, B, law, DT, 0.02, 0.4, 0.7)
    n = 50
    r = ref.run(n, gap0=-0.01, v0=-0.5, commands=np.full(n, -1.0))
    assert np.all(r.engaged)
    assert not r.separations
    expected = -0.2 + 0.2 * np.diff(r.x) / DT
    assert np.max(np.abs(r.friction - expected)) <= 1e-9 * (J + B * DT) / DT


# -- 4. energy is never created ---------------------------------------------------------------
@pytest.mark.parametrize(
    ("seed", "psi", "phi", "shape"),
    [
        (0, 0.3, 0.8, "linear"),
        (1, 0.7, 0.2, "linear"),
        (2, 0.5, 0.5, "step"),
        (3, 0.2, 0.0, "step"),
    ],
)
def test_energy_is_never_created(seed: int, psi: float, phi: float, shape: str) -> None:
    rng = np.random.default_rng(seed)
    n = 1500
    u = held_commands(rng, n, int(rng.integers(15, 60)), 1.5)
    ref = BacklashReference(0.3, 0.1, linear_law(0.05, shape), DT, 0.02, psi, phi)
    r = ref.run(n, commands=u, v0=0.3, motor_v0=-0.2)
    assert len(r.contacts) >= 5
    assert len(r.separations) >= 5
    assert np.all(np.abs(r.gap) <= 0.01 * (1 + 1e-12))
    losses = kinetic(ref, r)[0] + input_work(r) - kinetic(ref, r)
    assert np.min(losses) >= -1e-9
    # friction, damping and impacts dissipate in every period: losses never decrease
    assert np.min(np.diff(losses)) >= -1e-9


def test_the_impact_loses_the_relative_kinetic_energy() -> None:
    J, psi, c = 1.5, 0.4, 0.9
    ref = BacklashReference(J, 0.0, NoFriction(), DT, 0.01, psi, 0.5)
    r = ref.run(30, gap0=-0.005, motor_v0=c, commands=np.zeros(30))
    assert len(r.contacts) == 1
    mu = psi * (1 - psi) * J  # reduced mass of the pair
    assert kinetic(ref, r)[0] - kinetic(ref, r)[-1] == pytest.approx(0.5 * mu * c**2, rel=1e-12)


# -- 5. the rest rules of an engaged pair -----------------------------------------------------
@pytest.mark.parametrize("sigma", [1.0, -1.0])
def test_engaged_rest_rules(sigma: float) -> None:
    phi, W, n = 0.3, 0.02, 30
    g = W / 2
    us_push = ASYM["us_pos"] if sigma > 0 else ASYM["us_neg"]  # total level toward the face
    us_back = ASYM["us_neg"] if sigma > 0 else ASYM["us_pos"]  # motor's own level, away
    ref = BacklashReference(0.4, 0.2, linear_law(), DT, W, 0.45, phi)

    def hold(u: float) -> BacklashResult:
        return ref.run(n, gap0=sigma * g, commands=np.full(n, u))

    # the closed band [-(1 - phi) us_back, us_push] (in the direction sigma) holds both
    for u in (sigma * us_push, 0.0, -sigma * (1 - phi) * us_back, 0.5 * sigma * us_push):
        r = hold(u)
        assert np.all(np.c_[r.x, r.v, r.motor_v] == 0.0), u
        assert np.all(r.gap == sigma * g)
        assert np.all(r.engaged)
        assert not r.contacts
        assert not r.separations
    # beyond the total break-away level the pair leaves together
    r = hold(sigma * us_push * 1.01)
    assert np.all(sigma * r.v[1:] > 0.0)
    assert np.array_equal(r.v, r.motor_v)
    assert np.all(r.gap == sigma * g)
    assert np.all(r.engaged)
    # just beyond the motor's own level the motor leaves the face alone
    r = hold(-sigma * (1 - phi) * us_back * 1.01)
    assert r.separations == [0.0]
    assert np.all(r.x == 0.0)
    assert np.all(r.v == 0.0)
    assert np.all(sigma * r.motor_v[1:] < 0.0)
    assert np.all(np.diff(sigma * r.gap) < 0.0)


# -- 6. separation follows the sign of the contact force --------------------------------------
@pytest.mark.parametrize(("psi", "phi"), [(0.3, 0.8), (0.6, 0.2)])
def test_coasting_pair_separates_when_the_load_has_less_friction_per_inertia(
    psi: float, phi: float
) -> None:
    law, W, n = linear_law(viscous=0.1), 0.02, 400
    g = W / 2
    ref = BacklashReference(0.2, 0.3, law, DT, W, psi, phi)
    r = ref.run(n, gap0=g, v0=0.6, commands=np.zeros(n))  # motor ahead, pushing the load
    if phi > psi:  # F = (phi - psi) h(v) > 0: the motor drags the load all the way to rest
        assert r.separations == []
        assert np.all(r.engaged)
        assert np.all(r.gap == g)
        assert np.array_equal(r.v, r.motor_v)
        assert r.v[-1] == 0.0
        assert np.sum(r.v == 0.0) >= 10
    else:  # F < 0: the load runs ahead at once and the motor falls back
        assert r.separations == [0.0]
        assert not r.engaged[1]
        assert r.gap[1] < g
        assert r.v[1] > r.motor_v[1]


def test_separation_mid_piece_where_the_contact_force_crosses_zero() -> None:
    # braking with u < 0 while the heavily damped load is still pushed: F = v - 0.05 (closed
    # form), reached on the exponential decay of the pair's speed
    J, B, psi, phi, uc, u, v0 = 1.0, 2.0, 0.3, 0.8, 0.2, -0.5, 1.0
    law = CoulombViscous(uc_pos=uc, uc_neg=uc)
    ref = BacklashReference(J, B, law, DT, 0.02, psi, phi)
    n = 700
    r = ref.run(n, gap0=0.01, v0=v0, commands=np.full(n, u))
    v_sep = (-psi * u / (phi - psi) - uc) / B  # F = psi u + (phi - psi)(uc + B v) = 0
    v_inf = (u - uc) / B
    t_sep = -(J / B) * math.log((v_sep - v_inf) / (v0 - v_inf))
    assert v_sep == pytest.approx(0.05)
    assert len(r.separations) == 1
    assert r.separations[0] == pytest.approx(t_sep, rel=1e-9)
    k = int(t_sep // DT)
    assert np.all(r.engaged[: k + 1])
    assert not np.any(r.engaged[k + 1 :])
    assert r.gap[-1] < 0.01  # the motor brakes harder than the load after the separation


def test_a_quick_return_to_the_face_is_located() -> None:
    # A barely negative contact force at the start: the bodies part, but the motor's stronger
    # viscous braking turns the relative acceleration within ~0.1 ms and the motor returns to
    # the face inside the integrator's first step. Both slide forward on Coulomb + viscous
    # laws, so the gap is a closed form of exponentials.
    J, psi, phi, uc, visc, v0, W = 0.02, 0.3, 0.04, 0.3, 0.13, 2.9, 0.002
    law = CoulombViscous(uc_pos=uc, uc_neg=0.25, viscous=visc)
    u = ((psi - phi) * (uc + visc * v0) - 1e-5) / psi  # F(0) = -1e-5
    jm, jl, bm, bl = (1 - psi) * J, psi * J, (1 - phi) * visc, phi * visc
    tau_m, tau_l = jm / bm, jl / bl
    vinf_m, vinf_l = (u - (1 - phi) * uc) / bm, -uc / visc

    def gap_change(t: float) -> float:  # d(t) - g = integral of v_m - v_L
        return (
            (vinf_m - vinf_l) * t
            - (v0 - vinf_m) * tau_m * math.expm1(-t / tau_m)
            + (v0 - vinf_l) * tau_l * math.expm1(-t / tau_l)
        )

    assert gap_change(1e-4) < 0.0 < gap_change(DT)
    t_back = brentq(gap_change, 1e-4, DT, xtol=1e-18)
    ref = BacklashReference(J, 0.0, law, DT, W, psi, phi)
    r = ref.run(3, gap0=W / 2, v0=v0, commands=np.full(3, u))
    assert r.separations == [0.0]
    assert len(r.contacts) == 1
    # a grazing return (relative speed ~1e-7): the located time is good to ~1e-12 s
    assert abs(r.contacts[0] - t_back) <= 1e-8 * t_back
    assert np.all(r.engaged)


# -- argument checks --------------------------------------------------------------------------
def test_unsupported_shape_and_bad_arguments_raise() -> None:
    with pytest.raises(ValueError, match="shape"):
        BacklashReference(1.0, 0.0, linear_law(shape="smooth"), DT, 0.01, 0.5, 0.5)
    with pytest.raises(ValueError, match="inertia_share"):
        BacklashReference(1.0, 0.0, linear_law(), DT, 0.01, 1.0, 0.5)
    with pytest.raises(ValueError, match="friction_share"):
        BacklashReference(1.0, 0.0, linear_law(), DT, 0.01, 0.5, 1.5)
    ref = BacklashReference(1.0, 0.0, linear_law(), DT, 0.01, 0.5, 0.5)
    with pytest.raises(ValueError, match="play"):
        ref.run(3, gap0=0.006, commands=np.zeros(3))
    with pytest.raises(ValueError, match="exactly one"):
        ref.run(3)
