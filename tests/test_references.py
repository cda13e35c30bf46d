"""Reference generators and domain randomisation: values, draws, validation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from frictiongym.devices import ROTARY
from frictiongym.envs.references import (
    MAX_LEVELS,
    Ramp,
    RandomSteps,
    Sine,
    Step,
    StepSequence,
    resolve_reference,
)
from frictiongym.friction import ROTARY_PAPER
from frictiongym.plants.plant import plant_row
from frictiongym.plants.presets import ROTARY_PLANT
from frictiongym.plants.randomization import DomainRandomization, apply_factors

DT = 0.002
T = np.arange(2000) * DT  # the env's sample times k * dt, rounding included


def test_step_switches_at_the_first_sample_at_or_after_its_time():
    r = Step(2.0, time=0.1, initial=-1.0)(T)
    assert np.all(r[:50] == -1.0)
    assert np.all(r[50:] == 2.0)  # 50 * 0.002 rounds below 0.1; the 1 ns tolerance catches it
    assert np.all(Step(3.0)(T) == 3.0)


def test_step_sequence_holds_each_value_for_a_period_then_the_last():
    r = StepSequence((1.0, 2.0, 3.0), period=0.5)(T)
    np.testing.assert_array_equal(r[[0, 249, 250, 499, 500, 1999]], [1, 1, 2, 2, 3, 3])


def test_ramp_and_sine_follow_their_formulas():
    np.testing.assert_allclose(Ramp(2.0, start=1.0, initial=0.5)(T), 0.5 + 2 * np.maximum(T - 1, 0))
    sine = Sine(amplitude=2.0, period=0.7, offset=1.0, phase=0.3)(T)
    np.testing.assert_allclose(sine, 1.0 + 2.0 * np.sin(2 * np.pi * T / 0.7 + 0.3), atol=1e-15)


def test_random_steps_draw_their_levels_from_the_generator():
    ref = RandomSteps(-1.0, 2.0, period=0.1)
    a = ref(T, np.random.default_rng(0))
    levels = a[:: round(0.1 / DT)][:MAX_LEVELS]
    assert np.all((levels >= -1.0) & (levels <= 2.0))
    assert len(set(levels.tolist())) == MAX_LEVELS
    assert np.all(a[MAX_LEVELS * 50 :] == levels[-1])  # the last level is then held
    np.testing.assert_array_equal(a, ref(T, np.random.default_rng(0)))
    assert not np.array_equal(a, ref(T, np.random.default_rng(1)))
    with pytest.raises(ValueError, match="needs a generator"):
        ref.sample()


@pytest.mark.parametrize(
    ("build", "match"),
    [
        (lambda: Step(math.nan), "Step.value must be finite"),
        (lambda: StepSequence((), period=1.0), "1 to 16"),
        (lambda: StepSequence((1.0,) * 17, period=1.0), "1 to 16"),
        (lambda: StepSequence((1.0,), period=0.0), "period must be > 0"),
        (lambda: Sine(1.0, period=-1.0), "period must be > 0"),
        (lambda: RandomSteps(2.0, 1.0, period=1.0), "exceeds high"),
        (lambda: Ramp(math.inf), "Ramp.slope"),
    ],
)
def test_bad_generators_say_what_is_wrong(build, match):
    with pytest.raises(ValueError, match=match):
        build()


def test_resolve_reference_takes_names_numbers_and_generators():
    presets = ROTARY.references
    assert resolve_reference("sine", presets) == Sine(amplitude=1.0, period=2.0)
    assert resolve_reference(np.float32(0.5), presets) == Step(0.5)
    sine = Sine(1.0, 1.0)
    assert resolve_reference(sine, presets) is sine
    with pytest.raises(ValueError, match="unknown reference 'square'"):
        resolve_reference("square", presets)
    with pytest.raises(TypeError, match="reference must be"):
        resolve_reference(True, presets)


def test_randomisation_draws_in_field_order_and_scales_the_row():
    spec = DomainRandomization.from_spec({"friction": (0.5, 1.5), "damping": (2.0, 2.0)})
    factors = spec.draw(np.random.default_rng(0))
    assert list(factors) == ["friction", "damping"]
    assert factors["friction"] == np.random.default_rng(0).uniform(0.5, 1.5)
    nominal = plant_row(ROTARY_PLANT, ROTARY_PAPER)
    row, gain = apply_factors(nominal, factors)
    scaled = plant_row(
        dataclasses.replace(ROTARY_PLANT, damping=2 * ROTARY_PLANT.damping),
        ROTARY_PAPER.replace(
            **{
                k: getattr(ROTARY_PAPER, k) * factors["friction"]
                for k in ("us_pos", "us_neg", "uc_pos", "uc_neg")
            }
        ),
    )
    np.testing.assert_allclose(row, scaled, rtol=1e-15)
    assert gain == 1.0
    assert DomainRandomization.from_spec(None) is None
    with pytest.raises(TypeError, match="randomize must be"):
        DomainRandomization.from_spec([0.5, 1.5])
    with pytest.raises(ValueError, match="pair of factors"):
        DomainRandomization(inertia=1.0)
