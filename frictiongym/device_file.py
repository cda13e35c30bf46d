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

import copy
import functools
import json
import math
import numbers
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, NoReturn

from frictiongym.data import TOMLDecodeError, toml_loads
from frictiongym.device_tables import (
    DeviceFileError,
    Fail,
    Figures,
    build,
    check_gains,
    check_references,
    check_table,
    figures,
)
from frictiongym.friction import LuGre, StictionCoulomb
from frictiongym.plants import sensors
from frictiongym.plants.plant import PlantParams

__all__ = ["AXIS_ENV_ID", "DeviceFileError", "Figures", "dump", "parse", "read", "render_toml"]

#: The env id of a device described by a file (the built-in ones name their own).
AXIS_ENV_ID = "frictiongym/Axis-v0"

#: Longest control period a file may give, s (a motion loop slower than this is no loop).
MAX_PERIOD = 10.0

#: Sensor names of the file -> the kernel's sensor codes.
SENSORS = {"encoder": sensors.SENSOR_ENCODER, "ir": sensors.SENSOR_IR}

#: File key -> Device field, where they differ.
RENAMED = {"friction": "paper_friction", "lugre": "lugre_friction", "gains": "paper_gains"}

#: Ratio v0 / v_s of a Gaussian Stribeck curve within 1 % of u_c at v0 (as the presets').
_GAUSS_V0_OVER_VS = math.sqrt(math.log(100.0))


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
    "dt": Field("period", "s", "control period"),
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

#: Keys of ``[randomization]``: ``DomainRandomization``'s fields.
RANDOMIZATION_KEYS = ("friction", "inertia", "damping", "deadzone", "backlash", "sensor_gain")
#: The ranges of a file without ``[randomization]``: the built-in devices' shared ones.
DEFAULT_RANDOMIZATION = {"friction": (0.7, 1.3), "inertia": (0.8, 1.2), "damping": (0.8, 1.2)}
#: Drawings that assume units: a disk in rad (``draw_servo``), a car's IR in cm.
DRAWING_NEEDS = {"draw_servo": ("encoder", "rad"), "draw_altino": ("ir", "cm")}

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
    json_file = file.suffix.lower() == ".json"
    try:
        text = file.read_text(encoding="utf-8")
    except OSError as error:
        reason = error.strerror or error
        raise DeviceFileError(f"cannot read device file {file}: {reason}") from None
    except UnicodeDecodeError as error:
        raise DeviceFileError(
            f"{file}: not UTF-8 text (byte {error.start}); save it as UTF-8"
        ) from None
    # Tools look a device up by its file many times (a benchmark, per scenario and run): the
    # same text is parsed and checked once. A copy, so no two devices share a mutable table.
    return copy.deepcopy(_parsed(text, json_file, str(file)))


@functools.lru_cache(maxsize=32)
def _parsed(text: str, json_file: bool, source: str) -> dict[str, Any]:
    """Parse and check a description's text (:func:`read`); errors are not cached."""
    try:
        data = json.loads(text, object_pairs_hook=_no_repeats) if json_file else toml_loads(text)
    except (TOMLDecodeError, json.JSONDecodeError, RecursionError) as error:
        kind = "JSON" if json_file else "TOML"
        raise DeviceFileError(f"{source}: not valid {kind}: {error}") from None
    except _RepeatedKey as error:
        raise DeviceFileError(f"{source}: key {error} given twice") from None
    if not isinstance(data, dict):
        raise DeviceFileError(f"{source}: a device description is a table of fields")
    return parse(data, source)


class _RepeatedKey(Exception):
    """A JSON object with a key twice (JSON keeps the last; TOML refuses it)."""


def _no_repeats(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    table = dict(pairs)
    if len(table) < len(pairs):
        keys = [k for k, _ in pairs]
        raise _RepeatedKey(repr(next(k for k in keys if keys.count(k) > 1)))
    return table


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
    _check_sensor(data, values, fail)
    values["plant"] = build(PlantParams, "plant", data.get("plant"), fail)
    _check_task(values, fail)
    values["paper_friction"] = build(StictionCoulomb, "friction", data.get("friction"), fail)
    if "lugre" in data:
        values["lugre_friction"] = build(LuGre, "lugre", data["lugre"], fail)
    else:
        values["lugre_friction"] = _default_lugre(values, fail)
    for key in MAPPINGS:
        values[RENAMED.get(key, key)] = _mapping(key, data, fail)
    gains = values["paper_gains"]
    if "compensated" not in gains:  # the compensated loop keeps the PID's gains
        values["paper_gains"] = {**gains, "compensated": gains["pid"]}
    values["figures"] = figures(data.get("figures", {}), values, fail)
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
    unit = f", {field.unit}" if field.unit else ""
    if key not in data:
        if field.default is None:
            if key == "velocity_cutoff":
                return None
            fail(key, f"missing: give {key} ({field.meaning}{unit})")
        return field.default(values) if callable(field.default) else field.default
    value = data[key]
    where = f"= {value!r} ({field.meaning}{unit})"
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
        "period": 0 < number <= MAX_PERIOD,
    }[field.rule]
    if not ok:
        rule = {
            ">0": "> 0",
            ">=0": ">= 0",
            "finite": "a finite number",
            "inf-ok": "a number or inf",
            "(0,1)": "between 0 and 1",
            "period": f"> 0 and at most {MAX_PERIOD:g} s",
        }[field.rule]
        fail(key, f"{where}: must be {rule}")
    return number


def _check_sensor(data: Mapping[str, Any], values: dict[str, Any], fail: Fail) -> None:
    """Check the sensor and its observation, and that the drawing fits them."""
    if values["sensor"] not in SENSORS:
        fail("sensor", f"= {values['sensor']!r}: must be one of {', '.join(SENSORS)}")
    encoder = values["sensor"] == "encoder"
    if encoder != (0 < values["counts_per_rev"] <= 0xFFFF):
        fail("counts_per_rev", "must be 1..65535 with sensor = 'encoder' and 0 with 'ir'")
    if not encoder and "position_per_rev" in data:
        fail("position_per_rev", "is an encoder's: omit it with sensor = 'ir'")
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
    if not (
        isinstance(names, tuple)
        and len(names) == size
        and all(isinstance(n, str) and n for n in names)
        and len(set(names)) == size
    ):
        fail(
            "observation_names",
            f"= {names!r}: must be an array of {size} distinct names with sensor = "
            f"{values['sensor']!r}",
        )
    if values["output"] not in names[: size - 2]:
        fail("output", f"must name the measured output, one of {list(names[: size - 2])}")
    values["observation_names"] = names
    if values["drawing"] and values["drawing"] not in DRAWINGS:
        fail("drawing", f"= {values['drawing']!r}: must be one of {', '.join(DRAWINGS)}")
    needs = DRAWING_NEEDS.get(values["drawing"])
    if needs is not None and (values["sensor"], values["position_unit"]) != needs:
        what = "a disk, in rad" if needs[0] == "encoder" else "a car by its IR, in cm"
        fail("drawing", f"{values['drawing']} draws {what}: use draw_axis, which draws any unit")


def _check_task(values: Mapping[str, Any], fail: Fail) -> None:
    """Check what the plant and the task must agree on: periods, start, limit, end stop."""
    plant, dt = values["plant"], values["dt"]
    try:
        plant.delay_steps(dt)
    except ValueError:
        fail(
            "plant.dead_time",
            f"= {plant.dead_time!r}: must be a whole number of control periods dt = {dt!r} s",
        )
    if plant.jitter >= dt:
        fail("plant.jitter", f"= {plant.jitter!r}: must be below the control period {dt!r} s")
    start, limit, stop = values["start"], values["limit"], values["end_stop"]
    if values["sensor"] == "encoder":
        if limit <= 0.0 or abs(start) >= limit:
            fail(
                "limit",
                f"= {limit!r}: the safety limit ±limit must hold the start {start!r} {{p}} "
                "(an episode ends beyond it)",
            )
        if start >= stop:
            fail("end_stop", f"= {stop!r}: the end stop must lie ahead of the start {start!r}")
    else:  # IR: the distance to a wall; the limit is the least distance
        if not 0.0 <= limit < start:
            fail("limit", f"= {limit!r}: the least distance must be >= 0 and below the start")
        if -start >= stop:
            fail("end_stop", f"= {stop!r}: the wall (plant position) must lie ahead of -start")


def _observation_names(values: Mapping[str, Any]) -> tuple[str, ...]:
    if values["sensor"] == "encoder":
        return (values["output"], "velocity", "reference")
    return ("readout", values["output"], "velocity", "reference")


def _default_lugre(values: Mapping[str, Any], fail: Fail) -> LuGre:
    """Return the LuGre version of the device's law, built as the presets are (docs/devices.md)."""
    law, inertia = values["paper_friction"], values["plant"].inertia
    resolution = values["position_per_rev"] / max(values["counts_per_rev"], 1)
    # Pre-sliding deflection at break-away of half the sensor's resolution; a critically
    # damped bristle mode.
    sigma0 = max(law.us_pos, law.us_neg) / (0.5 * resolution)
    table = {
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

    def built_from(key: str, rule: str) -> NoReturn:
        fail("lugre", f"built from [friction] and [plant], {key}: {rule}; give [lugre] yourself")

    lugre: LuGre = build(LuGre, "lugre", table, built_from)
    return lugre


def _mapping(key: str, data: Mapping[str, Any], fail: Fail) -> Mapping[str, Any]:
    if key == "randomization" and key not in data:
        return dict(DEFAULT_RANDOMIZATION)
    value = data.get(key, {})
    if not isinstance(value, Mapping):
        fail(key, f"= {value!r}: must be a table [{key}]")
    if key in ("identification", "residual", "tuning"):
        return check_table(key, value, fail) if key in data else {}
    if key == "references":
        check_references(value, fail)
    if key == "randomization":
        for name, entry in value.items():
            if name not in RANDOMIZATION_KEYS:
                fail(f"randomization.{name}", f"unknown; use {', '.join(RANDOMIZATION_KEYS)}")
            if not (isinstance(entry, tuple) and len(entry) == 2 and 0 < entry[0] <= entry[1]):
                fail(f"randomization.{name}", f"= {entry!r}: must be [low, high], 0 < low <= high")
    if key == "gains":
        check_gains(value, fail)
    return value


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
