"""Identified device parameters: the ``friction.json`` file, its validation, saving and loading.

Identification writes one JSON object per device; ``gym.make(id, params=PATH)`` simulates it
and ``FrictionCompensator(base, model=PATH)`` compensates with it. A file of the paper's servo:

.. code-block:: json

    {
      "us_pos": 0.21, "us_neg": 0.19, "uc_pos": 0.124, "uc_neg": 0.104,
      "v0_pos": 3.015, "v0_neg": 2.53, "viscous": 0.0411,
      "J": 0.007143, "B": 0.0446, "law": "paper", "shape": "linear",
      "device": "RotaryServo", "env_id": "frictiongym/RotaryServo-v1",
      "units": {"force": "V", "velocity": "rad/s", "viscous": "V·s/rad", "J": "V·s²/rad",
                "B": "V·s/rad"},
      "uncertainty": {"us_pos": 0.004}, "metadata": {"date": "2024-05-01"},
      "format": "frictiongym.params/1"
    }

Required: the seven friction keys of :data:`PARAM_KEYS` (command units; levels are
magnitudes, ``>= 0``, as in :class:`~frictiongym.friction.StictionCoulomb`), ``J``, ``B`` and
``law`` (``"paper"``, ``"stribeck"`` or ``"coulomb"``). Optional: ``shape`` (the decay of
``paper``, default ``"linear"``; ``stribeck`` is ``exponential``), ``backlash`` (a play between
motor and load, :class:`Backlash`: ``{"width": W, "load_inertia": psi, "load_friction": phi}``
in position units and shares; ``frictiongym identify --backlash`` writes it), ``device`` (the
``Device.name`` it was identified on), ``env_id``, ``units``, ``uncertainty`` (standard errors,
same units; ``backlash`` for the play's width) and free-form ``metadata``. A file without
``backlash`` is a rigid drivetrain, as before the key existed. ``dead_zone`` (the actuator's
dead-zone half-width, command units; ``frictiongym identify --dead-zone`` writes it) makes the
levels the friction's own, below what the body shows while driven by the zone's width. For
``coulomb`` ``us_*`` equal ``uc_*`` or are null and ``v0_*`` may be null (no stiction, no
decay).

**B and viscous.** ``B`` is the *total* linear damping the plant sees: the paper's ``B_e`` of
Eq. (2), which includes the viscous slope of the friction map (paper §4.1). ``viscous`` is
that slope as fitted and reported (Fig. 8(b): 0.0411 V/(rad/s) beside ``B_e`` = 0.0446 V·s),
kept for the record but **not added a second time**: a loaded file simulates a plant of
damping ``B`` with the law's ``viscous`` set to 0 (:meth:`DeviceParams.plant_friction`). So the
Altino preset (plant damping 0, law viscous 10.93) is the file ``B = viscous = 10.93``.
"""

from __future__ import annotations

import copy
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from frictiongym import devices
from frictiongym._io import write_text_atomic
from frictiongym._validation import Rule, real_number
from frictiongym.devices import DEVICES, Device
from frictiongym.friction import CoulombViscous, FrictionModel, StictionCoulomb, friction_from_name
from frictiongym.friction import _core as friction_core
from frictiongym.plants.plant import PlantParams

__all__ = [
    "FILE_NAME",
    "FORMAT",
    "LAWS",
    "PARAM_KEYS",
    "Backlash",
    "DeviceParams",
    "ParamsFileError",
    "device_physics",
    "load_params",
    "resolve_params",
    "save_params",
]

#: The friction keys of a params file, in the order the file lists them.
PARAM_KEYS = ("us_pos", "us_neg", "uc_pos", "uc_neg", "v0_pos", "v0_neg", "viscous")
#: Every key a file must hold.
REQUIRED_KEYS = (*PARAM_KEYS, "J", "B", "law")
#: Optional keys, in file order after the required ones.
OPTIONAL_KEYS = (
    "shape",
    "backlash",
    "dead_zone",
    "device",
    "env_id",
    "units",
    "uncertainty",
    "metadata",
    "format",
)
#: Keys of the ``backlash`` object, in file order.
BACKLASH_KEYS = ("width", "load_inertia", "load_friction")
#: Keys an ``uncertainty`` may hold.
UNCERTAINTY_KEYS = (*PARAM_KEYS, "J", "B", "backlash", "dead_zone")
#: Version tag written into every file.
FORMAT = "frictiongym.params/1"
#: The name of the file inside a results directory.
FILE_NAME = "friction.json"
#: Laws a file can hold (friction/laws.py names).
LAWS = ("paper", "stribeck", "coulomb")

#: The paper's servo (Eq. (2), Fig. 8(b)) as a minimal file, shown in error messages.
_EXAMPLE = (
    '{"us_pos": 0.21, "us_neg": 0.19, "uc_pos": 0.124, "uc_neg": 0.104, "v0_pos": 3.015, '
    '"v0_neg": 2.53, "viscous": 0.0411, "J": 0.007143, "B": 0.0446, "law": "paper"}'
)


#: The physically meaningful range of every parameter, in the file's units: twelve orders of
#: magnitude around both devices' values (servo J = 7.1e-3 V·s²/rad and levels near 0.2 V,
#: Altino J = 2.2 units·s²/cm and levels near 200 units). Inside it the plant's exact step
#: stays finite; outside it a value is a typo or a unit mistake (B = 1e308 made every
#: position NaN).
PARAM_LIMITS: dict[str, tuple[float, float]] = {
    "J": (1e-9, 1e6),
    "B": (0.0, 1e6),
    "viscous": (0.0, 1e6),
    **{f"{k}_{d}": (0.0, 1e6) for k in ("us", "uc") for d in ("pos", "neg")},
    **{f"v0_{d}": (1e-9, 1e6) for d in ("pos", "neg")},
    "backlash.width": (0.0, 1e6),
    "dead_zone": (0.0, 1e6),
}


class ParamsFileError(ValueError):
    """A params file (or mapping) that cannot be read, is incomplete or is invalid."""


def _json_value(value: Any) -> Any:
    """Metadata as JSON values: numpy as numbers and lists, NaN and infinities as null."""
    if isinstance(value, Mapping):
        return {k: _json_value(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_value(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, str | bytes):
        return _json_value(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None  # JSON has no NaN
    return value


def _fail(source: str, message: str) -> ParamsFileError:
    return ParamsFileError(f"{source}: {message}")


def _real(source: str, key: str, value: object, rule: Rule = ">= 0") -> float:
    """``value`` as a float, finite and ``>= 0`` (or ``> 0``), else :class:`ParamsFileError`."""
    negative = isinstance(value, int | float) and value < 0.0
    hint = (
        " (levels are magnitudes: drop the minus sign)" if negative and key.endswith("_neg") else ""
    )
    try:
        v = real_number(repr(key), value, rule, hint=hint)
    except (TypeError, ValueError) as error:
        raise _fail(source, str(error)) from None
    low, high = PARAM_LIMITS.get(key, (-math.inf, math.inf))
    if not low <= v <= high and not (v == 0.0 and rule == ">= 0"):
        raise _fail(
            source,
            f"{key!r} = {value!r} lies outside its physically meaningful range [{low:g}, "
            f"{high:g}] (in the device's units: V and rad, or motor units and cm); check the "
            "value and its units",
        )
    return v


def _optional_str(source: str, data: Mapping[str, Any], key: str) -> str | None:
    value = data.get(key)
    if value is not None and not isinstance(value, str):
        raise _fail(source, f"{key!r} must be a string or null, got {value!r}")
    return value


def _mapping(source: str, data: Mapping[str, Any], key: str) -> dict[str, Any]:
    value = data.get(key)
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise _fail(source, f"{key!r} must be a JSON object, got {value!r}")
    return dict(value)


def _friction(source: str, data: Mapping[str, Any], law: str) -> FrictionModel:
    """Build the law of a validated-complete mapping."""
    get = {k: data[k] for k in PARAM_KEYS}
    shape = data.get("shape")
    if law == "coulomb":
        if shape not in (None, "step"):
            raise _fail(source, f"law 'coulomb' has no decay shape; drop 'shape' ({shape!r})")
        uc = {d: _real(source, f"uc_{d}", get[f"uc_{d}"]) for d in ("pos", "neg")}
        for d in ("pos", "neg"):
            us = get[f"us_{d}"]
            if us is not None and _real(source, f"us_{d}", us) != uc[d]:
                raise _fail(
                    source,
                    f"law 'coulomb' has no stiction: us_{d}={us!r} must equal uc_{d}="
                    f"{uc[d]!r} or be null; use law 'paper' for a break-away level above it",
                )
            if get[f"v0_{d}"] is not None:
                _real(source, f"v0_{d}", get[f"v0_{d}"], "> 0")
        return CoulombViscous(uc["pos"], uc["neg"], _real(source, "viscous", get["viscous"]))
    if law == "stribeck":
        if shape not in (None, "exponential"):
            raise _fail(
                source, f"law 'stribeck' is the exponential decay; drop 'shape' ({shape!r})"
            )
        shape = "exponential"
    elif shape is None:
        shape = "linear"
    elif not isinstance(shape, str) or shape not in friction_core.SHAPES:
        raise _fail(source, f"'shape' must be one of {sorted(friction_core.SHAPES)}, got {shape!r}")
    v = {k: _real(source, k, get[k], "> 0" if k.startswith("v0") else ">= 0") for k in get}
    for d, word in (("pos", "positive"), ("neg", "negative")):
        if v[f"uc_{d}"] > v[f"us_{d}"]:
            raise _fail(
                source,
                f"uc_{d}={v[f'uc_{d}']!r} exceeds us_{d}={v[f'us_{d}']!r} in the {word} "
                f"direction: the Coulomb level must not exceed the break-away level",
            )
    return StictionCoulomb(**v, shape=shape)  # type: ignore[arg-type]  # checked above


def _backlash_values(
    source: str, width: object, load_inertia: object, load_friction: object
) -> tuple[float, float, float]:
    """Return a play's width and shares as floats, else raise naming the bad field."""
    checked = [_real(source, "backlash.width", width)]
    for key, value, low_open in (
        ("backlash.load_inertia", load_inertia, True),
        ("backlash.load_friction", load_friction, False),
    ):
        share = _real(source, key, value, "> 0" if low_open else ">= 0")
        if share >= 1.0 if low_open else share > 1.0:
            what = "the inertia" if low_open else "the friction and damping"
            interval = "strictly between 0 and 1" if low_open else "from 0 to 1"
            raise _fail(
                source,
                f"{key!r} = {value!r} is the load's share of {what}: give a fraction {interval}",
            )
        checked.append(share)
    return checked[0], checked[1], checked[2]


@dataclass(frozen=True)
class Backlash:
    """A play between the motor and the load, as a file's optional ``backlash`` object.

    The plant's :class:`~frictiongym.plants.plant.PlantParams` fields of the same meaning
    (docs/physics.md, "Backlash"). The shares are part of the estimate: the reversal test
    sees the play only through the motor's motion inside it, so a width holds for the shares
    it was estimated with (docs/identification.md).

    Parameters
    ----------
    width : float
        ``W``, the play's full width, position units (>= 0).
    load_inertia : float
        The load's share of ``J``, in (0, 1).
    load_friction : float
        The load's share of the friction law and of ``B``, in [0, 1].
    """

    width: float
    load_inertia: float
    load_friction: float

    def __post_init__(self) -> None:
        values = _backlash_values("Backlash", self.width, self.load_inertia, self.load_friction)
        for key, value in zip(BACKLASH_KEYS, values, strict=True):
            object.__setattr__(self, key, value)

    def to_dict(self) -> dict[str, float]:
        """Return the file's ``backlash`` object."""
        return {key: float(getattr(self, key)) for key in BACKLASH_KEYS}


def _backlash(source: str, data: Mapping[str, Any]) -> Backlash | None:
    """Return the file's ``backlash`` object, validated (None when absent or null)."""
    value = data.get("backlash")
    if value is None:
        return None
    example = '{"width": 0.0175, "load_inertia": 0.8, "load_friction": 0.0}'
    if not isinstance(value, Mapping):
        raise _fail(
            source,
            f"'backlash' must be a JSON object such as {example} (position units and the load's "
            f"shares), got {value!r}",
        )
    missing = [k for k in BACKLASH_KEYS if k not in value]
    unknown = sorted(set(value) - set(BACKLASH_KEYS))
    if missing or unknown:
        problem = f"lacks {', '.join(missing)}" if missing else f"has unknown keys {unknown}"
        raise _fail(source, f"'backlash' {problem}; it holds exactly {example}")
    return Backlash(*_backlash_values(source, *(value[k] for k in BACKLASH_KEYS)))


@dataclass(frozen=True)
class DeviceParams:
    """A device's identified friction and linear plant: the content of a ``friction.json``.

    Parameters
    ----------
    friction : FrictionModel
        The law as identified, with its fitted ``viscous`` slope (:class:`StictionCoulomb` for
        ``paper``/``stribeck``, :class:`CoulombViscous` for ``coulomb``).
    inertia : float
        ``J``, command units per acceleration unit (> 0).
    damping : float
        ``B``, the *total* linear damping (the paper's ``B_e``, viscous slope included), >= 0.
    law : {"paper", "stribeck", "coulomb"}
        The law's name in the file.
    device : str, optional
        ``Device.name`` it was identified on (``"RotaryServo"``, ``"AltinoDistance"``).
    env_id : str, optional
        Gymnasium id of that device's env.
    uncertainty : mapping of str to float, optional
        Standard errors of the keys of :data:`PARAM_KEYS`, ``"J"`` and ``"B"``, same units.
    metadata : mapping, optional
        Free-form, JSON-serialisable: experiments, residuals, software version, date (numpy
        values are written as numbers and lists, NaN and infinities as null).
    units : mapping of str to str, optional
        Units of the quantities (see :attr:`frictiongym.devices.Device.units`).
    backlash : Backlash, optional
        A play between motor and load (None: a rigid drivetrain); it needs a law with the
        event-exact step (``paper`` with a ``linear`` or ``step`` decay, or ``coulomb``).
    dead_zone : float, optional
        Half-width ``d`` of the actuator's dead zone, command units (None: the plant's own,
        none in the presets). The levels are then the friction's own: a zone adds ``d`` to
        every level the body shows while the command drives it (docs/physics.md).
    source : str, optional
        Where it was read from (for messages; not compared).
    """

    friction: FrictionModel
    inertia: float
    damping: float
    law: str
    device: str | None = None
    env_id: str | None = None
    uncertainty: Mapping[str, float] = field(default_factory=dict)
    metadata: Mapping[str, Any] = field(default_factory=dict)
    units: Mapping[str, str] = field(default_factory=dict)
    backlash: Backlash | None = None
    dead_zone: float | None = None
    source: str | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        where = self.source or "DeviceParams"
        if self.law not in LAWS:
            raise _fail(
                where, f"law {self.law!r} has no params-file form; supported: {', '.join(LAWS)}"
            )
        kind = CoulombViscous if self.law == "coulomb" else StictionCoulomb
        if type(self.friction) is not kind:
            raise _fail(
                where,
                f"law {self.law!r} needs a {kind.__name__}, got {self.friction!r}; a params file "
                f"stores {', '.join(LAWS)} only",
            )
        if self.law == "stribeck" and getattr(self.friction, "shape", None) != "exponential":
            raise _fail(where, "law 'stribeck' needs a StictionCoulomb with shape='exponential'")
        _real(where, "J", self.inertia, "> 0")
        _real(where, "B", self.damping)
        for key, value in self.uncertainty.items():
            if key not in UNCERTAINTY_KEYS:
                raise _fail(
                    where,
                    f"uncertainty of unknown key {key!r}; use {', '.join(UNCERTAINTY_KEYS)}",
                )
            _real(where, f"uncertainty.{key}", value)
        if self.backlash is not None:
            if not isinstance(self.backlash, Backlash):
                raise _fail(where, f"backlash must be a Backlash or None, got {self.backlash!r}")
            if self.backlash.width > 0.0 and not self.friction.exact:
                raise _fail(
                    where,
                    f"'backlash' needs a law with the event-exact step ('paper' with shape "
                    f"'linear' or 'step', or 'coulomb'), got law {self.law!r} with "
                    f"{self.friction!r}; drop 'backlash' or change the law",
                )
        if self.dead_zone is not None:
            object.__setattr__(self, "dead_zone", _real(where, "dead_zone", self.dead_zone))
            for device in (d for d in DEVICES if d.name == self.device):
                limit = device.plant.command_limit
                if self.dead_zone >= limit:
                    raise _fail(
                        where,
                        f"'dead_zone' = {self.dead_zone:g} reaches {device.name}'s command limit "
                        f"({limit:g} {device.command_unit}): no command would drive the plant; "
                        "check the value and its units",
                    )
        if not all(isinstance(k, str) and isinstance(u, str) for k, u in self.units.items()):
            raise _fail(where, f"'units' must map names to strings, got {dict(self.units)!r}")
        for name in ("uncertainty", "metadata", "units"):  # private copies: callers keep theirs
            object.__setattr__(self, name, copy.deepcopy(dict(getattr(self, name))))
        object.__setattr__(self, "inertia", float(self.inertia))
        object.__setattr__(self, "damping", float(self.damping))

    @classmethod
    def from_model(
        cls,
        friction: FrictionModel,
        *,
        inertia: float,
        damping: float,
        law: str | None = None,
        device: str | None = None,
        env_id: str | None = None,
        units: Mapping[str, str] | None = None,
        uncertainty: Mapping[str, float] | None = None,
        metadata: Mapping[str, Any] | None = None,
        backlash: Backlash | None = None,
        dead_zone: float | None = None,
    ) -> DeviceParams:
        """Wrap an identified law and linear plant (what identification calls).

        ``law`` defaults to ``friction.name`` (``StictionCoulomb`` of any shape is ``paper``);
        ``units`` to the device's (:attr:`frictiongym.devices.Device.units`) when ``device``
        names a built-in device or one read from its file in this process.
        """
        if units is None:
            known = [d.units for d in (*DEVICES, *devices.described()) if d.name == device]
            units = known[0] if known else {}
        return cls(
            friction,
            inertia,
            damping,
            law or friction.name,
            device,
            env_id,
            dict(uncertainty or {}),
            dict(metadata or {}),
            dict(units),
            backlash,
            dead_zone,
        )

    def plant(self, base: PlantParams) -> PlantParams:
        """Return ``base`` with this inertia and (total) damping; limit, lag, dead time kept.

        With :attr:`backlash`, also its play and shares, and with :attr:`dead_zone` its zone;
        without, ``base``'s are kept.
        """
        plant = replace(base, inertia=self.inertia, damping=self.damping)
        if self.dead_zone is not None:
            plant = replace(plant, dead_zone=self.dead_zone)
        if self.backlash is None:
            return plant
        return replace(
            plant,
            backlash=self.backlash.width,
            load_inertia=self.backlash.load_inertia,
            load_friction=self.backlash.load_friction,
        )

    def plant_friction(self) -> FrictionModel:
        """Return the law with ``viscous=0``: what a plant of damping ``B`` adds to it."""
        return self.friction.replace(viscous=0.0)

    def to_dict(self) -> dict[str, Any]:
        """Return the JSON mapping, in file order (the required keys first)."""
        f = self.friction
        out: dict[str, Any] = {}
        if isinstance(f, StictionCoulomb):
            out.update((k, float(getattr(f, k))) for k in PARAM_KEYS)
        elif isinstance(f, CoulombViscous):  # no stiction, no decay (checked on construction)
            pos, neg = float(f.uc_pos), float(f.uc_neg)
            out.update(us_pos=pos, us_neg=neg, uc_pos=pos, uc_neg=neg, v0_pos=None, v0_neg=None)
            out["viscous"] = float(f.viscous)
        out.update(J=self.inertia, B=self.damping, law=self.law)
        if isinstance(f, StictionCoulomb):
            out["shape"] = f.shape
        if self.backlash is not None:  # absent otherwise: files without a play are unchanged
            out["backlash"] = self.backlash.to_dict()
        if self.dead_zone is not None:  # likewise
            out["dead_zone"] = self.dead_zone
        out.update(device=self.device, env_id=self.env_id, units=dict(self.units))
        out.update(uncertainty=dict(self.uncertainty), metadata=_json_value(self.metadata))
        out["format"] = FORMAT
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "<mapping>") -> DeviceParams:
        """Validate a file's mapping and build the parameters.

        Raises
        ------
        ParamsFileError
            Naming ``source`` and the problem: missing or unknown keys, a wrong type, a
            non-finite or negative value, ``uc > us``, an unknown law or shape.
        """
        if not isinstance(data, Mapping):
            raise _fail(source, f"a params file holds one JSON object, got {type(data).__name__}")
        missing = [k for k in REQUIRED_KEYS if k not in data]
        if missing:
            raise _fail(
                source,
                f"missing keys {', '.join(missing)}. A params file looks like (friction in "
                f"command units, levels as magnitudes):\n  {_EXAMPLE}\nWrite one with "
                "`frictiongym identify --out DIR` or by hand",
            )
        unknown = sorted(set(data) - set(REQUIRED_KEYS) - set(OPTIONAL_KEYS))
        if unknown:
            raise _fail(
                source,
                f"unknown keys {', '.join(map(repr, unknown))}; the keys are "
                f"{', '.join(REQUIRED_KEYS + OPTIONAL_KEYS)} (put anything else in 'metadata')",
            )
        fmt = data.get("format", FORMAT)
        if fmt != FORMAT:
            raise _fail(source, f"format {fmt!r} is not {FORMAT!r}; update frictiongym")
        law = data["law"]
        if law not in LAWS:
            raise _fail(source, f"unknown law {law!r}; supported: {', '.join(LAWS)}")
        try:
            return cls(
                _friction(source, data, law),
                _real(source, "J", data["J"], "> 0"),
                _real(source, "B", data["B"]),
                law,
                _optional_str(source, data, "device"),
                _optional_str(source, data, "env_id"),
                _mapping(source, data, "uncertainty"),
                _mapping(source, data, "metadata"),
                _mapping(source, data, "units"),
                _backlash(source, data),
                None
                if data.get("dead_zone") is None
                else _real(source, "dead_zone", data["dead_zone"]),
                source,
            )
        except ParamsFileError:
            raise
        except (TypeError, ValueError) as err:
            raise _fail(source, str(err)) from None
        except RecursionError:  # deep-copying absurdly nested metadata
            raise _fail(source, "its metadata is nested too deeply to be a params file") from None


def load_params(path: str | os.PathLike[str]) -> DeviceParams:
    """Read and validate a params file (a directory means ``DIR/friction.json``).

    Raises
    ------
    ParamsFileError
        If the file is missing, unreadable, not JSON or not a valid params file.
    """
    given = Path(path)
    file = given / FILE_NAME if given.is_dir() else given
    source = str(file)
    if not file.exists():
        where = "directory has no friction.json" if given.is_dir() else "no such file"
        raise _fail(source, f"{where}; write one with `frictiongym identify --out DIR`")

    def no_constant(name: str) -> None:
        raise ValueError(f"{name} is not JSON; write numbers or null")

    try:
        data = json.loads(file.read_text(encoding="utf-8"), parse_constant=no_constant)
    except OSError as err:
        raise _fail(source, f"cannot read: {err.strerror or err}") from None
    except UnicodeDecodeError as err:
        raise _fail(source, f"not UTF-8 text ({err.reason}); is it a params file?") from None
    except ValueError as err:  # json.JSONDecodeError too
        raise _fail(source, f"not valid JSON: {err}") from None
    except RecursionError:
        raise _fail(source, "nested too deeply to be a params file") from None
    return DeviceParams.from_dict(data, source=source)


def save_params(path: str | os.PathLike[str], params: DeviceParams) -> Path:
    """Write ``params`` atomically as pretty JSON; return the file written.

    ``path`` ending in ``.json`` is the file; any other path is a directory (created if
    needed) that receives ``friction.json``. The file is replaced whole
    (:func:`frictiongym._io.write_text_atomic`): an error leaves an existing file untouched and
    no temporary file behind.

    Raises
    ------
    ParamsFileError
        If ``metadata`` holds something JSON cannot represent or the file cannot be written.
    """
    if not isinstance(params, DeviceParams):
        raise TypeError(f"save_params takes a DeviceParams, got {params!r}")
    p = Path(path)
    file = p / FILE_NAME if p.is_dir() or p.suffix.lower() != ".json" else p
    try:
        text = json.dumps(params.to_dict(), indent=2, ensure_ascii=False, allow_nan=False)
    except (TypeError, ValueError) as err:
        raise _fail(
            str(file), f"cannot write as JSON ({err}); keep metadata to JSON values"
        ) from None
    try:
        file.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(file, text + "\n")
    except OSError as err:
        raise _fail(str(file), f"cannot write: {err.strerror or err}") from None
    return file


def resolve_params(value: str | os.PathLike[str] | DeviceParams) -> DeviceParams:
    """``value`` if it is a :class:`DeviceParams`, else the file it names (:func:`load_params`)."""
    if isinstance(value, DeviceParams):
        return value
    if isinstance(value, str | os.PathLike):
        return load_params(value)
    raise TypeError(
        f"params must be a path to a friction.json (or its directory) or a DeviceParams, "
        f"got {value!r}"
    )


def device_physics(
    device: Device,
    dt: float,
    friction: str | FrictionModel | None = None,
    plant: PlantParams | None = None,
    params: str | os.PathLike[str] | DeviceParams | None = None,
    delay: float | None = None,
    deadzone: float | None = None,
    backlash: float | None = None,
    jitter: float | None = None,
) -> tuple[DeviceParams | None, FrictionModel, FrictionModel, PlantParams]:
    """Resolve the physics settings of a simulated ``device`` (an env's or the emulator's).

    ``params`` excludes ``plant`` and a ``friction`` other than ``"paper"`` (the default law,
    which the file's replaces); ``delay`` defaults to the device's dead time in whole periods of
    ``dt``, ``deadzone``, ``backlash`` and ``jitter`` to the plant's dead zone, play and
    latency jitter (none in the presets). Returns the file (or
    None), the plant's law (without the viscous slope a file puts in ``B``), the law a
    compensator models by default (the file's, else the paper preset) and the plant.
    """
    loaded = None
    if params is not None:
        pairs = (("friction", None if friction == "paper" else friction), ("plant", plant))
        given = [name for name, value in pairs if value is not None]
        if given:
            raise ValueError(
                f"params and {' and '.join(given)} both set the simulated physics; pick one: "
                "params=PATH (the identified file) or friction=/plant= (presets or objects)"
            )
        loaded = resolve_params(params)
        if loaded.device is not None and loaded.device != device.name:
            raise ParamsFileError(
                f"{loaded.source or 'params'}: identified on device {loaded.device!r}, but this "
                f"env simulates {device.name!r}; their units differ (identify this device, or "
                f"make the env of {loaded.device!r})"
            )
        friction, plant = loaded.plant_friction(), loaded.plant(device.plant)
    if isinstance(friction, str) or friction is None:
        law = "paper" if friction is None else friction
        friction = friction_from_name(law, device.paper_friction, device.lugre_friction)
    if not isinstance(friction, FrictionModel):
        raise TypeError(f"friction must be a law's name or a FrictionModel, got {friction!r}")
    nominal = device.plant if plant is None else plant
    if not isinstance(nominal, PlantParams):
        raise TypeError(f"plant must be a PlantParams, got {nominal!r}")
    if delay is None:  # the device's dead time, in whole periods of this dt
        delay = round(nominal.dead_time / dt) * dt
    dead_time = real_number("delay", delay, ">= 0")
    end_stop = min(nominal.end_stop, device.end_stop)
    width = nominal.dead_zone
    if deadzone is not None:
        width = real_number("deadzone", deadzone, ">= 0")
        if width >= nominal.command_limit:
            unit = device.command_unit
            raise ValueError(
                f"deadzone={deadzone!r} {unit} leaves no command that drives the plant: it must "
                f"be below the command limit, {nominal.command_limit:g} {unit}"
            )
    play = nominal.backlash if backlash is None else real_number("backlash", backlash, ">= 0")
    if play > 0.0 and not friction.exact:
        raise ValueError(
            f"backlash={play!r} {device.position_unit} needs a friction law with the event-exact "
            f"step ('paper', 'coulomb', 'none', or a static law with a 'step' or 'linear' "
            f"decay), got {friction!r}"
        )
    late = nominal.jitter if jitter is None else real_number("jitter", jitter, ">= 0")
    if late >= dt:
        raise ValueError(
            f"jitter={late!r} s reaches the control period dt={dt:g} s; use a jitter below it "
            "(a whole period more latency is delay=)"
        )
    model = device.paper_friction if loaded is None else loaded.friction
    plant = replace(
        nominal,
        dead_time=dead_time,
        end_stop=end_stop,
        dead_zone=width,
        backlash=play,
        jitter=late,
    )
    return loaded, friction, model, plant
