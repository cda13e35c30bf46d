"""``emulator://``: an emulated device in this process, driven through the real serial path.

:class:`EmulatedBackend` starts an :class:`~frictiongym.hardware.emulator.Emulator` on a
pseudo-terminal when it opens and talks to it with :class:`SerialBackend`, so everything
between the env and the bytes on the wire is what a device run uses. ``gym.make(ID,
backend="emulator://")`` is the quickest way to try the hardware path without hardware.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

from frictiongym import devices
from frictiongym.hardware.base import KINDS, DeviceInfo
from frictiongym.hardware.emulator import Emulator
from frictiongym.hardware.errors import HardwareError
from frictiongym.hardware.serial_backend import SerialBackend
from frictiongym.hardware.uri import flag, integer, positive, uri_options

#: Watchdog of a lock-step emulator, ms of wall time: its clock only moves when the host sends,
#: so a pause of the host (a compile, a garbage collection) is not a fault; a vanished host is.
LOCKSTEP_WATCHDOG_MS = 1000


class EmulatedBackend(SerialBackend):
    """A :class:`SerialBackend` on its own in-process emulator of ``kind``.

    Parameters
    ----------
    kind : str
        ``"rotary"`` or ``"altino"``.
    lockstep : bool, default False
        Tick the emulated device once per command instead of in real time (exact and
        independent of the host's speed; for tests and reproducible comparisons).
    timeout : float, optional
        The serial side's wait for a state frame (see :class:`SerialBackend`).
    max_age : float, optional
        Oldest sample a step accepts, s (see :class:`SerialBackend`).
    **emulator
        More :class:`~frictiongym.hardware.emulator.Emulator` settings: ``params``,
        ``friction``, ``sensor_noise``, ``watchdog_ms``, ``seed``, ``faults``.
    """

    def __init__(
        self,
        kind: str = "rotary",
        *,
        lockstep: bool = False,
        timeout: float | None = None,
        max_age: float | None = None,
        **emulator: Any,
    ) -> None:
        kind = devices.get(kind).kind  # a ValueError naming the devices
        super().__init__("(emulator not started)", timeout=timeout, max_age=max_age)
        self.kind = kind
        if kind not in KINDS:  # a described device: the emulator and the host share its file
            self.described_kind = kind
        self.lockstep = lockstep
        self.emulator_settings = emulator
        self.emulator: Any = None

    @classmethod
    def from_uri(cls, path: str, query: dict[str, str]) -> EmulatedBackend:
        """Build from ``emulator://KIND?lockstep=1&params=PATH&friction=LAW&noise=1&seed=N&max_age=S``."""
        parsers: dict[str, Callable[[str], Any]] = {
            "lockstep": flag("lockstep"),
            "params": os.fspath,
            "friction": str,
            "noise": flag("noise"),
            "seed": integer("seed"),
            "watchdog_ms": integer("watchdog_ms"),
            "max_age": positive("max_age"),
        }
        settings = uri_options(query, parsers, f"emulator://{path}")
        if "noise" in settings:
            settings["sensor_noise"] = settings.pop("noise")
        return cls(path.strip("/") or "rotary", **settings)

    def _open(self) -> DeviceInfo:
        settings = dict(self.emulator_settings)
        if self.lockstep:  # device time waits for the host: only a long silence is a fault
            settings.setdefault("watchdog_ms", LOCKSTEP_WATCHDOG_MS)
        self.emulator = Emulator(self.kind, lockstep=self.lockstep, **settings)
        try:
            self.port = self.emulator.serve_pty()
            return super()._open()
        except BaseException as exc:
            emulator, self.emulator = self.emulator, None
            emulator.close()
            if emulator.error is None or not isinstance(exc, HardwareError):
                raise
            # The link only saw the device go quiet; say why it did.
            raise HardwareError(
                f"the emulator of {self.kind!r} stopped: {emulator.error!r}"
            ) from emulator.error

    def _close(self) -> None:
        try:
            super()._close()
        finally:
            if self.emulator is not None:
                self.emulator.close()
                self.emulator = None
