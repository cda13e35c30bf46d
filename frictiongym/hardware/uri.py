"""Parsing the query options of backend URIs (``serial://PATH?baud=N``): one parser per key."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any


def positive(name: str) -> Callable[[str], float]:
    """Parser of a positive, finite number option."""

    def parse(text: str) -> float:
        value = float(text)
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} must be a positive number, got {text!r}")
        return value

    return parse


def integer(name: str) -> Callable[[str], int]:
    """Parser of an integer option."""

    def parse(text: str) -> int:
        try:
            return int(text)
        except ValueError:
            raise ValueError(f"{name} must be an integer, got {text!r}") from None

    return parse


_TRUE = ("1", "true", "yes", "on")
_FALSE = ("0", "false", "no", "off", "")


def flag(name: str) -> Callable[[str], bool]:
    """Parser of an on/off option: 1, true, yes, on, or 0, false, no, off, empty."""

    def parse(text: str) -> bool:
        if text.lower() in _TRUE:
            return True
        if text.lower() in _FALSE:
            return False
        raise ValueError(f"{name} must be 1 or 0, got {text!r}")

    return parse


def uri_options(
    query: Mapping[str, str], parsers: Mapping[str, Callable[[str], Any]], uri: str
) -> dict[str, Any]:
    """Parse the query of a backend URI with one parser per accepted key (``ValueError``)."""
    unknown = sorted(set(query) - set(parsers))
    if unknown:
        raise ValueError(
            f"unknown option(s) {', '.join(unknown)} in {uri}; accepted: {', '.join(parsers)}"
        )
    options: dict[str, Any] = {}
    for key, text in query.items():
        try:
            options[key] = parsers[key](text)
        except ValueError as exc:
            raise ValueError(f"{uri}: option {key}={text!r}: {exc}") from None
    return options
