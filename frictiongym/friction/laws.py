"""Friction laws behind one interface.

Every law is a frozen dataclass of parameters validated on construction. Friction is
expressed in the plant's *command* units (volts for the servo, motor-command units for the
Altino), as in the paper: a friction of 0.21 V is the input needed to overcome it.

Sign convention: levels are **magnitudes** in both directions. The paper writes
``u_s- = -0.190 V``; here that is ``us_neg=0.190``.

=====================  =========================================================================
law                    sliding friction ``F(v)`` (``s = sign(v)``); at rest
=====================  =========================================================================
:class:`NoFriction`    0; the body moves under any input
:class:`CoulombViscous`  ``s*u_c,s + b*v``; stuck while ``-u_c,- <= u <= u_c,+``
:class:`StictionCoulomb`  ``s*[u_c,s + (u_s,s - u_c,s)*phi(|v|/v0_s)] + b*v`` (the paper's law);
                       stuck while ``-u_s,- <= u <= u_s,+``
:class:`LuGre`         ``sigma0*z + sigma1*dz/dt + b*v``, bristle state ``z`` (Canudas de Wit
                       et al. 1995); steady state is the Gaussian Stribeck curve
=====================  =========================================================================
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
import numpy.typing as npt

from frictiongym._validation import check_nonnegative, check_positive, real_number
from frictiongym.friction import _core

Shape = Literal["step", "linear", "smooth", "exponential"]
ArrayLike = float | npt.ArrayLike


def _magnitude_hint(name: str, value: float) -> str:
    if name.endswith("_neg"):
        return f" (levels are magnitudes: write {name}={-value!r}, not {value!r})"
    return ""


def _check_levels(obj: object, *names: str) -> None:
    """Check the named fields are finite and >= 0 (the magnitude hint), then ``uc <= us``."""
    check_nonnegative(obj, *names, hint=_magnitude_hint)
    for direction in ("pos", "neg"):
        us = getattr(obj, f"us_{direction}")
        uc = getattr(obj, f"uc_{direction}")
        if uc > us:
            raise ValueError(
                f"{type(obj).__name__}.uc_{direction}={uc!r} exceeds us_{direction}={us!r}: "
                f"the Coulomb level must not exceed the break-away level (uc_{direction} <= "
                f"us_{direction})"
            )


def _sliding_force(v: ArrayLike, p: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    return np.asarray(
        _core.sliding_force_ufunc(np.asarray(v, dtype=np.float64), *p[: _core.I_VISCOUS + 1])
    )


class FrictionModel(ABC):
    """Interface shared by all friction laws.

    Subclasses are frozen dataclasses; :meth:`row` packs them for the compiled plant kernel,
    and :meth:`force` evaluates the steady sliding curve with the very same compiled code.
    """

    #: Short name used by ``gym.make(..., friction=<name>)`` and in result files.
    name: ClassVar[str]

    @abstractmethod
    def row(self) -> npt.NDArray[np.float64]:
        """Pack the parameters into the float64 row read by the plant kernel."""

    @property
    @abstractmethod
    def breakaway(self) -> tuple[float, float]:
        """Break-away magnitudes ``(us_pos, us_neg)``.

        The body stays at rest while the input lies in ``[-us_neg, us_pos]``.
        """

    @property
    def is_dynamic(self) -> bool:
        """Whether the law has internal state (LuGre's bristle deflection)."""
        return False

    @property
    def exact(self) -> bool:
        """Whether the plant's closed-form (event-exact) step applies to this law."""
        return True

    def force(self, v: ArrayLike) -> npt.NDArray[np.float64]:
        """Steady sliding friction at velocity ``v``, including the viscous part.

        Vectorised over any shape. Zero at ``v == 0``, where friction is set-valued: the
        plant holds the body while the input lies in :attr:`breakaway`.
        """
        return _sliding_force(v, self.row())

    def nonlinear_force(self, v: ArrayLike) -> npt.NDArray[np.float64]:
        """:meth:`force` without the viscous term: the stiction/Coulomb part a compensator adds."""
        p = self.row()
        p[_core.I_VISCOUS] = 0.0
        return _sliding_force(v, p)

    def replace(self, **changes: float | str) -> FrictionModel:
        """Return a copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)  # type: ignore[type-var]

    def scaled(self, factor: float) -> FrictionModel:
        """Return a copy with every break-away and Coulomb level multiplied by ``factor``.

        Speeds, bristle parameters and the viscous slope are kept: this is the model-mismatch
        knob of a compensator (``factor=1.2`` over-estimates the friction by 20 %).
        """
        real_number("a friction scale factor", factor, ">= 0")
        levels = ("us_pos", "us_neg", "uc_pos", "uc_neg")
        return self.replace(**{f: getattr(self, f) * factor for f in levels if hasattr(self, f)})


@dataclass(frozen=True)
class NoFriction(FrictionModel):
    """No friction: the nominal plant."""

    name: ClassVar[str] = "none"

    def row(self) -> npt.NDArray[np.float64]:  # noqa: D102
        p = np.zeros(_core.ROW_SIZE)
        p[_core.I_V0_POS] = p[_core.I_V0_NEG] = 1.0
        return p

    @property
    def breakaway(self) -> tuple[float, float]:  # noqa: D102
        return (0.0, 0.0)


@dataclass(frozen=True)
class StictionCoulomb(FrictionModel):
    """The paper's stiction + Coulomb + viscous law, asymmetric.

    While sliding in direction ``s`` the nonlinear part decays from the break-away level
    ``u_s`` at rest to the Coulomb level ``u_c`` at speed ``v0`` with the chosen ``shape``; a
    viscous term ``viscous * v`` is added. At rest the body stays put while the input lies in
    ``[-us_neg, us_pos]``.

    Parameters
    ----------
    us_pos, us_neg : float
        Break-away (stiction) magnitudes, command units.
    uc_pos, uc_neg : float
        Coulomb magnitudes, command units (``uc <= us`` per direction).
    v0_pos, v0_neg : float
        Speed magnitude at which friction has decayed to ``uc``, plant velocity units.
    viscous : float, default 0.0
        Viscous slope, command units per velocity unit. Keep it 0 when the plant's own
        damping ``B`` already contains it (the paper's servo, where ``B_e`` does).
    shape : {"linear", "step", "smooth", "exponential"}, default "linear"
        Decay from ``u_s`` to ``u_c``: ``step`` drops to ``u_c`` as soon as the body moves;
        ``linear`` is ``1 - r``; ``smooth`` the quintic smoothstep; ``exponential`` a Stribeck
        ``exp(-ln(100) r)`` rescaled to reach ``u_c`` exactly at ``v0``. The paper gives the
        end points only; ``linear`` joins them with the fewest assumptions.
    """

    us_pos: float
    us_neg: float
    uc_pos: float
    uc_neg: float
    v0_pos: float
    v0_neg: float
    viscous: float = 0.0
    shape: Shape = "linear"

    name: ClassVar[str] = "paper"

    def __post_init__(self) -> None:
        check_positive(self, "v0_pos", "v0_neg")
        _check_levels(self, "us_pos", "us_neg", "uc_pos", "uc_neg", "viscous")
        if self.shape not in _core.SHAPES:
            raise ValueError(
                f"StictionCoulomb.shape must be one of {sorted(_core.SHAPES)}, got {self.shape!r}"
            )

    @property
    def exact(self) -> bool:
        """Closed form exists for the piecewise-affine shapes ``step`` and ``linear``."""
        return self.shape in ("step", "linear")

    def row(self) -> npt.NDArray[np.float64]:  # noqa: D102
        p = np.zeros(_core.ROW_SIZE)
        p[_core.I_LAW] = _core.LAW_STATIC
        p[_core.I_SHAPE] = _core.SHAPES[self.shape]
        p[_core.I_US_POS], p[_core.I_US_NEG] = self.us_pos, self.us_neg
        p[_core.I_UC_POS], p[_core.I_UC_NEG] = self.uc_pos, self.uc_neg
        p[_core.I_V0_POS], p[_core.I_V0_NEG] = self.v0_pos, self.v0_neg
        p[_core.I_VISCOUS] = self.viscous
        return p

    @property
    def breakaway(self) -> tuple[float, float]:  # noqa: D102
        return (self.us_pos, self.us_neg)


@dataclass(frozen=True)
class CoulombViscous(FrictionModel):
    """Coulomb + viscous friction: one level in each direction, no separate stiction.

    Parameters
    ----------
    uc_pos, uc_neg : float
        Coulomb magnitudes, command units; also the break-away levels.
    viscous : float, default 0.0
        Viscous slope, command units per velocity unit.
    """

    uc_pos: float
    uc_neg: float
    viscous: float = 0.0

    name: ClassVar[str] = "coulomb"

    def __post_init__(self) -> None:
        check_nonnegative(self, "uc_pos", "uc_neg", "viscous", hint=_magnitude_hint)

    def row(self) -> npt.NDArray[np.float64]:  # noqa: D102
        return StictionCoulomb(
            self.uc_pos, self.uc_neg, self.uc_pos, self.uc_neg, 1.0, 1.0, self.viscous, "step"
        ).row()

    @property
    def breakaway(self) -> tuple[float, float]:  # noqa: D102
        return (self.uc_pos, self.uc_neg)


@dataclass(frozen=True)
class LuGre(FrictionModel):
    """LuGre dynamic friction (Canudas de Wit, Olsson, Åström, Lischinsky 1995).

    ``dz/dt = v - sigma0 |v| z / g(v)``, ``F = sigma0 z + sigma1 dz/dt + viscous v``, with
    ``g(v) = u_c + (u_s - u_c) exp(-(v/v_s)^2)`` per direction. Pre-sliding displacement is
    about ``u_s / sigma0``; there is no exact stick, so a body under a load below break-away
    creeps slowly (Åström & Canudas de Wit 2008, "Revisiting the LuGre model", IEEE Control
    Systems Magazine 28(6)).

    Parameters
    ----------
    us_pos, us_neg, uc_pos, uc_neg : float
        Break-away and Coulomb magnitudes, command units.
    vs_pos, vs_neg : float
        Stribeck velocities, plant velocity units.
    sigma0 : float
        Bristle stiffness, command units per position unit.
    sigma1 : float
        Bristle damping, command units per velocity unit.
    viscous : float, default 0.0
        Viscous slope ``sigma2``.
    """

    us_pos: float
    us_neg: float
    uc_pos: float
    uc_neg: float
    vs_pos: float
    vs_neg: float
    sigma0: float
    sigma1: float
    viscous: float = 0.0

    name: ClassVar[str] = "lugre"

    def __post_init__(self) -> None:
        check_positive(self, "vs_pos", "vs_neg", "sigma0")
        _check_levels(self, "us_pos", "us_neg", "uc_pos", "uc_neg", "sigma1", "viscous")
        if self.uc_pos == 0.0 or self.uc_neg == 0.0:
            raise ValueError(
                "LuGre.uc_pos and LuGre.uc_neg must be > 0: the bristle time constant "
                "sigma0*|v|/g(v) divides by the Coulomb level"
            )

    @property
    def is_dynamic(self) -> bool:  # noqa: D102
        return True

    @property
    def exact(self) -> bool:  # noqa: D102
        return False

    def row(self) -> npt.NDArray[np.float64]:  # noqa: D102
        p = np.zeros(_core.ROW_SIZE)
        p[_core.I_LAW] = _core.LAW_LUGRE
        p[_core.I_US_POS], p[_core.I_US_NEG] = self.us_pos, self.us_neg
        p[_core.I_UC_POS], p[_core.I_UC_NEG] = self.uc_pos, self.uc_neg
        p[_core.I_V0_POS], p[_core.I_V0_NEG] = self.vs_pos, self.vs_neg
        p[_core.I_VISCOUS] = self.viscous
        p[_core.I_SIGMA0], p[_core.I_SIGMA1] = self.sigma0, self.sigma1
        return p

    @property
    def breakaway(self) -> tuple[float, float]:  # noqa: D102
        return (self.us_pos, self.us_neg)
