"""pyserial and its ports: importing it, recognising a port another program holds, naming who.

Backends open their ports with pyserial's ``exclusive=True`` (a ``flock`` on POSIX; Windows
ports are exclusive anyway), so a second host on one port fails to open it instead of sharing
the device's stream and both driving its motor.
"""

from __future__ import annotations

import os
from typing import Any

from frictiongym.hardware.errors import DeviceBusyError, SDKNotAvailableError


def pyserial() -> Any:
    """Import pyserial, or raise :class:`SDKNotAvailableError` saying how to install it."""
    try:
        import serial
    except ImportError as exc:
        raise SDKNotAvailableError(
            "serial backends need pyserial: pip install 'frictiongym[hardware]' (or pyserial)"
        ) from exc
    return serial


def is_lock_failure(exc: BaseException) -> bool:
    """Whether pyserial's open failed on the exclusive lock (another program holds the port)."""
    return "exclusively lock" in str(exc)


def port_users(port: str) -> list[str]:
    """Return the processes with ``port`` open, as ``"pid 123 (python)"`` (Linux; best effort)."""
    try:
        target = os.path.realpath(port)
        pids = [name for name in os.listdir("/proc") if name.isdigit()]
    except OSError:
        return []
    users = []
    for pid in pids:
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
            if not any(os.readlink(f"/proc/{pid}/fd/{fd}") == target for fd in fds):
                continue
            with open(f"/proc/{pid}/comm") as comm:
                name = comm.read().strip()
        except OSError:  # gone, or not ours to look at
            continue
        users.append(f"pid {pid} ({name})" + (", this process" if int(pid) == os.getpid() else ""))
    return users


def port_busy_error(port: str) -> DeviceBusyError:
    """Return the error of a port another program holds, naming it where the system lets us."""
    users = port_users(port)
    who = f" ({'; '.join(users)})" if users else ""
    return DeviceBusyError(
        f"{port!r} is in use by another program{who}: only one host may drive a device. Close "
        "it (or the other env), or use another port"
    )


__all__ = ["is_lock_failure", "port_busy_error", "port_users", "pyserial"]
