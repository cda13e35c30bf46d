"""Files shipped with the package: the built-in devices' descriptions (``devices/*.toml``).

:func:`device_table` reads one as a plain table, with nothing but the standard library, so the
presets modules (:mod:`frictiongym.plants.presets`, :mod:`frictiongym.friction.presets`) take
their numbers from the same file that :mod:`frictiongym.devices` checks and loads: each number
exists once, with its source beside it.
"""

from __future__ import annotations

import functools
import sys
from importlib import resources
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

#: The TOML parser and its error (the standard library's from Python 3.11).
toml_loads, TOMLDecodeError = tomllib.loads, tomllib.TOMLDecodeError

__all__ = ["BUILTIN_FILES", "TOMLDecodeError", "device_path", "device_table", "toml_loads"]

#: The built-in devices' files, by device kind.
BUILTIN_FILES = {"rotary": "rotary_servo.toml", "altino": "altino_distance.toml"}


def device_path(kind: str) -> Path:
    """Path of a built-in device's description file."""
    return Path(str(resources.files(__name__) / "devices" / BUILTIN_FILES[kind]))


@functools.cache
def device_table(kind: str) -> dict[str, Any]:
    """Return a built-in device's description, as parsed TOML (not checked: see devices.load)."""
    return toml_loads(device_path(kind).read_text(encoding="utf-8"))
