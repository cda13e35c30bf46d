"""Domain randomisation: plant, friction and sensor factors drawn at every reset."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace

import numpy as np
import numpy.typing as npt

from frictiongym.plants import _kernel as plant_kernel
from frictiongym.plants.plant import PlantParams

FloatArray = npt.NDArray[np.float64]
Range = tuple[float, float]


@dataclass(frozen=True)
class DomainRandomization:
    """Ranges of multiplicative factors, each drawn uniformly at every reset.

    A field left at ``None`` is not randomised (and draws nothing from the generator). Draws
    happen in the order of the fields, from the env's ``np_random``.

    Parameters
    ----------
    friction : (float, float), optional
        Factor on every friction level (break-away ``u_s±`` and Coulomb ``u_c±`` together, so
        ``u_c <= u_s`` still holds).
    inertia : (float, float), optional
        Factor on the inertia (servo) or mass (Altino) ``J``.
    damping : (float, float), optional
        Factor on the linear damping: the plant's ``B`` and the friction law's viscous slope.
    sensor_gain : (float, float), optional
        Factor on the sensor: the encoder's scale (a calibration error) for the servo, the IR
        reflectivity for the Altino.
    deadzone : (float, float), optional
        Factor on the actuator's dead zone (the env's ``deadzone=``, which must be set). Drawn
        after the other factors, which a seed therefore draws as before; a random reference
        and the noise seed, drawn after every factor, change.
    backlash : (float, float), optional
        Factor on the play between motor and load (the env's ``backlash=``, which must be
        set). Drawn last of the factors, with the same consequence for later draws.

    Examples
    --------
    >>> DomainRandomization(friction=(0.5, 1.5), inertia=(0.9, 1.1))  # doctest: +SKIP
    """

    friction: Range | None = None
    inertia: Range | None = None
    damping: Range | None = None
    sensor_gain: Range | None = None
    deadzone: Range | None = None
    backlash: Range | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            bounds = getattr(self, f.name)
            if bounds is None:
                continue
            try:
                low, high = (float(b) for b in bounds)
            except (TypeError, ValueError):
                raise ValueError(
                    f"DomainRandomization.{f.name} must be a (low, high) pair of factors, "
                    f"got {bounds!r}"
                ) from None
            if not (math.isfinite(low) and math.isfinite(high) and 0.0 < low <= high):
                raise ValueError(
                    f"DomainRandomization.{f.name}={bounds!r} must satisfy 0 < low <= high "
                    "(factors on the nominal value, e.g. (0.8, 1.2))"
                )
            object.__setattr__(self, f.name, (low, high))

    @classmethod
    def from_spec(cls, spec: object) -> DomainRandomization | None:
        """Accept ``None``, a :class:`DomainRandomization` or a mapping of its fields."""
        if spec is None or isinstance(spec, DomainRandomization):
            return spec
        if isinstance(spec, Mapping):
            names = {f.name for f in fields(cls)}
            unknown = set(spec) - names
            if unknown:
                raise ValueError(
                    f"unknown randomisation keys {sorted(unknown)}; use {sorted(names)}"
                )
            return cls(**spec)
        raise TypeError(
            f"randomize must be None, a dict or a DomainRandomization, got {spec!r} "
            "(e.g. randomize={'friction': (0.8, 1.2)})"
        )

    def check(self, plant: PlantParams) -> None:
        """Refuse a range that scales what the plant lacks, or a zone up to the command limit."""
        if self.backlash is not None and plant.backlash == 0.0:
            raise ValueError(
                f"randomize backlash={self.backlash!r} scales the play between motor and load, "
                "and this plant has none: give the env backlash=... too (its nominal width)"
            )
        if self.deadzone is not None and plant.dead_zone == 0.0:
            raise ValueError(
                f"randomize deadzone={self.deadzone!r} scales the actuator's dead zone, and this "
                "plant has none: give the env deadzone=... too (its nominal half-width)"
            )
        if self.deadzone is not None and plant.dead_zone * self.deadzone[1] >= plant.command_limit:
            raise ValueError(
                f"randomize deadzone={self.deadzone!r} can widen the dead zone "
                f"({plant.dead_zone:g}) to the command limit ({plant.command_limit:g}), where "
                "no command drives the plant; lower the upper factor"
            )

    def lightest(self, plant: PlantParams) -> PlantParams:
        """Return ``plant`` at the least inertia a draw can give (it sets the substeps)."""
        if self.inertia is None:
            return plant
        return replace(plant, inertia=plant.inertia * self.inertia[0])

    def draw(self, rng: np.random.Generator) -> dict[str, float]:
        """One factor per randomised field, in field order."""
        drawn = {}
        for f in fields(self):
            bounds = getattr(self, f.name)
            if bounds is not None:
                drawn[f.name] = float(rng.uniform(bounds[0], bounds[1]))
        return drawn


def apply_factors(plant_row: FloatArray, factors: Mapping[str, float]) -> tuple[FloatArray, float]:
    """Scaled copy of a plant row, and the sensor-gain factor."""
    names = ("friction", "inertia", "damping", "deadzone", "backlash")
    scales = (factors.get(name, 1.0) for name in names)
    return plant_kernel.scale_row(plant_row, *scales), factors.get("sensor_gain", 1.0)
