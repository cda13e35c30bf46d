"""Field checks shared by the parameter dataclasses (friction laws, plants, controllers).

Each check names the class and the field in its message, e.g.
``PlantParams.inertia must be > 0, got -1.0``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable

#: The largest seed every library we seed takes (numpy's legacy ``np.random.seed``, which
#: Stable-Baselines3 calls, stops at 2**32 - 1).
MAX_SEED = 2**32 - 1


def check_finite(obj: object, *names: str) -> None:
    """Raise unless every named field is a real, finite number (``TypeError``/``ValueError``)."""
    for name in names:
        value = getattr(obj, name)
        if not isinstance(value, numbers.Real) or isinstance(value, bool):
            raise TypeError(f"{type(obj).__name__}.{name} must be a real number, got {value!r}")
        if not math.isfinite(float(value)):
            raise ValueError(f"{type(obj).__name__}.{name} must be finite, got {value!r}")


def check_nonnegative(
    obj: object, *names: str, hint: Callable[[str, float], str] | None = None
) -> None:
    """Raise ``ValueError`` unless every named field is >= 0; ``hint`` may add advice."""
    for name in names:
        value = getattr(obj, name)
        if value < 0.0:
            extra = hint(name, value) if hint is not None else ""
            raise ValueError(f"{type(obj).__name__}.{name} must be >= 0, got {value!r}{extra}")


def check_positive(obj: object, *names: str) -> None:
    """Raise ``ValueError`` unless every named field is > 0."""
    for name in names:
        value = getattr(obj, name)
        if value <= 0.0:
            raise ValueError(f"{type(obj).__name__}.{name} must be > 0, got {value!r}")
