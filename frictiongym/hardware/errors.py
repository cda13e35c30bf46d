"""The errors a device backend raises: one small tree under :class:`HardwareError`.

Each error subclasses the matching built-in as well (python-control's ``exception.py`` does the
same), so ``except TimeoutError`` or ``except ConnectionError`` also catch ours. Messages say
what to check.
"""

from __future__ import annotations


class HardwareError(RuntimeError):
    """Anything that went wrong between the host and a device; the motor has been zeroed."""


class DeviceNotFoundError(HardwareError, FileNotFoundError):
    """The port or device could not be opened (wrong path, unplugged, no permission)."""


class DeviceTimeoutError(HardwareError, TimeoutError):
    """The device did not answer in time (a frame, a handshake or a write)."""


class StaleSampleError(DeviceTimeoutError):
    """The newest sample is older than the backend allows (``max_age``): the link delays it."""


class DeviceBusyError(DeviceNotFoundError):
    """The port is open in another program (or another backend of this one)."""


class DeviceDisconnectedError(HardwareError, ConnectionError):
    """The link went away mid-run (cable pulled, emulator stopped, port closed)."""


class ProtocolError(HardwareError):
    """The device speaks another protocol version or kind, or its frames make no sense."""


class DeviceFaultError(HardwareError):
    """The device reported a fault: amplifier fault, stall error, watchdog trip or limit."""


class WatchdogTripError(DeviceFaultError):
    """The device's watchdog stopped the motor (no command in time) and nothing else failed.

    The host loop stalled or the link lost frames; the device itself is fine, and the next
    ``start()`` (an env's ``reset()``) re-arms it.
    """


class SDKNotAvailableError(HardwareError, ImportError):
    """A vendor SDK (Quanser's ``quanser.hardware``) is not installed."""
