"""Scalar friction physics, compiled once and shared by every caller.

The plant kernel (:mod:`frictiongym.plants._kernel`) calls these functions element by element;
:func:`sliding_force_ufunc` wraps the same function as a NumPy ufunc, so a friction curve
evaluated for a plot, a compensator or an identification fit is bit-for-bit the curve the
simulated plant feels.

A friction model is packed into a float64 *row* (see the ``I_*`` indices below) so the
compiled kernel can hold a different model for every plant of a batch.
"""

from __future__ import annotations

import math

from numba import njit

from frictiongym._ufunc import float64_ufunc

# Law codes.
LAW_STATIC = 0  #: memoryless curve + explicit stick state (none, Coulomb, the paper's law)
LAW_LUGRE = 1  #: LuGre dynamic model (bristle state z)

# Decay shapes phi(r), r = |v| / v0, phi(0) = 1 and phi(r >= 1) = 0.
SHAPE_STEP = 0
SHAPE_LINEAR = 1
SHAPE_SMOOTH = 2
SHAPE_EXPONENTIAL = 3
SHAPES = {
    "step": SHAPE_STEP,
    "linear": SHAPE_LINEAR,
    "smooth": SHAPE_SMOOTH,
    "exponential": SHAPE_EXPONENTIAL,
}

# Row layout of a packed friction model.
I_LAW = 0
I_SHAPE = 1
I_US_POS = 2
I_US_NEG = 3
I_UC_POS = 4
I_UC_NEG = 5
I_V0_POS = 6  #: v0 for the static law, Stribeck velocity v_s for LuGre
I_V0_NEG = 7
I_VISCOUS = 8
I_SIGMA0 = 9
I_SIGMA1 = 10
ROW_SIZE = 11

# Exponential decay normalised to reach exactly 0 at r = 1; without the normalisation it
# would be 1 % of (u_s - u_c) there (exp(-ln 100) = 0.01).
_EXP_RATE = math.log(100.0)
_EXP_FLOOR = math.exp(-_EXP_RATE)


@njit(cache=True)
def decay(r: float, shape: int) -> float:
    """Decay shape phi(r) from the break-away level (phi = 1) to the Coulomb level (phi = 0).

    Parameters
    ----------
    r : float
        Speed over the decay speed, ``|v| / v0`` (>= 0).
    shape : int
        One of the ``SHAPE_*`` codes.

    Returns
    -------
    float
        phi(r), with phi(0) = 1 and phi(r) = 0 for r >= 1 for every shape.
    """
    if r >= 1.0:
        return 0.0
    if shape == SHAPE_STEP:
        return 1.0 if r == 0.0 else 0.0
    if shape == SHAPE_LINEAR:
        return 1.0 - r
    if shape == SHAPE_SMOOTH:  # quintic smoothstep, C2 at both ends
        return 1.0 - r * r * r * (10.0 - r * (15.0 - 6.0 * r))
    return (math.exp(-_EXP_RATE * r) - _EXP_FLOOR) / (1.0 - _EXP_FLOOR)


@njit(cache=True)
def level(speed: float, law: float, shape: float, us: float, uc: float, v0: float) -> float:
    """Magnitude of the nonlinear (stiction/Coulomb) friction while sliding in one direction.

    Parameters
    ----------
    speed : float
        ``|v|`` (>= 0).
    law, shape : float
        ``LAW_*`` and ``SHAPE_*`` codes (floats, as stored in a packed row).
    us, uc, v0 : float
        Break-away level, Coulomb level and decay speed of that direction (for LuGre,
        ``v0`` is the Stribeck velocity ``v_s``).

    Returns
    -------
    float
        ``u_c + (u_s - u_c) * phi(speed / v0)`` for the static law; the Gaussian Stribeck
        curve ``u_c + (u_s - u_c) * exp(-(speed / v_s)**2)`` for LuGre.
    """
    if us == uc:
        return uc
    if law == LAW_LUGRE:
        q = speed / v0
        return uc + (us - uc) * math.exp(-q * q)
    return uc + (us - uc) * decay(speed / v0, int(shape))


@njit(cache=True)
def sliding_level(speed: float, direction: float, p: tuple[float, ...]) -> float:
    """:func:`level` for the direction ``direction`` (+1.0 or -1.0) of the packed row ``p``."""
    if direction > 0.0:
        return level(speed, p[I_LAW], p[I_SHAPE], p[I_US_POS], p[I_UC_POS], p[I_V0_POS])
    return level(speed, p[I_LAW], p[I_SHAPE], p[I_US_NEG], p[I_UC_NEG], p[I_V0_NEG])


@float64_ufunc(10)
def sliding_force_ufunc(
    v: float,
    law: float,
    shape: float,
    us_pos: float,
    us_neg: float,
    uc_pos: float,
    uc_neg: float,
    v0_pos: float,
    v0_neg: float,
    viscous: float,
) -> float:
    """Steady sliding friction at velocity ``v`` (ufunc over any broadcast shape).

    Zero at ``v == 0``, where static friction is set-valued and decided by the plant.
    """
    if v == 0.0:
        return 0.0
    if v > 0.0:
        return level(v, law, shape, us_pos, uc_pos, v0_pos) + viscous * v
    return -level(-v, law, shape, us_neg, uc_neg, v0_neg) + viscous * v
