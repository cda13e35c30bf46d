"""Device backends: the simulated plant's step contract, on a QUBE-Servo 2 or an Altino.

Pick one with ``gym.make(id, backend=...)``, by object or URI (:func:`resolve_backend`):

=======================================  ======================================================
``sim`` / ``sim://``                     the simulator (default)
``serial:///dev/ttyACM0?baud=1000000``   our firmware over a serial port (``SerialBackend``)
``socket://127.0.0.1:5000``              our firmware or the emulator over TCP
``/dev/pts/7``, ``COM3``                 a plain port path is ``serial://``
``emulator://`` (``?lockstep=1``)        an emulator of the env's device, in this process
``altino-stock:///dev/rfcomm0``          an Altino on its stock firmware (``AltinoStockBackend``)
``quanser-hil://qube_servo2_usb/0``      a QUBE-Servo 2 over Quanser's SDK (``QuanserHILBackend``)
=======================================  ======================================================

Errors are :class:`HardwareError` subclasses (:mod:`frictiongym.hardware.errors`).
"""

from __future__ import annotations

import importlib
from typing import Any
from urllib.parse import urlencode, urlsplit, urlunsplit

from frictiongym.hardware.base import KINDS, Backend, DeviceInfo, Sample, stop_devices_on_signals
from frictiongym.hardware.errors import (
    DeviceDisconnectedError,
    DeviceFaultError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    HardwareError,
    ProtocolError,
    SDKNotAvailableError,
    WatchdogTripError,
)
from frictiongym.hardware.uri import query_options

__all__ = [
    "KINDS",
    "AltinoStockBackend",
    "Backend",
    "DeviceDisconnectedError",
    "DeviceFaultError",
    "DeviceInfo",
    "DeviceNotFoundError",
    "DeviceTimeoutError",
    "EmulatedBackend",
    "Emulator",
    "HardwareError",
    "ProtocolError",
    "QuanserHILBackend",
    "SDKNotAvailableError",
    "Sample",
    "SerialBackend",
    "WatchdogTripError",
    "resolve_backend",
    "stop_devices_on_signals",
]

#: Classes imported on first use (pyserial, the emulator's simulation): name -> module.
_LAZY = {
    "SerialBackend": "frictiongym.hardware.serial_backend",
    "EmulatedBackend": "frictiongym.hardware.emulated",
    "Emulator": "frictiongym.hardware.emulator",
    "AltinoStockBackend": "frictiongym.hardware.altino_stock",
    "QuanserHILBackend": "frictiongym.hardware.quanser_hil",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'frictiongym.hardware' has no attribute {name!r}")


#: URI scheme -> backend class (of :data:`_LAZY`); each class has ``from_uri(path, query)``.
SCHEMES = {
    "serial": "SerialBackend",
    "altino-stock": "AltinoStockBackend",
    "quanser-hil": "QuanserHILBackend",
    "emulator": "EmulatedBackend",
}
#: pyserial's own URL handlers, passed to :class:`SerialBackend` with the query options pyserial
#: takes for each; the others (``baud``, ``timeout``, ``max_age``) are the backend's.
PYSERIAL_SCHEMES = {
    "socket": ("logging",),
    "rfc2217": ("logging", "ign_set_control", "poll_modem", "timeout"),
    "spy": ("file", "color", "raw", "all"),
    "loop": ("logging",),
}
SIM = ("sim", "sim://")


def _backend_class(scheme: str) -> Any:
    return __getattr__(SCHEMES[scheme])


def resolve_backend(spec: object, kind: str) -> Backend | None:
    """Return the backend ``spec`` names for a device of ``kind`` (``None``: the simulator).

    Parameters
    ----------
    spec : str, Backend or None
        A :class:`Backend`, a URI (see the module docstring), a port path, or ``"sim"``.
    kind : str
        ``"rotary"`` or ``"altino"``: the env's device (``emulator://`` emulates it).
    """
    if spec is None or spec in SIM:
        return None
    if isinstance(spec, Backend):
        return spec
    if not isinstance(spec, str):
        raise TypeError(f"backend must be a URI string or a Backend, got {spec!r}")
    parts = urlsplit(spec)
    scheme = parts.scheme.lower()
    if spec.strip().lower() in SIM or scheme == "sim":  # not a port called "SIM"
        raise ValueError(f"backend {spec!r}: the simulator is 'sim' (lower case) or None")
    if scheme in PYSERIAL_SCHEMES:  # pyserial's options stay in its URL, ours are taken out
        query = query_options(parts.query, spec)
        theirs = {k: v for k, v in query.items() if k in PYSERIAL_SCHEMES[scheme]}
        url = urlunsplit(parts._replace(query=urlencode(theirs)))
        ours = {k: v for k, v in query.items() if k not in theirs}
        serial_backend: Backend = _backend_class("serial").from_uri(url, ours)
        return serial_backend
    if not scheme or (len(scheme) == 1 and spec[1:2] == ":"):  # a path, or a Windows drive
        return _backend_class("serial")(spec)
    if scheme not in SCHEMES:
        raise ValueError(
            f"unknown backend {spec!r}; use 'sim', a port path, or one of the schemes "
            f"{sorted([*SCHEMES, *PYSERIAL_SCHEMES])} (e.g. serial:///dev/ttyACM0?baud=1000000)"
        )
    query = query_options(parts.query, spec)
    path = parts.netloc + parts.path
    if scheme == "emulator":
        path = path or kind
    elif not path and scheme != "quanser-hil":
        raise ValueError(f"{spec!r} names no port; e.g. {scheme}:///dev/ttyACM0")
    backend: Backend = _backend_class(scheme).from_uri(path, query)
    return backend
