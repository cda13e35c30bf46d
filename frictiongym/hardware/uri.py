"""Parsing the query options of backend URIs (``serial://PATH?baud=N``): one parser per key."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any
from urllib.parse import parse_qsl, urlsplit


def positive(name: str) -> Callable[[str], float]:
    """Parser of a positive, finite number option."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
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


def query_options(query: str, uri: str) -> dict[str, str]:
    """Return the ``key=value`` pairs of a URI's query; a key given twice is a ``ValueError``."""
    options: dict[str, str] = {}
    for key, value in parse_qsl(query, keep_blank_values=True):
        if key in options:
            raise ValueError(
                f"{uri}: option {key} is given twice ({options[key]!r} and {value!r}); keep one"
            )
        options[key] = value
    return options


def check_socket_url(url: str) -> tuple[str, int]:
    """Return the host and port of ``socket://HOST:PORT`` (a ``ValueError`` says what is wrong)."""
    parts = urlsplit(url)
    example = "e.g. socket://127.0.0.1:5000 (the URL the emulator printed)"
    try:
        port = parts.port
    except ValueError:
        raise ValueError(f"{url}: the port must be a number in 0..65535; {example}") from None
    if not parts.hostname or port is None:
        raise ValueError(f"{url} names no {'port' if parts.hostname else 'host'}; {example}")
    return parts.hostname, port


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
