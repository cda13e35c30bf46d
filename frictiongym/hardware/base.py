"""What every device backend provides: the simulated plant's step, on a device, safely.

A :class:`Backend` opens a link, arms the device, and then, once per control period, holds a
command and returns the next :class:`Sample` of the device's own clock. The base class owns
the safety rules every backend shares, so a subclass cannot forget one:

* a command must be a real number (``int``, ``float`` or a NumPy integer or floating scalar;
  not ``bool``, a string, a date or an array) and finite: anything else never reaches the
  device, the motor is zeroed and ``ValueError`` says what was given; a command beyond the
  device's limit is saturated, as the simulator saturates it;
* a sample older than :attr:`Backend.max_sample_age` (:attr:`Sample.age`; a backend's
  ``max_age``, default :func:`default_max_sample_age`) zeroes the motor and raises
  :class:`~frictiongym.hardware.errors.StaleSampleError`: a loop must not steer on old news;
* the motor is zeroed (and the amplifier disabled where there is one) on :meth:`~Backend.stop`,
  :meth:`~Backend.close`, any exception inside a step (a refused command, a device error, a
  ``KeyboardInterrupt``), on ``SIGTERM`` and ``SIGHUP``
  (:mod:`~frictiongym.hardware.stop_signals`), and at interpreter exit for a backend left open;
* device-side, the firmware's watchdog zeroes the motor when commands stop (a host that dies
  cannot send a stop).

Subclasses implement ``_open``, ``_start``, ``_exchange``, ``_stop`` and ``_close``.
"""

from __future__ import annotations

import atexit
import math
import numbers
import reprlib
import threading
import weakref
from abc import ABC, abstractmethod
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from frictiongym.hardware.errors import HardwareError, StaleSampleError
from frictiongym.hardware.stop_signals import install_stop_signals, release_stop_signals

if TYPE_CHECKING:
    from typing_extensions import Self

#: Device kinds, as the env ids name them.
KINDS = ("rotary", "altino")

#: What a Hello of ``DeviceKind.AXIS`` names: a device described by a file (docs/devices.md).
AXIS_KIND = "axis"


def kind_code(kind: str) -> int:
    """Return the wire's ``DeviceKind`` code of a kind: a built-in one's, else ``AXIS``."""
    return KINDS.index(kind) + 1 if kind in KINDS else len(KINDS) + 1


def kind_of_code(code: int, described: str | None) -> str:
    """Return the device kind of a Hello's code (``described``: the described one expected).

    Raises
    ------
    HardwareError
        A described device's Hello when the host expects none (or an unknown code).
    """
    if 1 <= code <= len(KINDS):
        return KINDS[code - 1]
    if code == len(KINDS) + 1:
        if described is None:
            raise HardwareError(
                "the device is described by a file (docs/devices.md): open it through the env "
                "of that file, gym.make('frictiongym/Axis-v0', device=FILE, backend=...)"
            )
        return described
    raise HardwareError(f"the device names an unknown kind {code}")


@dataclass(frozen=True)
class DeviceInfo:
    """What the host knows about an opened device."""

    kind: str  #: one of :data:`KINDS`, or a described device's kind
    rate_hz: float  #: the device's sample rate (it paces the loop)
    command_limit: float  #: largest |command| it applies, physical units (V or motor units)
    counts_per_rev: int  #: encoder counts per revolution (0 without an encoder)
    watchdog_s: float | None  #: device watchdog time, s (None: the device has none)
    can_place: bool = False  #: honours :meth:`Backend.place` (the emulator)
    distance_limit: bool = False  #: the device itself refuses to drive into the wall
    firmware: str = ""
    link: str = ""  #: the protocol and port, for logs


@dataclass(frozen=True)
class Sample:
    """One tick of the device: the sensor, and the command it held over the period before."""

    measured: float  #: servo: encoder angle, rad; Altino: IR readout 0..800
    applied: float  #: command held over the period ending at this tick, physical units
    tick_us: int  #: device clock at the sample, µs (wraps at 2**32)
    host_ns: int  #: host ``perf_counter_ns`` when the sample arrived
    seq: int = 0  #: the device's frame counter
    seq_applied: int = 0  #: sequence number of the host command held
    status: int = 0  #: device status bits (:class:`frictiongym.hardware.protocol.Status`)
    late: bool = False  #: the command of this step arrived too late and an older one was held
    skipped: int = 0  #: device ticks since the previous sample, minus one
    #: s the device took at least to answer a recent command (:mod:`frictiongym.hardware.echo`;
    #: time the host was stalled does not count; 0.0: the backend cannot tell)
    age: float = 0.0


#: The default bound of :attr:`Sample.age` is this many device periods ...
MAX_SAMPLE_AGE_PERIODS = 5.0
#: ... and at least this long, s: as long as the device's watchdog lets a silent host run.
MIN_MAX_SAMPLE_AGE = 0.1


def default_max_sample_age(rate_hz: float) -> float:
    """Oldest sample a step accepts by default, s: max(5 periods, 0.1 s).

    Five periods leave twice the room of an ordinary late command (no answer 2.5 periods
    after the send); 0.1 s is the servo's watchdog time: as long as the device itself lets a
    silent host drive it, and short enough that at full voltage from rest the disk turns
    5.7 rad, inside the env's 4 pi limit, on news that old.
    """
    return max(MAX_SAMPLE_AGE_PERIODS / rate_hz, MIN_MAX_SAMPLE_AGE)


_NOT_COMMANDS = (bool, np.bool_, np.datetime64, np.timedelta64)


def real_command(command: object) -> float:
    """Return ``command`` as a finite float, or raise ``ValueError`` saying what was given.

    Real numbers only: ``int``, ``float``, ``fractions.Fraction`` and NumPy integer or
    floating scalars. ``bool`` is refused (as the envs refuse a boolean action): ``True`` is
    more likely a bug than a command of 1 V or 1 motor unit.
    """
    if isinstance(command, _NOT_COMMANDS) or not isinstance(command, numbers.Real):
        raise ValueError(
            f"command must be a real number (int or float), got {reprlib.repr(command)} "
            f"({type(command).__name__}); the motor was zeroed and nothing was sent (check the "
            "controller's output)"
        )
    try:
        value = float(command)
    except OverflowError:  # an int beyond the float range: as infinite as inf
        value = math.inf
    if not math.isfinite(value):
        raise ValueError(
            f"command {reprlib.repr(command)} is not a finite number; the motor was zeroed and "
            "nothing was sent (check the controller's output)"
        )
    return value


_OPEN: weakref.WeakSet[Backend] = weakref.WeakSet()


@atexit.register
def _stop_all() -> None:
    """Zero every device still open when the interpreter exits."""
    for backend in list(_OPEN):
        backend.close()


def _stop_open() -> None:
    """Zero every open device's motor, keeping the links (a signal's handler: never raises)."""
    for backend in list(_OPEN):
        backend.stop()


def stop_devices_on_signals() -> None:
    """Stop every open device on ``SIGTERM`` and ``SIGHUP`` from now on, whichever thread opens it.

    Call it from the main thread before a worker thread opens a device: Python lets only the
    main thread set signal handlers, so a device opened elsewhere is otherwise stopped on
    these signals only if a device was open in the main thread at the time.
    """
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("call stop_devices_on_signals() from the main thread")
    install_stop_signals(_stop_open, keep=True)


class Backend(ABC):
    """A device behind a link; see the module docstring for the contract.

    Use as a context manager, or call :meth:`close`; both zero the motor.
    """

    info: DeviceInfo | None = None
    #: The kind of a described device the host expects behind the link (set before ``open``;
    #: a Hello of ``DeviceKind.AXIS`` is taken to be it)
    described_kind: str | None = None
    #: Oldest :attr:`Sample.age` a step accepts, s (None: :func:`default_max_sample_age` of
    #: the device's rate); a backend's ``max_age`` setting.
    max_sample_age: float | None = None
    _armed: bool = False

    @property
    def is_open(self) -> bool:
        """Whether the link is open."""
        return self.info is not None

    @property
    def armed(self) -> bool:
        """Whether the device is armed (between :meth:`start` and :meth:`stop`)."""
        return self._armed

    def open(self) -> DeviceInfo:
        """Open the link and check the device (idempotent); return what it is."""
        if self.info is None:
            self.info = self._open()
            _OPEN.add(self)
            install_stop_signals(_stop_open)
        return self.info

    @property
    def sample_age_limit(self) -> float:
        """Oldest sample a step accepts, s (:attr:`max_sample_age`, or the device's default)."""
        if self.max_sample_age is not None:
            return self.max_sample_age
        return default_max_sample_age(self.open().rate_hz)

    def start(self, *, zero_position: bool = True) -> Sample:
        """Arm the device with a zero command and return its first sample.

        ``zero_position`` zeroes the encoder (servo; the Altino has none).
        """
        self.open()
        with self._stopping_on_error():
            sample = self._checked(self._start(zero_position))
        self._armed = True
        return sample

    def step(self, command: float) -> Sample:
        """Hold ``command`` (physical units) for one device period; return the next sample.

        Any exception inside (a refused command, a device error, a stale sample, a
        ``KeyboardInterrupt``) zeroes the motor first.
        """
        info = self.open()
        with self._stopping_on_error():
            value = real_command(command)
        if not self._armed:  # stopped already
            raise HardwareError(
                "the device is stopped (an episode ended, or an error or a stop() stopped it): "
                "start() it again (an env: reset())"
            )
        value = min(max(value, -info.command_limit), info.command_limit)
        with self._stopping_on_error():
            return self._checked(self._exchange(value))

    def _checked(self, sample: Sample) -> Sample:
        """Return ``sample``, or raise :class:`StaleSampleError` if it is too old."""
        limit = self.sample_age_limit
        if sample.age > limit:
            link = self.info.link if self.info is not None else type(self).__name__
            raise StaleSampleError(
                f"{link} took {sample.age * 1000:.0f} ms to answer a command (limit "
                f"{limit * 1000:.0f} ms): the link delays the device's frames, so a loop would "
                "steer on old news; the motor was zeroed. Check the link (a Bluetooth or network "
                "hop, a loaded USB hub), or raise the backend's max_age if the delay is known "
                "and harmless"
            )
        return sample

    def place(self, position: float) -> None:
        """Put an emulated plant at rest at ``position`` (rad, or cm from the wall)."""
        info = self.open()
        if not info.can_place:
            raise HardwareError(
                f"{info.link or type(self).__name__} cannot be placed: only the emulator can; "
                "put the device at its start by hand"
            )
        try:
            value = real_command(position)
        except ValueError:
            raise ValueError(
                f"position must be a finite real number, got {reprlib.repr(position)} "
                f"({type(position).__name__})"
            ) from None
        self._place(value)

    def stop(self) -> None:
        """Zero the motor and disable it (idempotent; best effort, never raises)."""
        self._armed = False
        if self.info is None:
            return
        try:
            self._stop()
        except Exception:  # a stop must not mask the error that caused it
            pass

    def close(self) -> None:
        """Stop the device and close the link (idempotent)."""
        if self.info is None:
            return
        self.stop()
        try:
            self._close()
        finally:
            self.info = None
            _OPEN.discard(self)
            if not _OPEN:
                release_stop_signals()

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def _stopping_on_error(self) -> Iterator[None]:
        """Zero the motor if the block raises anything, ``KeyboardInterrupt`` included."""
        try:
            yield
        except BaseException:
            self.stop()
            raise

    def _place(self, position: float) -> None:
        raise HardwareError(f"{type(self).__name__} cannot place the plant")

    @abstractmethod
    def _open(self) -> DeviceInfo:
        """Open the link, handshake, leave the motor off; return the device's description."""

    @abstractmethod
    def _start(self, zero_position: bool) -> Sample:
        """Clear latched faults, enable with a zero command, return the first sample."""

    @abstractmethod
    def _exchange(self, command: float) -> Sample:
        """Send the (finite, saturated) ``command``; block until the next sample."""

    @abstractmethod
    def _stop(self) -> None:
        """Send a zero command and disable the motor."""

    @abstractmethod
    def _close(self) -> None:
        """Close the link (after :meth:`_stop`)."""
