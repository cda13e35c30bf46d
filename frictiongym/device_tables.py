"""The tables of a device description file: their keys, units and rules (docs/devices.md).

:mod:`frictiongym.device_file` reads the file's top-level fields and hands each table here:
``[plant]``, ``[friction]`` and ``[lugre]`` are built by their classes with each field's unit
in the messages; the tools' tables (``[identification]``, ``[residual]``, ``[tuning]``...)
are checked key by key against :data:`TABLE_RULES`, whose keys
``tests/test_device_file.py`` keeps equal to the fields of the classes that read them.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Callable, Mapping
from dataclasses import MISSING, fields
from typing import Any, NamedTuple, NoReturn

__all__ = [
    "FIELD_UNITS",
    "TABLE_RULES",
    "DeviceFileError",
    "Fail",
    "Figures",
    "build",
    "check_gains",
    "check_references",
    "check_table",
    "figures",
]


class DeviceFileError(ValueError):
    """A device description that cannot be used: the message names the file and the field."""


#: Raise the file's error for a field: ``fail(key, what is wrong)``; ``{p}`` and ``{c}`` in
#: the text become the device's position and command units.
Fail = Callable[[str, str], NoReturn]


class Figures(NamedTuple):
    """What the benchmark's figures say of a device (:mod:`frictiongym.benchmark.figures`)."""

    response: str  #: title of its paper scenarios' responses
    residual: str  #: title of its residual policy's response
    friction: str  #: title of its friction curves
    speed: float  #: the friction curves' velocity range, ±
    zoom: float  #: error axis of the paper responses, ±
    residual_zoom: float  #: error axis of the residual response, ±


#: Units of the fields of ``[plant]``, ``[friction]`` and ``[lugre]``, for the messages.
FIELD_UNITS: dict[str, str] = {
    "inertia": "{c}·s²/{p}",
    "damping": "{c}·s/{p}",
    "command_limit": "{c}",
    "lag": "s",
    "dead_time": "s",
    "dead_zone": "{c}",
    "backlash": "{p}",
    "load_inertia": "a fraction",
    "load_friction": "a fraction",
    "jitter": "s",
    "us_pos": "{c}",
    "us_neg": "{c}",
    "uc_pos": "{c}",
    "uc_neg": "{c}",
    "v0_pos": "{p}/s",
    "v0_neg": "{p}/s",
    "vs_pos": "{p}/s",
    "vs_neg": "{p}/s",
    "viscous": "{c}·s/{p}",
    "sigma0": "{c}/{p}",
    "sigma1": "{c}·s/{p}",
    "shape": "linear, exponential or step",
}

#: Rules of the tools' tables: key -> rule. ``+``: a number > 0; ``0+``: >= 0; ``>1``: > 1;
#: ``n``: a whole number >= 0; ``n+``: >= 1; ``+[]``: an array of numbers > 0; ``[2]``,
#: ``[3]``: an array of that many numbers; ``[lo,hi]``: two numbers, 0 <= low < high;
#: ``bool``; ``table``; ``num``: any finite number. A key in ``REQUIRED`` must be given
#: when its table is.
TABLE_RULES: dict[str, dict[str, str]] = {
    "identification": {
        "levels": "+[]",
        "constant_duration": "+",
        "ramp_repeats": "n",
        "ramp_from": "+",
        "ramp_to": "+",
        "ramp_duration": "+",
        "step_levels": "[2]",
        "step_time": "+",
        "step_duration": "+",
        "step_repeats": "n",
        "probe_to": "+",
        "probe_duration": "+",
        "relay_levels": "+[]",
        "relay_band": "[2]",
        "relay_duration": "0+",
        "refine": "bool",
        "reading": "[3]",
        "span": "[3]",
        "ramp_positions": "[2]",
        "env_kwargs": "table",
        "reversal": "table",
    },
    "identification.reversal": {
        "level": ">1",
        "hold": "+",
        "reversals": "n+",
        "max_width": "+",
        "resolution": "+",
        "band": "[2]",
        "grid": "n+",
        "shares": "[2]",
    },
    "residual": {
        "scale": "+",
        "error_scale": "+",
        "fine_error": "+",
        "velocity_scale": "+",
        "reference_scale": "+",
        "reference_offset": "num",
    },
    "tuning": {
        "rise_time": "+",
        "peak_time": "+",
        "settling_time": "+",
        "overshoot_pct": "+",
        "settling_band": "+",
        "rise_limits": "[lo,hi]",
        "kp": "[lo,hi]",
        "ki": "[lo,hi]",
        "kd": "[lo,hi]",
    },
}

#: Keys a table must hold when it is given. An identification table must hold every key of
#: a plan but :data:`PLAN_OPTIONAL`, unless it holds only those (then it is no plan, and
#: ``identify`` refuses the device).
REQUIRED: dict[str, tuple[str, ...]] = {
    "identification.reversal": ("level", "hold", "reversals", "max_width", "resolution"),
    "residual": ("scale", "error_scale", "fine_error", "velocity_scale", "reference_scale"),
}
#: Keys of a plan with a default (``Plan``'s fields with one, and the reversal test).
PLAN_OPTIONAL = (
    "relay_levels",
    "relay_band",
    "relay_duration",
    "refine",
    "reading",
    "span",
    "ramp_positions",
    "env_kwargs",
    "reversal",
)

_RULE_TEXT = {
    "+": "a number > 0",
    "0+": "a number >= 0",
    ">1": "a number > 1",
    "n": "a whole number >= 0",
    "n+": "a whole number >= 1",
    "+[]": "an array of numbers > 0",
    "[2]": "an array of 2 numbers",
    "[3]": "an array of 3 numbers",
    "[lo,hi]": "[low, high] with 0 <= low < high",
    "bool": "true or false",
    "table": "a table",
    "num": "a finite number",
}


def _number(value: Any) -> bool:
    return (
        isinstance(value, numbers.Real)
        and not isinstance(value, bool)
        and math.isfinite(float(value))
    )


def _follows(rule: str, value: Any) -> bool:
    """Whether ``value`` follows ``rule`` (:data:`TABLE_RULES`)."""
    if rule == "bool":
        return isinstance(value, bool)
    if rule == "table":
        return isinstance(value, Mapping)
    if rule in ("n", "n+"):
        least = 1 if rule == "n+" else 0
        return isinstance(value, int) and not isinstance(value, bool) and value >= least
    if rule.startswith("["):
        ok = isinstance(value, tuple) and all(_number(v) for v in value)
        if rule == "[lo,hi]":
            return ok and len(value) == 2 and 0 <= value[0] < value[1]
        return ok and len(value) == int(rule[1])
    if rule == "+[]":
        return isinstance(value, tuple) and all(_number(v) and v > 0 for v in value)
    bound = {"+": 0.0, "0+": 0.0, ">1": 1.0, "num": -math.inf}[rule]
    return _number(value) and (value >= bound if rule == "0+" else value > bound)


def check_table(name: str, table: Any, fail: Fail) -> Mapping[str, Any]:
    """Check a tool's table ``name`` (a key of :data:`TABLE_RULES`); return it."""
    if not isinstance(table, Mapping):
        fail(name, f"= {table!r}: must be a table [{name}]")
    rules = TABLE_RULES[name]
    for key in sorted(set(table) - set(rules)):
        fail(f"{name}.{key}", f"unknown; [{name}] takes {', '.join(rules)}")
    required = _required(name, table)
    for key in required:
        if key not in table:
            fail(f"{name}.{key}", f"missing: [{name}] needs {', '.join(required)}")
    for key, value in table.items():
        if not _follows(rules[key], value):
            fail(f"{name}.{key}", f"= {value!r}: must be {_RULE_TEXT[rules[key]]}")
    if name == "identification" and "reversal" in table:
        check_table("identification.reversal", table["reversal"], fail)
    return table


def _required(name: str, table: Mapping[str, Any]) -> tuple[str, ...]:
    if name != "identification":
        return REQUIRED.get(name, ())
    if set(table) <= {"env_kwargs", "reversal"}:
        return ()  # no plan: identify refuses the device, and says so
    return tuple(k for k in TABLE_RULES[name] if k not in PLAN_OPTIONAL)


def build(cls: type, key: str, table: Any, fail: Fail) -> Any:
    """Build ``cls`` from the table ``key``, with each field's unit in an error."""
    if not isinstance(table, Mapping):
        fail(key, f"missing table [{key}] of {cls.__name__} fields (docs/devices.md)")
    names = {f.name: f for f in fields(cls) if f.init}
    for name in sorted(set(table) - set(names)):
        fail(f"{key}.{name}", f"unknown; [{key}] takes {', '.join(sorted(names))}")
    for name, field in names.items():
        unit = f" ({FIELD_UNITS[name]})" if name in FIELD_UNITS else ""
        if name not in table and field.default is MISSING:
            fail(f"{key}.{name}", f"missing: give it{unit}")
        value = table.get(name)
        if name in table and name != "shape" and not _number(value):
            fail(f"{key}.{name}", f"= {value!r}: must be a finite number{unit}")
    try:
        return cls(**table)
    except (TypeError, ValueError) as error:
        text = str(error).replace(f"{cls.__name__}.", f"{key}.")
        named = re.search(rf"{re.escape(key)}\.(\w+)", text)
        unit = FIELD_UNITS.get(named.group(1), "") if named else ""
        where = named.group(0) if named else key
        text = text.removeprefix(f"{where}=").removeprefix(f"{where} ")  # said before the colon
        fail(where, text + (f" ({unit})" if unit else ""))


def check_references(references: Mapping[str, Any], fail: Fail) -> None:
    """Tables of numbers, with a step to a nonzero set-point (their classes check the rest)."""
    if "step" not in references:
        fail("references.step", "missing: give [references.step] value = the demo set-point")
    for kind, table in references.items():
        if not isinstance(table, Mapping):
            fail(f"references.{kind}", f"= {table!r}: must be a table of its arguments")
        for name, entry in table.items():
            items = entry if isinstance(entry, tuple) else (entry,)
            if not all(_number(item) for item in items):
                fail(f"references.{kind}.{name}", f"= {entry!r}: must be a finite number")
    value = references["step"].get("value")
    if not (_number(value) and value != 0.0):
        fail("references.step.value", f"= {value!r}: must be a nonzero set-point ({{p}})")


def check_gains(gains: Mapping[str, Any], fail: Fail) -> None:
    """Check ``[gains]``: a ``pid`` table, and every table's kp, ki, kd numbers >= 0."""
    if "pid" not in gains:
        fail("gains.pid", "missing: give [gains.pid] kp, ki, kd (the baseline PID)")
    for name, gain in gains.items():
        if not isinstance(gain, Mapping) or set(gain) != {"kp", "ki", "kd"}:
            fail(f"gains.{name}", "must be a table of kp, ki and kd")
        for term, value in gain.items():
            if not (_number(value) and float(value) >= 0):
                fail(f"gains.{name}.{term}", f"= {value!r}: must be a number >= 0")


def figures(table: Any, values: Mapping[str, Any], fail: Fail) -> Figures:
    """Return ``[figures]`` with the defaults it leaves out, from the title and the step."""
    if not isinstance(table, Mapping):
        fail("figures", f"= {table!r}: must be a table [figures]")
    law, title = values["paper_friction"], values["title"]
    step = abs(values["references"]["step"]["value"])
    defaults = {
        "response": f"{title[0].upper()}{title[1:]}, step response",
        "residual": f"{title[0].upper()}{title[1:]}, step response: residual policy",
        "friction": title,
        "speed": 2.0 * max(law.v0_pos, law.v0_neg),
        "zoom": 0.03 * step,
        "residual_zoom": 0.02 * step,
    }
    unknown = sorted(set(table) - set(defaults))
    if unknown:
        fail(f"figures.{unknown[0]}", f"unknown; [figures] takes {', '.join(defaults)}")
    merged = {**defaults, **table}
    for key in ("response", "residual", "friction"):
        if not isinstance(merged[key], str):
            fail(f"figures.{key}", f"= {merged[key]!r}: must be a title (a string)")
    for key in ("speed", "zoom", "residual_zoom"):
        if not (_number(merged[key]) and float(merged[key]) > 0):
            fail(f"figures.{key}", f"= {merged[key]!r}: must be a number > 0")
    return Figures(**merged)
