"""Friction presets with the paper's identified numbers, and construction by name.

The numbers are read from the built-in devices' description files
(``frictiongym/data/devices/*.toml``), which give their source: the paper, *Performance
Enhancement of Motion Control Systems Through Friction Identification and Compensation* (§4.1,
Fig. 8(b) for the servo; §4.2, Fig. 10(b) for the Altino), unless marked *assumed*.
"""

from __future__ import annotations

from frictiongym.data import device_table
from frictiongym.friction.laws import (
    CoulombViscous,
    FrictionModel,
    LuGre,
    NoFriction,
    StictionCoulomb,
)

_SERVO, _ALTINO = device_table("rotary"), device_table("altino")

#: QUBE-Servo 2, volts vs rad/s (paper Fig. 8(b)); its viscous slope is in the plant's B_e.
ROTARY_PAPER = StictionCoulomb(**_SERVO["friction"])
#: Altino, motor-command units vs cm/s (paper Fig. 10(b)), viscous slope 10.93 units/(cm/s).
ALTINO_PAPER = StictionCoulomb(**_ALTINO["friction"])
#: LuGre versions of the same levels (Stribeck velocities within 1 % of u_c at the paper's v0;
#: sigma0 and sigma1 *assumed*: the files give the reasons).
ROTARY_LUGRE = LuGre(**_SERVO["lugre"])
ALTINO_LUGRE = LuGre(**_ALTINO["lugre"])


FRICTION_NAMES = ("paper", "none", "coulomb", "stribeck", "lugre")


def friction_from_name(name: str, paper: StictionCoulomb, lugre: LuGre) -> FrictionModel:
    """Build one of the named friction variants from a preset.

    Parameters
    ----------
    name : {"paper", "none", "coulomb", "stribeck", "lugre"}
        ``paper``: the paper's law as given; ``none``: no friction; ``coulomb``: the paper's
        Coulomb levels and viscous slope without stiction; ``stribeck``: the paper's levels
        with an exponential (Stribeck) decay; ``lugre``: the LuGre preset.
    paper, lugre : StictionCoulomb, LuGre
        The plant's presets.

    Returns
    -------
    FrictionModel
    """
    if name not in FRICTION_NAMES:
        raise ValueError(
            f"unknown friction law {name!r}; choose one of {', '.join(FRICTION_NAMES)} or pass "
            "a FrictionModel object"
        )
    return {
        "paper": paper,
        "none": NoFriction(),
        "coulomb": CoulombViscous(paper.uc_pos, paper.uc_neg, paper.viscous),
        "stribeck": paper.replace(shape="exponential"),
        "lugre": lugre,
    }[name]
