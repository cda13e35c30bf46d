"""Device description files: a single-axis device in TOML or JSON, read into a ``Device``.

One schema (docs/devices.md) serves the built-in devices, whose files ship in
``frictiongym/data/devices``, and any user's rig. :func:`read` returns the keyword arguments
of :class:`frictiongym.devices.Device` after checking every field: an error names the file,
the field, its unit and what it may be. :func:`dump` writes a device back as TOML, the start
of a new description (``frictiongym device show rotary``).

The file's keys are the ``Device`` fields, with three renamed for a device that is not the
paper's: ``friction`` (``paper_friction``: the law the env simulates by default), ``lugre``
(``lugre_friction``) and ``gains`` (``paper_gains``). Arrays are read as tuples.
"""

from __future__ import annotations

import json
import math
import numbers
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, NamedTuple, NoReturn

from frictiongym.data import TOMLDecodeError, toml_loads
from frictiongym.friction import LuGre, StictionCoulomb
from frictiongym.plants import sensors
from frictiongym.plants.plant import PlantParams

__all__ = ["DeviceFileError", "Figures", "dump", "parse", "read", "render_toml"]

#: The env id of a device described by a file (the built-in ones name their own).
AXIS_ENV_ID = "frictiongym/Axis-v0"

#: Sensor names of the file -> the kernel's sensor codes.
SENSORS = {"encoder": sensors.SENSOR_ENCODER, "ir": sensors.SENSOR_IR}

#: File key -> Device field, where they differ.
RENAMED = {"friction": "paper_friction", "lugre": "lugre_friction", "gains": "paper_gains"}

#: Ratio v0 / v_s of a Gaussian Stribeck curve within 1 % of u_c at v0 (as the presets').
_GAUSS_V0_OVER_VS = math.sqrt(math.log(100.0))


class Figures(NamedTuple):
    """What the benchmark's figures say of a device (:mod:`frictiongym.benchmark.figures`)."""

    response: str  #: title of its paper scenarios' responses
    residual: str  #: title of its residual policy's response
    friction: str  #: title of its friction curves
    speed: float  #: the friction curves' velocity range, ±
    zoom: float  #: error axis of the paper responses, ±
    residual_zoom: float  #: error axis of the residual response, ±


#: Raise the file's error for a field: ``fail(key, what is wrong)``.
Fail = Callable[[str, str], NoReturn]


class DeviceFileError(ValueError):
    """A device description that cannot be used: the message names the file and the field."""


@dataclass(frozen=True)
class Field:
    """One scalar of the file: its check, unit (``{p}`` position, ``{c}`` command) and meaning."""

    rule: str  #: "str", "name", "int>0", ">0", ">=0", "finite", "inf-ok", "(0,1)"
    unit: str
    meaning: str
    default: Any = None  #: None: required (a callable: derived from the other fields)


def _default_noise(values: Mapping[str, Any]) -> float:
    return (
        values["position_per_rev"] / values["counts_per_rev"]
        if values["sensor"] == "encoder"
        else 2.0
    )


#: Drawings of :mod:`frictiongym.envs.rendering` a device may name.
DRAWINGS = ("draw_servo", "draw_altino", "draw_axis")

#: Every scalar field, in the order :func:`dump` writes them.
SCALARS: dict[str, Field] = {
    "name": Field("name", "", "identifier of the device (params files, run logs, models)"),
    "kind": Field("kind", "", "short name of the tools' --device", lambda v: v["name"].lower()),
    "env_id": Field("str", "", "the env id the tools make", AXIS_ENV_ID),
    "title": Field("str", "", "for messages, e.g. 'a ball-screw stage'"),
    "position_unit": Field("str", "", "unit of position, e.g. 'mm'"),
    "command_unit": Field("str", "", "unit of the command, e.g. 'V'"),
    "dt": Field(">0", "s", "control period"),
    "sensor": Field("str", "", "'encoder' or 'ir' (the paper's IR law, Eq. (1))"),
    "counts_per_rev": Field("int>=0", "counts", "encoder counts per revolution", 0),
    "position_per_rev": Field(">0", "{p}", "travel per revolution (a screw's lead)", 2 * math.pi),
    "velocity_cutoff": Field(">0", "rad/s", "velocity filter's pole (omit: backward difference)"),
    "noise_std": Field(">=0", "{p} or counts", "sensor noise of sensor_noise=True", _default_noise),
    "episode_steps": Field("int>0", "steps", "registered episode length"),
    "start": Field("finite", "{p}", "default start position", 0.0),
    "error_scale": Field(">0", "{p}", "tracking error that costs 1 per step"),
    "error_cap": Field(">0", "{p}", "largest tracking error the reward charges"),
    "effort_weight": Field(">=0", "", "weight of (command / limit)² in the reward", 0.01),
    "limit": Field("finite", "{p}", "safety limit: |position| beyond it ends an episode"),
    "limit_penalty": Field(">=0", "", "cost of crossing the safety limit", 100.0),
    "output": Field("str", "", "observation name of the controlled output"),
    "rest_speed": Field(">0", "{p}/s", "speed below which the compensator sees a body at rest"),
    "benchmark_steps": Field("int>0", "steps", "length of a benchmark run"),
    "training_precision": Field(">0", "{p}", "error scale of train --reward precision"),
    "training_gamma": Field("(0,1)", "", "discount of residual training", 0.99),
    "command_scale": Field("int>0", "counts/{c}", "firmware command counts per command unit"),
    "end_stop": Field("inf-ok", "{p}", "plant position of a rigid end stop (inf: none)", math.inf),
    "drawing": Field("str", "", "frame drawing: " + ", ".join(DRAWINGS), ""),
}

#: Fields that only an encoder uses (:func:`dump` leaves them out without one).
ENCODER_ONLY = ("counts_per_rev", "position_per_rev")

#: Keys of the tables read by classes of higher layers (tests/test_device_file.py keeps them
#: equal to those classes' fields): ``identification`` (``Plan``, identify.py; ``reversal``
#: holds ``ReversalPlan``'s), ``residual`` (``ResidualConfig`` but device and limit),
#: ``randomization`` (``DomainRandomization``), ``tuning`` (``StepSpecs``, ``GainBounds``).
TABLE_KEYS: dict[str, tuple[str, ...]] = {
    "identification": (
        "levels",
        "constant_duration",
        "ramp_repeats",
        "ramp_from",
        "ramp_to",
        "ramp_duration",
        "step_levels",
        "step_time",
        "step_duration",
        "step_repeats",
        "probe_to",
        "probe_duration",
        "relay_levels",
        "relay_band",
        "relay_duration",
        "refine",
        "reading",
        "span",
        "ramp_positions",
        "env_kwargs",
        "reversal",
    ),
    "identification.reversal": (
        "level",
        "hold",
        "reversals",
        "max_width",
        "resolution",
        "band",
        "grid",
        "shares",
    ),
    "residual": (
        "scale",
        "error_scale",
        "fine_error",
        "velocity_scale",
        "reference_scale",
        "reference_offset",
    ),
    "randomization": ("friction", "inertia", "damping", "deadzone", "backlash", "sensor_gain"),
    "tuning": (
        "rise_time",
        "peak_time",
        "settling_time",
        "overshoot_pct",
        "settling_band",
        "rise_limits",
        "kp",
        "ki",
        "kd",
    ),
}

#: Tables of the file whose entries are free mappings (checked by their users' classes).
MAPPINGS = (
    "references",
    "gains",
    "randomization",
    "identification",
    "residual",
    "training_env",
    "tuning",
)


def read(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read and check a device description; return ``Device`` keyword arguments.

    Raises
    ------
    DeviceFileError
        The file is missing, not TOML/JSON, or a field is missing, unknown or out of range;
        the message names the file, the field, its unit and the allowed values.
    """
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except OSError as error:
        reason = error.strerror or error
        raise DeviceFileError(f"cannot read device file {file}: {reason}") from None
    try:
        data = json.loads(text) if file.suffix.lower() == ".json" else toml_loads(text)
    except (TOMLDecodeError, json.JSONDecodeError) as error:
        kind = "JSON" if file.suffix.lower() == ".json" else "TOML"
        raise DeviceFileError(f"{file}: not valid {kind}: {error}") from None
    if not isinstance(data, dict):
        raise DeviceFileError(f"{file}: a device description is a table of fields")
    return parse(data, str(file))


def parse(data: Mapping[str, Any], source: str = "device description") -> dict[str, Any]:
    """Check a parsed description (see :func:`read`); ``source`` names it in errors."""
    data = _tuples(dict(data))
    known = set(SCALARS) | set(MAPPINGS) | {"plant", "friction", "lugre", "figures"}
    known |= {"observation_names"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise DeviceFileError(
            f"{source}: unknown field(s) {', '.join(unknown)}; the fields are listed in "
            "docs/devices.md"
        )
    fail = _failer(source, data)
    values: dict[str, Any] = {}
    for key, field in SCALARS.items():
        values[key] = _scalar(key, field, data, values, fail)
    if values["drawing"] and values["drawing"] not in DRAWINGS:
        fail("drawing", f"= {values['drawing']!r}: must be one of {', '.join(DRAWINGS)}")
    if values["sensor"] not in SENSORS:
        fail("sensor", f"must be one of {', '.join(SENSORS)}")
    encoder = values["sensor"] == "encoder"
    if encoder != (0 < values["counts_per_rev"] <= 0xFFFF):
        fail("counts_per_rev", "must be 1..65535 with sensor = 'encoder' and 0 with 'ir'")
    reading = (sensors.IR_NUMERATOR, sensors.IR_OFFSET, sensors.IR_MAX_READOUT)
    plan = data.get("identification", {})
    if not encoder and isinstance(plan, Mapping) and plan.get("reading", reading) != reading:
        fail(
            "identification.reading",
            f"must be the env's IR law {list(reading)} (the paper's Eq. (1)): other readout "
            "curves are not supported",
        )
    names = data.get("observation_names", _observation_names(values))
    size = 3 if encoder else 4
    if not (len(names) == size and all(isinstance(n, str) and n for n in names)):
        fail("observation_names", f"must be {size} names with sensor = {values['sensor']!r}")
    if values["output"] not in names[: size - 2]:
        fail("output", f"must name the measured output, one of {list(names[: size - 2])}")
    values["observation_names"] = names
    values["plant"] = _build(PlantParams, "plant", data, fail, values)
    values["paper_friction"] = _build(StictionCoulomb, "friction", data, fail, values)
    lugre = data.get("lugre", _default_lugre(values["paper_friction"], values))
    values["lugre_friction"] = _build(LuGre, "lugre", {"lugre": lugre}, fail, values)
    for key in MAPPINGS:
        values[RENAMED.get(key, key)] = _mapping(key, data, fail)
    _check_gains(values["paper_gains"], fail)
    gains = values["paper_gains"]
    if "compensated" not in gains:  # the compensated loop keeps the PID's gains
        values["paper_gains"] = {**gains, "compensated": gains["pid"]}
    values["figures"] = _figures(data.get("figures", {}), values, fail)
    values["sensor"] = SENSORS[values["sensor"]]
    values["drawing"] = values["drawing"] or None
    values["source"] = source
    return values


def _failer(source: str, data: Mapping[str, Any]) -> Fail:
    units = {"{p}": str(data.get("position_unit", "position units"))}
    units["{c}"] = str(data.get("command_unit", "command units"))

    def fail(key: str, rule: str) -> NoReturn:
        for mark, unit in units.items():
            rule = rule.replace(mark, unit)
        raise DeviceFileError(f"{source}: {key}: {rule}")

    return fail


def _scalar(
    key: str, field: Field, data: Mapping[str, Any], values: Mapping[str, Any], fail: Fail
) -> Any:
    unit = f" {field.unit}" if field.unit else ""
    if key not in data:
        if field.default is None:
            if key == "velocity_cutoff":
                return None
            fail(key, f"missing: give the {field.meaning}{f' ({field.unit})' if unit else ''}")
        return field.default(values) if callable(field.default) else field.default
    value = data[key]
    where = f"= {value!r} ({field.meaning}{',' + unit if unit else ''})"
    if field.rule in ("str", "name", "kind"):
        if not (isinstance(value, str) and value):
            fail(key, f"{where}: must be a non-empty string")
        if field.rule == "name" and not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", value):
            fail(key, f"{where}: must be letters, digits and _ (it names files and env ids)")
        if field.rule == "kind" and not re.fullmatch(r"[a-z][a-z0-9-]*", value):
            fail(key, f"{where}: must be lower-case letters, digits and - (a command-line name)")
        return value
    if field.rule.startswith("int"):
        if not isinstance(value, int) or isinstance(value, bool):
            fail(key, f"{where}: must be a whole number")
        if value < (0 if field.rule == "int>=0" else 1):
            fail(key, f"{where}: must be {field.rule[3:]}")
        return value
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        fail(key, f"{where}: must be a number")
    number = float(value)
    ok = {
        ">0": math.isfinite(number) and number > 0,
        ">=0": math.isfinite(number) and number >= 0,
        "finite": math.isfinite(number),
        "inf-ok": not math.isnan(number),
        "(0,1)": 0 < number < 1,
    }[field.rule]
    if not ok:
        rule = {
            ">0": "> 0",
            ">=0": ">= 0",
            "finite": "a finite number",
            "inf-ok": "a number or inf",
            "(0,1)": "between 0 and 1",
        }[field.rule]
        fail(key, f"{where}: must be {rule}")
    return number


def _observation_names(values: Mapping[str, Any]) -> tuple[str, ...]:
    if values["sensor"] == "encoder":
        return (values["output"], "velocity", "reference")
    return ("readout", values["output"], "velocity", "reference")


def _build(cls: type, key: str, data: Mapping[str, Any], fail: Fail, values: Mapping) -> Any:
    table = data.get(key)
    if not isinstance(table, Mapping):
        fail(key, f"missing table [{key}] of {cls.__name__} fields (docs/devices.md)")
    names = {f.name for f in fields(cls) if f.init}
    unknown = sorted(set(table) - names)
    if unknown:
        fail(f"{key}.{unknown[0]}", f"unknown; [{key}] takes {', '.join(sorted(names))}")
    if key == "plant" and "end_stop" in table:
        fail("plant.end_stop", "set the device's end_stop instead (the envs place it)")
    try:
        return cls(**table)
    except TypeError as error:
        fail(key, f"{error} (units: docs/devices.md)")
    except ValueError as error:
        fail(key, str(error).replace(f"{cls.__name__}.", f"{key}."))


def _default_lugre(law: StictionCoulomb, values: Mapping[str, Any]) -> dict[str, float]:
    """Return the LuGre version of the device's law, built as the presets are (docs/devices.md)."""
    inertia = values.get("plant", PlantParams(1.0, 0.0, 1.0)).inertia
    resolution = values["position_per_rev"] / max(values["counts_per_rev"], 1)
    # Pre-sliding deflection at break-away of half the sensor's resolution; a critically
    # damped bristle mode.
    sigma0 = max(law.us_pos, law.us_neg) / (0.5 * resolution)
    return {
        "us_pos": law.us_pos,
        "us_neg": law.us_neg,
        "uc_pos": law.uc_pos,
        "uc_neg": law.uc_neg,
        "vs_pos": law.v0_pos / _GAUSS_V0_OVER_VS,
        "vs_neg": law.v0_neg / _GAUSS_V0_OVER_VS,
        "sigma0": sigma0,
        "sigma1": 2.0 * math.sqrt(sigma0 * inertia),
        "viscous": law.viscous,
    }


def _mapping(key: str, data: Mapping[str, Any], fail: Fail) -> Mapping[str, Any]:
    value = data.get(key, {})
    if not isinstance(value, Mapping):
        fail(key, f"must be a table [{key}]")
    if key == "references" and "step" not in value:
        fail("references.step", "missing: give [references.step] value = the demo set-point")
    for table, keys in TABLE_KEYS.items():
        head, _, sub = table.partition(".")
        if head != key:
            continue
        entries = value.get(sub, {}) if sub else value
        if not isinstance(entries, Mapping):
            fail(table, f"must be a table [{table}]")
        for name in sorted(set(entries) - set(keys)):
            fail(f"{table}.{name}", f"unknown; [{table}] takes {', '.join(keys)}")
        for name, entry in entries.items():
            if name not in ("env_kwargs", "reversal", "reading", "refine"):
                _check_numbers(f"{table}.{name}", entry, fail)
    if key == "randomization":
        for name, entry in value.items():
            if not (isinstance(entry, tuple) and len(entry) == 2 and 0 < entry[0] <= entry[1]):
                fail(f"randomization.{name}", f"= {entry!r}: must be [low, high], 0 < low <= high")
    if key == "gains" and "pid" not in value:
        fail("gains.pid", "missing: give [gains.pid] kp, ki, kd (the baseline PID)")
    return value


def _check_numbers(key: str, value: Any, fail: Fail) -> None:
    """Refuse all but a finite number or an array of them (their classes check the ranges)."""
    items = value if isinstance(value, tuple) else (value,)
    for item in items:
        if not isinstance(item, numbers.Real) or isinstance(item, bool) or not math.isfinite(item):
            fail(key, f"= {value!r}: must be a finite number or an array of them")


def _check_gains(gains: Mapping[str, Any], fail: Fail) -> None:
    for name, gain in gains.items():
        if not isinstance(gain, Mapping) or set(gain) != {"kp", "ki", "kd"}:
            fail(f"gains.{name}", "must be a table of kp, ki and kd")
        for term, value in gain.items():
            if not (isinstance(value, numbers.Real) and math.isfinite(value) and float(value) >= 0):
                fail(f"gains.{name}.{term}", f"= {value!r}: must be a number >= 0")


def _figures(table: Mapping[str, Any], values: Mapping[str, Any], fail: Fail) -> Any:
    law = values["paper_friction"]
    title = values["title"]
    defaults = {
        "response": f"{title[0].upper()}{title[1:]}, step response",
        "residual": f"{title[0].upper()}{title[1:]}, step response: residual policy",
        "friction": title,
        "speed": 2.0 * max(law.v0_pos, law.v0_neg),
        "zoom": 0.03 * abs(values["references"]["step"].get("value", 1.0)),
        "residual_zoom": 0.02 * abs(values["references"]["step"].get("value", 1.0)),
    }
    unknown = sorted(set(table) - set(defaults))
    if unknown:
        fail(f"figures.{unknown[0]}", f"unknown; [figures] takes {', '.join(defaults)}")
    merged = {**defaults, **table}
    for key in ("speed", "zoom", "residual_zoom"):
        value = merged[key]
        if not (isinstance(value, numbers.Real) and math.isfinite(value) and float(value) > 0):
            fail(f"figures.{key}", f"= {value!r}: must be a number > 0")
    return Figures(**merged)


def _tuples(value: Any) -> Any:
    """Arrays of the file as tuples (the ``Device`` presets hold tuples), tables as dicts."""
    if isinstance(value, list | tuple):
        return tuple(_tuples(v) for v in value)
    if isinstance(value, Mapping):
        return {k: _tuples(v) for k, v in value.items()}
    return value


# --- writing -----------------------------------------------------------------------------


def dump(device: Any) -> str:
    """Return a device's description as TOML text that :func:`read` gives back exactly."""
    top: dict[str, Any] = {}
    for key in SCALARS:
        value = getattr(device, key)
        if key == "sensor":
            value = next(name for name, code in SENSORS.items() if code == value)
        if value is None or (key in ENCODER_ONLY and device.counts_per_rev == 0):
            continue
        top[key] = value
    top["observation_names"] = list(device.observation_names)
    tables: dict[str, Any] = {
        "plant": _fields_of(device.plant, skip=("end_stop",)),
        "friction": _fields_of(device.paper_friction),
        "lugre": _fields_of(device.lugre_friction),
    }
    for key in MAPPINGS:
        tables[key] = getattr(device, RENAMED.get(key, key))
    tables["figures"] = device.figures._asdict()
    return render_toml({**top, **tables})


def _fields_of(obj: Any, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    return {f.name: getattr(obj, f.name) for f in fields(obj) if f.init and f.name not in skip}


def render_toml(data: Mapping[str, Any], prefix: str = "") -> str:
    """TOML text of nested mappings of numbers, strings, booleans and arrays."""
    lines = [f"{_key(k)} = {_value(v)}" for k, v in data.items() if not isinstance(v, Mapping)]
    text = "\n".join(lines) + ("\n" if lines else "")
    for key, value in data.items():
        if isinstance(value, Mapping):
            name = f"{prefix}{_key(key)}"
            body = render_toml(value, f"{name}.")
            scalars = any(not isinstance(v, Mapping) for v in value.values())
            text += f"\n[{name}]\n{body}" if scalars or not value else body
    return text


def _key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if hasattr(value, "item"):  # a numpy scalar
        return _value(value.item())
    raise TypeError(f"cannot write {value!r} ({type(value).__name__}) to a device file")
