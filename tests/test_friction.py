"""Friction laws: validation, the sliding curve ``force(v)``, presets and names."""

from __future__ import annotations

import math

import numpy as np
import pytest

from frictiongym.friction import (
    ALTINO_PAPER,
    FRICTION_NAMES,
    ROTARY_LUGRE,
    ROTARY_PAPER,
    CoulombViscous,
    LuGre,
    NoFriction,
    StictionCoulomb,
    friction_from_name,
)

SHAPES = ("step", "linear", "smooth", "exponential")
DECAYING = ("linear", "smooth", "exponential")
BASE = dict(us_pos=0.5, us_neg=0.4, uc_pos=0.3, uc_neg=0.2, v0_pos=1.5, v0_neg=0.7)


def law(shape: str = "linear", viscous: float = 0.0, **changes: float) -> StictionCoulomb:
    kw = {**BASE, "viscous": viscous, "shape": shape, **changes}
    return StictionCoulomb(**kw)


# -- validation ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"us_pos": math.nan}, r"StictionCoulomb\.us_pos must be finite"),
        ({"uc_neg": math.inf}, r"StictionCoulomb\.uc_neg must be finite"),
        ({"viscous": -math.inf}, r"StictionCoulomb\.viscous must be finite"),
        ({"v0_pos": math.nan}, r"StictionCoulomb\.v0_pos must be finite"),
        ({"v0_neg": -0.5}, r"StictionCoulomb\.v0_neg must be > 0"),
        ({"v0_pos": 0.0}, r"StictionCoulomb\.v0_pos must be > 0"),
        ({"uc_pos": 0.6}, r"uc_pos=0\.6 exceeds us_pos=0\.5"),
        ({"uc_neg": 0.41}, r"uc_neg=0\.41 exceeds us_neg=0\.4"),
        ({"viscous": -0.1}, r"StictionCoulomb\.viscous must be >= 0"),
        ({"us_pos": -0.5}, r"StictionCoulomb\.us_pos must be >= 0"),
        ({"shape": "tanh"}, r"StictionCoulomb\.shape must be one of .*'tanh'"),
    ],
)
def test_stiction_coulomb_rejects_bad_parameters(changes: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        StictionCoulomb(**{**BASE, **changes})


@pytest.mark.parametrize("name", ["us_neg", "uc_neg"])
def test_negative_level_hints_that_levels_are_magnitudes(name: str) -> None:
    # The paper writes u_s- = -0.190 V; here it is us_neg=0.190 and the error says so.
    changes = {name: -0.15} if name == "uc_neg" else {name: -0.4, "uc_neg": 0.0}
    expected = rf"{name} must be >= 0, got -0\.\d+ \(levels are magnitudes: write {name}=0\.\d+"
    with pytest.raises(ValueError, match=expected):
        StictionCoulomb(**{**BASE, **changes})


def test_coulomb_viscous_validation() -> None:
    with pytest.raises(ValueError, match=r"CoulombViscous\.uc_neg must be >= 0.*magnitudes"):
        CoulombViscous(0.1, -0.2)
    with pytest.raises(ValueError, match=r"CoulombViscous\.uc_pos must be finite"):
        CoulombViscous(math.nan, 0.2)
    with pytest.raises(ValueError, match=r"CoulombViscous\.viscous must be >= 0"):
        CoulombViscous(0.1, 0.2, viscous=-1.0)


def test_lugre_validation() -> None:
    good = dict(
        us_pos=1.5,
        us_neg=1.5,
        uc_pos=1.0,
        uc_neg=1.0,
        vs_pos=1e-3,
        vs_neg=1e-3,
        sigma0=1e5,
        sigma1=316.0,
        viscous=0.4,
    )
    LuGre(**good)
    for changes, match in [
        ({"sigma0": 0.0}, r"LuGre\.sigma0 must be > 0"),
        ({"vs_neg": -1e-3}, r"LuGre\.vs_neg must be > 0"),
        ({"sigma1": math.nan}, r"LuGre\.sigma1 must be finite"),
        ({"uc_pos": 2.0}, r"uc_pos=2\.0 exceeds us_pos=1\.5"),
        ({"uc_neg": 0.0}, r"LuGre\.uc_pos and LuGre\.uc_neg must be > 0"),
    ]:
        with pytest.raises(ValueError, match=match):
            LuGre(**{**good, **changes})


def test_non_numbers_are_type_errors() -> None:
    with pytest.raises(TypeError, match=r"StictionCoulomb\.us_pos must be a real number"):
        StictionCoulomb(**{**BASE, "us_pos": "0.5"})
    with pytest.raises(TypeError, match=r"StictionCoulomb\.viscous must be a real number"):
        StictionCoulomb(**{**BASE, "viscous": True})


def test_replace_validates_again() -> None:
    with pytest.raises(ValueError, match="shape must be one of"):
        ROTARY_PAPER.replace(shape="quadratic")
    assert ROTARY_PAPER.replace(shape="step").shape == "step"


# -- force(v) --------------------------------------------------------------------------------
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("batch", [(), (7,), (3, 4), (2, 1, 5)])
def test_force_keeps_any_batch_shape(shape: str, batch: tuple[int, ...]) -> None:
    rng = np.random.default_rng(1)
    v = rng.normal(size=batch) * 2.0
    f = law(shape, viscous=0.1).force(v)
    assert isinstance(f, np.ndarray)
    assert f.shape == batch
    assert f.dtype == np.float64
    flat = law(shape, viscous=0.1).force(v.reshape(-1))
    np.testing.assert_array_equal(f.reshape(-1), flat)


def test_force_scalar_and_list_inputs() -> None:
    f = ROTARY_PAPER.force(0.5)
    assert f.shape == ()
    assert float(f) == ROTARY_PAPER.force([0.5])[0]
    assert ROTARY_PAPER.force(0.0) == 0.0  # set-valued at rest: the plant decides
    assert law("smooth").force(np.array([-0.0, 0.0])).tolist() == [0.0, 0.0]


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("viscous", [0.0, 0.37])
def test_force_at_v0_is_coulomb_plus_viscous(shape: str, viscous: float) -> None:
    m = law(shape, viscous)
    assert m.force(m.v0_pos) == m.uc_pos + viscous * m.v0_pos
    assert m.force(-m.v0_neg) == -m.uc_neg - viscous * m.v0_neg
    # and beyond v0 the nonlinear part stays at the Coulomb level
    v = np.array([1.0, 2.0, 10.0, 1e6])
    np.testing.assert_array_equal(m.nonlinear_force(v * m.v0_pos), m.uc_pos)
    np.testing.assert_array_equal(m.nonlinear_force(-v * m.v0_neg), -m.uc_neg)


@pytest.mark.parametrize("shape", DECAYING)
def test_force_approaches_breakaway_at_rest(shape: str) -> None:
    m = law(shape, viscous=0.2)
    for eps in (1e-6, 1e-9, 1e-12):
        assert m.force(eps) == pytest.approx(m.us_pos, abs=10 * eps)
        assert m.force(-eps) == pytest.approx(-m.us_neg, abs=10 * eps)
    assert m.force(1e-300) == pytest.approx(m.us_pos, abs=1e-15)
    assert m.force(-1e-300) == pytest.approx(-m.us_neg, abs=1e-15)


def test_step_shape_drops_to_coulomb_immediately() -> None:
    m = law("step")
    assert m.force(1e-300) == m.uc_pos
    assert m.force(-1e-300) == -m.uc_neg


def test_linear_shape_closed_form() -> None:
    m = law("linear", viscous=0.25)
    v = np.linspace(0.01, 1.4, 50)
    expected = m.uc_pos + (m.us_pos - m.uc_pos) * (1 - v / m.v0_pos) + 0.25 * v
    np.testing.assert_allclose(m.force(v), expected, rtol=1e-14)
    vn = -np.linspace(0.01, 0.69, 50)
    expected_n = -(m.uc_neg + (m.us_neg - m.uc_neg) * (1 + vn / m.v0_neg)) + 0.25 * vn
    np.testing.assert_allclose(m.force(vn), expected_n, rtol=1e-14)


def test_smooth_and_exponential_closed_forms() -> None:
    r = np.linspace(0.0, 0.999, 37)[1:]
    sm = law("smooth")
    expected = sm.uc_pos + (sm.us_pos - sm.uc_pos) * (1 - 10 * r**3 + 15 * r**4 - 6 * r**5)
    np.testing.assert_allclose(sm.force(r * sm.v0_pos), expected, rtol=1e-13)
    ex = law("exponential")
    phi = (np.exp(-np.log(100.0) * r) - 0.01) / 0.99
    np.testing.assert_allclose(
        ex.force(r * ex.v0_pos), ex.uc_pos + (ex.us_pos - ex.uc_pos) * phi, rtol=1e-13
    )


@pytest.mark.parametrize("shape", SHAPES)
def test_decay_is_monotone(shape: str) -> None:
    m = law(shape)
    v = np.linspace(0.0, 3.0, 3001)[1:]
    fp = m.nonlinear_force(v * m.v0_pos)
    fn = -m.nonlinear_force(-v * m.v0_neg)
    for f, us, uc in ((fp, m.us_pos, m.uc_pos), (fn, m.us_neg, m.uc_neg)):
        assert np.all(np.diff(f) <= 0.0)
        assert np.all((f >= uc) & (f <= us))
        assert f[-1] == uc


@pytest.mark.parametrize("shape", SHAPES)
def test_asymmetric_levels_and_speeds(shape: str) -> None:
    m = law(shape, viscous=0.1)
    v = np.linspace(0.05, 3.0, 60)
    # each side uses its own levels and decay speed
    pos = m.force(v) - 0.1 * v
    neg = -(m.force(-v) + 0.1 * v)
    mirrored = law(
        shape,
        viscous=0.1,
        us_pos=m.us_neg,
        us_neg=m.us_pos,
        uc_pos=m.uc_neg,
        uc_neg=m.uc_pos,
        v0_pos=m.v0_neg,
        v0_neg=m.v0_pos,
    )
    np.testing.assert_array_equal(mirrored.force(-v), -m.force(v))
    assert not np.allclose(pos, neg)
    assert m.breakaway == (0.5, 0.4)


@pytest.mark.parametrize("shape", SHAPES)
def test_mirror_symmetry_for_symmetric_parameters(shape: str) -> None:
    m = StictionCoulomb(0.7, 0.7, 0.4, 0.4, 0.9, 0.9, viscous=0.3, shape=shape)
    v = np.random.default_rng(2).normal(size=500)
    np.testing.assert_array_equal(m.force(-v), -m.force(v))


def test_viscous_is_the_only_difference_between_force_and_nonlinear_force() -> None:
    m = law("smooth", viscous=0.45)
    v = np.linspace(-3, 3, 41)
    np.testing.assert_allclose(m.force(v) - m.nonlinear_force(v), 0.45 * v, atol=1e-15)


def test_coulomb_viscous_and_no_friction_curves() -> None:
    cv = CoulombViscous(0.3, 0.2, viscous=0.5)
    v = np.array([-2.0, -1e-9, 1e-9, 2.0])
    np.testing.assert_allclose(cv.force(v), np.sign(v) * [0.2, 0.2, 0.3, 0.3] + 0.5 * v, rtol=1e-15)
    assert cv.breakaway == (0.3, 0.2)
    np.testing.assert_array_equal(NoFriction().force(v), 0.0)
    assert NoFriction().breakaway == (0.0, 0.0)
    assert all(m.exact for m in (cv, NoFriction(), law("step"), law("linear")))
    assert not law("smooth").exact
    assert not law("exponential").exact


def test_equal_levels_have_no_decay() -> None:
    m = StictionCoulomb(0.3, 0.2, 0.3, 0.2, 1.0, 1.0, shape="exponential")
    v = np.array([1e-12, 0.3, 0.9, 5.0])
    np.testing.assert_array_equal(m.force(v), 0.3)
    np.testing.assert_array_equal(m.force(-v), -0.2)


def test_lugre_steady_curve_is_gaussian_stribeck() -> None:
    m = ROTARY_LUGRE
    v = np.array([0.5, 1.0, 2.0, 5.0]) * m.vs_pos
    g = m.uc_pos + (m.us_pos - m.uc_pos) * np.exp(-((v / m.vs_pos) ** 2))
    np.testing.assert_allclose(m.force(v), g, rtol=1e-14)
    # within 1 % of the Coulomb level at the paper's v0
    assert m.force(3.015) - m.uc_pos == pytest.approx(0.01 * (m.us_pos - m.uc_pos), rel=1e-9)
    assert m.is_dynamic
    assert not m.exact


# -- presets ---------------------------------------------------------------------------------
def test_rotary_preset_carries_the_paper_numbers() -> None:
    m = ROTARY_PAPER
    assert (m.us_pos, m.us_neg) == (0.210, 0.190)
    assert (m.uc_pos, m.uc_neg) == (0.124, 0.104)
    assert (m.v0_pos, m.v0_neg) == (3.015, 2.530)
    assert m.viscous == 0.0  # the 0.0411 V/(rad/s) slope is part of the plant's B_e
    assert m.breakaway == (0.210, 0.190)
    assert m.force(3.015) == 0.124
    assert m.force(-2.530) == -0.104
    assert (ROTARY_LUGRE.us_pos, ROTARY_LUGRE.uc_neg) == (0.210, 0.104)


def test_altino_preset_carries_the_paper_numbers() -> None:
    m = ALTINO_PAPER
    assert (m.us_pos, m.us_neg) == (200.0, 200.0)
    assert (m.uc_pos, m.uc_neg) == (150.4, 119.6)
    assert (m.v0_pos, m.v0_neg) == (13.8, 10.9)
    assert m.viscous == 10.93
    assert m.force(13.8) == pytest.approx(150.4 + 10.93 * 13.8, rel=1e-15)
    assert m.force(-10.9) == pytest.approx(-119.6 - 10.93 * 10.9, rel=1e-15)


def test_friction_from_name() -> None:
    assert FRICTION_NAMES == ("paper", "none", "coulomb", "stribeck", "lugre")
    built = {n: friction_from_name(n, ROTARY_PAPER, ROTARY_LUGRE) for n in FRICTION_NAMES}
    assert built["paper"] == ROTARY_PAPER
    assert isinstance(built["none"], NoFriction)
    assert built["coulomb"] == CoulombViscous(0.124, 0.104, 0.0)
    assert built["stribeck"] == ROTARY_PAPER.replace(shape="exponential")
    assert built["lugre"] == ROTARY_LUGRE
    for n, m in built.items():
        assert m.name == n or (n == "stribeck" and m.name == "paper")
    alt = friction_from_name("coulomb", ALTINO_PAPER, ROTARY_LUGRE)
    assert alt == CoulombViscous(150.4, 119.6, 10.93)


@pytest.mark.parametrize("bad", ["Paper", "tanh", ""])
def test_friction_from_name_unknown(bad: str) -> None:
    with pytest.raises(
        ValueError,
        match=rf"unknown friction law '{bad}'; choose one of paper, "
        r"none, coulomb, stribeck, lugre",
    ):
        friction_from_name(bad, ROTARY_PAPER, ROTARY_LUGRE)
