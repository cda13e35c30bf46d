"""Number checks shared by the package, with one error style: what is wrong, what to give.

:func:`real_number` checks one value (an argument, an option); :func:`check_finite`,
:func:`check_positive` and :func:`check_nonnegative` check named fields of a dataclass and
name the class in the message, e.g. ``PlantParams.inertia must be > 0, got -1.0``. A value
that is not a real number (``bool`` included) raises ``TypeError``, a real number that breaks
the rule ``ValueError``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from typing import Literal

#: The largest seed every library we seed takes (numpy's legacy ``np.random.seed``, which
#: Stable-Baselines3 calls, stops at 2**32 - 1).
MAX_SEED = 2**32 - 1

#: What a number must be besides finite.
Rule = Literal["finite", ">= 0", "> 0"]


def real_number(
    name: str, value: object, rule: Rule = "finite", *, unit: str = "", hint: str = ""
) -> float:
    """Return ``value`` as a float, refused unless it is a finite real number obeying ``rule``.

    Parameters
    ----------
    name : str
        How the message names the value (``"dt"``, ``"LoopSpec.dt"``, ``"--horizon"``).
    value : object
        The value given.
    rule : {"finite", ">= 0", "> 0"}, default "finite"
        The bound besides finiteness.
    unit : str, optional
        Appended to the bound in the message (``" s"``: "dt must be > 0 s").
    hint : str, optional
        Appended to the message: how to fix it, where that is not plain from the rule.

    Raises
    ------
    TypeError
        ``value`` is not a real number (``bool`` is refused: ``True`` is a bug more often
        than a 1).
    ValueError
        It is NaN, infinite, too large for a float or breaks ``rule``.
    """
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        raise TypeError(
            f"{name} must be a real number, got {value!r} ({type(value).__name__}){hint}"
        )
    try:
        number = float(value)
    except OverflowError:  # an integer beyond the float range, such as 10**400
        raise ValueError(f"{name} must be finite, got an integer too large for a float") from None
    if not math.isfinite(number):
        raise ValueError(f"{name} must be finite, got {value!r}{hint}")
    if (rule == ">= 0" and number < 0.0) or (rule == "> 0" and number <= 0.0):
        raise ValueError(f"{name} must be {rule}{unit}, got {value!r}{hint}")
    return number


def check_seed(value: int, option: str = "--seed") -> None:
    """Raise ``ValueError`` unless ``value`` can seed numpy, gymnasium and SB3 (0..2**32 - 1)."""
    if not 0 <= value <= MAX_SEED:
        raise ValueError(f"{option} must be a whole number from 0 to {MAX_SEED}, got {value}")


def check_finite(obj: object, *names: str) -> None:
    """Raise unless every named field of ``obj`` is a finite real number."""
    for name in names:
        real_number(f"{type(obj).__name__}.{name}", getattr(obj, name))


def check_nonnegative(
    obj: object, *names: str, hint: Callable[[str, float], str] | None = None
) -> None:
    """Raise unless every named field is a finite number >= 0; ``hint(name, value)`` may advise."""
    for name in names:
        value = getattr(obj, name)
        try:
            real_number(f"{type(obj).__name__}.{name}", value, ">= 0")
        except ValueError as error:
            if hint is None or not -math.inf < value < 0.0:  # advise on finite numbers only
                raise
            raise ValueError(f"{error}{hint(name, value)}") from None


def check_positive(obj: object, *names: str) -> None:
    """Raise unless every named field is a finite number > 0."""
    for name in names:
        real_number(f"{type(obj).__name__}.{name}", getattr(obj, name), "> 0")
