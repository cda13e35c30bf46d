"""Pluggable friction laws (see :mod:`frictiongym.friction.laws`) and the paper's presets."""

from frictiongym.friction.laws import (
    CoulombViscous,
    FrictionModel,
    LuGre,
    NoFriction,
    StictionCoulomb,
)
from frictiongym.friction.presets import (
    ALTINO_LUGRE,
    ALTINO_PAPER,
    FRICTION_NAMES,
    ROTARY_LUGRE,
    ROTARY_PAPER,
    friction_from_name,
)

__all__ = [
    "ALTINO_LUGRE",
    "ALTINO_PAPER",
    "FRICTION_NAMES",
    "ROTARY_LUGRE",
    "ROTARY_PAPER",
    "CoulombViscous",
    "FrictionModel",
    "LuGre",
    "NoFriction",
    "StictionCoulomb",
    "friction_from_name",
]
