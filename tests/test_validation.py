"""The package's number checks (frictiongym._validation): one rule set, one message style."""

import dataclasses
import math
from fractions import Fraction

import numpy as np
import pytest

from frictiongym._validation import check_finite, check_nonnegative, check_positive, real_number
from frictiongym.controllers import LoopSpec
from frictiongym.hardware.guard import CarBounds
from frictiongym.tuning.specs import StepSpecs


@dataclasses.dataclass
class Fields:
    a: object = 1.0
    b: object = 2.0


@pytest.mark.parametrize("value", [0, 2.5, np.float32(1.5), np.int64(3), Fraction(1, 3)])
def test_real_numbers_of_every_kind_are_taken_as_floats(value):
    assert real_number("x", value) == float(value)
    assert type(real_number("x", value)) is float


@pytest.mark.parametrize(
    ("value", "rule", "error", "message"),
    [
        ("1", "finite", TypeError, "x must be a real number, got '1' (str)"),
        (True, "finite", TypeError, "x must be a real number, got True (bool)"),
        (None, "> 0", TypeError, "x must be a real number, got None (NoneType)"),
        (math.nan, "finite", ValueError, "x must be finite, got nan"),
        (-math.inf, ">= 0", ValueError, "x must be finite, got -inf"),
        (10**400, "finite", ValueError, "x must be finite, got an integer too large for a float"),
        (-1.0, ">= 0", ValueError, "x must be >= 0, got -1.0"),
        (0.0, "> 0", ValueError, "x must be > 0, got 0.0"),
    ],
)
def test_a_bad_number_is_named_with_the_rule_it_breaks(value, rule, error, message):
    with pytest.raises(error) as caught:
        real_number("x", value, rule)
    assert str(caught.value) == message


def test_unit_and_hint_complete_the_message():
    with pytest.raises(ValueError, match=r"^dt must be > 0 s, got -0.1 \(the control period\)$"):
        real_number("dt", -0.1, "> 0", unit=" s", hint=" (the control period)")
    assert real_number("dt", 0.0, ">= 0", unit=" s") == 0.0


def test_field_checks_name_the_class_and_refuse_nan_and_infinity():
    check_finite(Fields(), "a", "b")
    with pytest.raises(TypeError, match=r"^Fields.b must be a real number, got 'x' \(str\)$"):
        check_finite(Fields(b="x"), "a", "b")
    # NaN compares false with every bound: a check by comparison alone let it through.
    with pytest.raises(ValueError, match=r"^Fields.a must be finite, got nan$"):
        check_positive(Fields(a=math.nan), "a")
    with pytest.raises(ValueError, match=r"^Fields.a must be finite, got inf$"):
        check_nonnegative(Fields(a=math.inf), "a")
    with pytest.raises(ValueError, match=r"^Fields.b must be >= 0, got -2 \(b: -2\)$"):
        check_nonnegative(Fields(b=-2), "a", "b", hint=lambda name, value: f" ({name}: {value})")


def test_the_package_uses_them_for_its_settings():
    with pytest.raises(ValueError, match=r"^LoopSpec.dt must be > 0 s, got -0.002$"):
        LoopSpec(-0.002, 10.0)
    with pytest.raises(ValueError, match=r"^LoopSpec.rest_speed must be finite, got nan$"):
        LoopSpec(0.002, 10.0, rest_speed=math.nan)
    with pytest.raises(TypeError, match=r"^StepSpecs.rise_time must be a real number"):
        StepSpecs(rise_time="0.05")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"^CarBounds.friction must be >= 0, got -1 \(0: none\)$"):
        CarBounds(friction=-1)
