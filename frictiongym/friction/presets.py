"""Friction presets with the paper's identified numbers, and construction by name.

Source of every number: the paper, *Performance Enhancement of Motion Control Systems Through
Friction Identification and Compensation* (§4.1, Fig. 8(b)
for the servo; §4.2, Fig. 10(b) for the Altino), unless marked *assumed*.
"""

from __future__ import annotations

import math

from frictiongym.friction.laws import (
    CoulombViscous,
    FrictionModel,
    LuGre,
    NoFriction,
    StictionCoulomb,
)

#: Ratio v0 / v_s of a Gaussian Stribeck curve that is within 1 % of u_c at v0
#: (exp(-(v0/v_s)^2) = 0.01 gives v_s = v0 / 2.146).
_GAUSS_V0_OVER_VS = math.sqrt(math.log(100.0))

#: QUBE-Servo 2, volts vs rad/s (paper Fig. 8(b)). The viscous slope 0.0411 V/(rad/s) is part
#: of the plant's B_e = 0.0446 V·s (paper §4.1), so it is not repeated here.
ROTARY_PAPER = StictionCoulomb(
    us_pos=0.210,
    us_neg=0.190,
    uc_pos=0.124,
    uc_neg=0.104,
    v0_pos=3.015,
    v0_neg=2.530,
    viscous=0.0,
    shape="linear",
)

#: Altino, motor-command units vs cm/s (paper Fig. 10(b)), viscous slope 10.93 units/(cm/s).
ALTINO_PAPER = StictionCoulomb(
    us_pos=200.0,
    us_neg=200.0,
    uc_pos=150.4,
    uc_neg=119.6,
    v0_pos=13.8,
    v0_neg=10.9,
    viscous=10.93,
    shape="linear",
)

#: LuGre versions of the same levels. Stribeck velocities put the Gaussian within 1 % of u_c at
#: the paper's v0. sigma0 and sigma1 are *assumed*: a pre-sliding deflection u_s/sigma0 below
#: one encoder count (2.1 mrad < 3.07 mrad) and a critically damped bristle mode with J_e.
ROTARY_LUGRE = LuGre(
    us_pos=0.210,
    us_neg=0.190,
    uc_pos=0.124,
    uc_neg=0.104,
    vs_pos=3.015 / _GAUSS_V0_OVER_VS,
    vs_neg=2.530 / _GAUSS_V0_OVER_VS,
    sigma0=100.0,
    sigma1=2.0 * math.sqrt(100.0 * 7.143e-3),
    viscous=0.0,
)

#: Altino, same construction. sigma0 and sigma1 are *assumed* (docs/altino-model.md): a
#: pre-sliding deflection u_s/sigma0 = 200/4000 = 0.05 cm at break-away (tyre and gear-train
#: compliance; about two IR counts at the 5 cm target, where one count is 0.026 cm) and a
#: critically damped bristle mode with the 2.2 units·s²/cm mass of ``ALTINO_PLANT`` (written
#: as a literal, like J_e above, so this module does not import the plant package).
ALTINO_LUGRE = LuGre(
    us_pos=200.0,
    us_neg=200.0,
    uc_pos=150.4,
    uc_neg=119.6,
    vs_pos=13.8 / _GAUSS_V0_OVER_VS,
    vs_neg=10.9 / _GAUSS_V0_OVER_VS,
    sigma0=4000.0,
    sigma1=2.0 * math.sqrt(4000.0 * 2.2),
    viscous=10.93,
)


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
