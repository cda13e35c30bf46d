"""One description per device: everything that differs between one device and another.

Every module that depends on the device reads its :class:`Device`: :func:`get` finds one by
any spelling (or a description file's path), :func:`device_of` an env's. A device is described
by a file (TOML or JSON, docs/devices.md) that :func:`load` reads; the built-in servo and
Altino are such files, shipped in ``frictiongym/data/devices``, where each value cites its
source. Adding a device: write its file (docs/devices.md).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from frictiongym import device_file
from frictiongym.data import device_path, device_table
from frictiongym.device_file import Figures
from frictiongym.friction import LuGre, StictionCoulomb
from frictiongym.plants import sensors
from frictiongym.plants.plant import PlantParams

__all__ = [
    "ALTINO",
    "DEVICES",
    "ROTARY",
    "Device",
    "DeviceFileError",
    "Figures",
    "described",
    "device_of",
    "get",
    "load",
    "register",
]

DeviceFileError = device_file.DeviceFileError

#: Largest count of the wire format's ``int16`` command fields (``Command``, ``Hello``).
INT16_MAX = 0x7FFF


@dataclass(frozen=True)
class Device:
    """Everything per-device: names, physics and sensor, env task, units, the tools' settings."""

    name: str  #: ``"RotaryServo"``: the ``device`` of params files, residual models, run logs
    kind: str  #: ``"rotary"``: the hardware's kind, the benchmark's and the CLI's device name
    env_id: str  #: the current id, ``"frictiongym/RotaryServo-v1"`` (tools make their envs by it)
    title: str  #: for messages: ``"a QUBE-Servo 2"``
    plant: PlantParams
    dt: float
    paper_friction: StictionCoulomb
    lugre_friction: LuGre
    #: :data:`~frictiongym.plants.sensors.SENSOR_ENCODER` or ``SENSOR_IR`` (a wall ahead of the
    #: plant at its position 0: the output is the distance to it, and the safety limit the
    #: least distance)
    sensor: int
    velocity_cutoff: float | None  #: rad/s of the velocity filter; None: backward difference
    noise_std: float  #: sensor noise of ``sensor_noise=True``
    episode_steps: int  #: registered episode length
    start: float  #: default starting position (rad, or cm from the wall)
    #: Default generator of each reference kind, as keyword arguments of its class
    #: (:data:`frictiongym.envs.references.PRESET_CLASSES`).
    references: Mapping[str, Mapping[str, Any]]
    error_scale: float  #: tracking error that costs 1 per step
    #: Largest tracking error the v1 reward charges (``terminal_cost=True``), output units
    error_cap: float
    effort_weight: float
    limit: float  #: default safety limit of the env
    limit_penalty: float
    observation_names: tuple[str, ...]
    output: str  #: observation name of the measured controlled output
    #: speed (plant units) below which a friction compensator treats the body as at rest
    rest_speed: float
    position_unit: str  #: of the output: ``"rad"``, ``"cm"``
    command_unit: str  #: ``"V"``, ``"units"``
    #: The paper's PID gains (``kp``, ``ki``, ``kd``) of its plain (``pid``) and its
    #: compensated PID (``compensated``), and of any other of its experiments.
    paper_gains: Mapping[str, Mapping[str, float]]
    benchmark_steps: int  #: length of a benchmark run
    #: Factor ranges of ``frictiongym train --randomize default`` and of the benchmark's
    #: held-out plants.
    randomization: Mapping[str, tuple[float, float]]
    #: The identification plan: ``Plan`` fields (frictiongym/identification/identify.py; its
    #: schedule has no defaults; ``span`` and ``reading`` as tuples of their fields) and the
    #: env arguments it needs; empty: ``identify`` refuses the device. An optional
    #: ``reversal`` entry holds the ``ReversalPlan`` fields of ``identify --backlash``
    #: (frictiongym/identification/backlash.py); without it the device has no reversal test.
    identification: Mapping[str, Any]
    #: Default ``ResidualConfig`` of a residual policy: its fields but ``device`` and ``limit``
    #: (the plant's command limit).
    residual: Mapping[str, float]
    training_env: Mapping[str, Any]  #: ``gym.make`` arguments of the training env
    training_precision: float  #: error scale of ``--reward precision``
    training_gamma: float  #: discount
    #: Firmware command counts per command unit: the wire format's commands are int16, so
    #: ``plant.command_limit * command_scale`` must be at most 32767
    command_scale: int
    figures: Figures
    #: plant position of a rigid end stop (the Altino's wall), whatever plant is simulated
    end_stop: float = math.inf
    #: Encoder counts per revolution with ``SENSOR_ENCODER`` (the wire format's ``Hello``
    #: carries it: at most 65535), 0 without an encoder
    counts_per_rev: int = 0
    #: Position units per encoder revolution: 2π rad; a linear axis's lead
    position_per_rev: float = 2.0 * math.pi
    #: Function of :mod:`frictiongym.envs.rendering` that draws a frame of the position and
    #: reference (``"draw_servo"``); None: the env cannot render
    drawing: str | None = None
    #: The description file it was read from ("" if built in code)
    source: str = ""
    #: ``frictiongym tune``'s specs and gain bounds: ``StepSpecs`` fields and ``kp``, ``ki``,
    #: ``kd`` as (low, high); empty: the paper's specs (the servo's own)
    tuning: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        counts = round(self.plant.command_limit * self.command_scale)
        if not 0 < counts <= INT16_MAX:
            change = "lower" if counts > INT16_MAX else "raise"
            raise ValueError(
                f"{self.name}: plant.command_limit * command_scale = {counts} counts must fit "
                f"the wire format's int16 commands (1..{INT16_MAX}): {change} command_scale"
            )
        if (self.sensor == sensors.SENSOR_ENCODER) != (0 < self.counts_per_rev <= 0xFFFF):
            raise ValueError(
                f"{self.name}: counts_per_rev must be 1..65535 with SENSOR_ENCODER and 0 "
                f"without, got {self.counts_per_rev!r}"
            )

    @property
    def direction(self) -> float:
        """The sign convention: plant position = ``direction`` × the env's position.

        +1 with the encoder; -1 with the IR sensor, whose output is the distance to the wall
        (a positive command drives toward it). So it is also +1 if a positive command
        increases ``output``, -1 if it decreases it.
        """
        return 1.0 if self.sensor == sensors.SENSOR_ENCODER else -1.0

    @property
    def encoder_step(self) -> float:
        """One encoder count, position units (0.0 without an encoder)."""
        return self.position_per_rev / self.counts_per_rev if self.counts_per_rev else 0.0

    @property
    def units(self) -> dict[str, str]:
        """Units of an identified parameter file's quantities (``friction.json``)."""
        force, position = self.command_unit, self.position_unit
        return {
            "force": force,
            "velocity": f"{position}/s",
            "viscous": f"{force}·s/{position}",
            "J": f"{force}·s²/{position}",
            "B": f"{force}·s/{position}",
        }


def load(path: str | os.PathLike[str]) -> Device:
    """Return the device a description file describes (TOML or JSON, docs/devices.md).

    The device is also registered for this process, so :func:`get` finds it by its name or
    kind (a params file, a run log or a residual model names its device).

    Raises
    ------
    DeviceFileError
        The file cannot be read or a field is missing or out of range (the message names it).
    """
    try:
        device = Device(**device_file.read(path))
    except device_file.DeviceFileError:
        raise
    except ValueError as error:  # what the Device checks across fields (the wire's limits)
        raise device_file.DeviceFileError(f"{path}: {error}") from None
    builtin = {d.name: d for d in DEVICES}.get(device.name)
    if builtin is not None or device.kind in {d.kind for d in DEVICES}:
        if builtin is None or dataclasses.replace(device, source=builtin.source) != builtin:
            raise device_file.DeviceFileError(
                f"{path}: name {device.name!r} or kind {device.kind!r} is a built-in device's; "
                "give your device its own name and kind"
            )
        return builtin
    if device.env_id != device_file.AXIS_ENV_ID:
        raise device_file.DeviceFileError(
            f"{path}: env_id: = {device.env_id!r}: a described device's env is "
            f"{device_file.AXIS_ENV_ID}; omit env_id"
        )
    return register(device)


def described() -> tuple[Device, ...]:
    """Return the devices read from description files in this process (:func:`load`)."""
    return tuple(_LOADED.values())


def register(device: Device) -> Device:
    """Make a described device known to :func:`get` in this process, by name and kind.

    A device of the same name or kind read from the same file replaces the earlier one (the
    file was edited); from another file, or built in code, it is refused.

    Raises
    ------
    DeviceFileError
        If another device of this process has the name or the kind.
    """
    for other in (*DEVICES, *_LOADED.values()):
        clash = other.name == device.name or other.kind == device.kind
        if not clash or other == device or _same_file(other.source, device.source):
            continue
        raise device_file.DeviceFileError(
            f"{device.source or device.name}: name {device.name!r} or kind {device.kind!r} is "
            f"also that of {other.source or other.name}, loaded in this process; give each "
            "device its own name and kind"
        )
    for other in [d for d in _LOADED.values() if _same_file(d.source, device.source)]:
        del _LOADED[other.name]  # the same file, edited (or named by another path)
    _LOADED[device.name] = device
    return device


def _same_file(first: str, second: str) -> bool:
    """Whether two descriptions' sources are one file, however each path was spelled."""
    if not first or not second:
        return False
    try:
        return Path(first).resolve() == Path(second).resolve()
    except OSError:
        return first == second


def _builtin(kind: str) -> Device:
    """Return a built-in device, from its file shipped in the package (frictiongym/data/devices)."""
    return Device(**device_file.parse(device_table(kind), str(device_path(kind))))


ROTARY = _builtin("rotary")
ALTINO = _builtin("altino")

#: Every built-in device, in the order of the protocol's device kinds.
DEVICES = (ROTARY, ALTINO)

#: Devices read from description files in this process, by name (:func:`load`).
_LOADED: dict[str, Device] = {}

#: Suffixes of description files.
FILE_SUFFIXES = (".toml", ".json")


def get(spelling: str | os.PathLike[str] | Device) -> Device:
    """Return the device ``spelling`` names: kind, name, env id (any version) or file path.

    A path (``.toml`` or ``.json``, or an existing file of no known name) is read with
    :func:`load`.

    Raises
    ------
    ValueError
        If no device has that name; the message lists the valid ones.
    DeviceFileError
        If a description file cannot be used (a ``ValueError`` too).
    """
    if isinstance(spelling, Device):
        return spelling
    path = Path(os.fspath(spelling)) if isinstance(spelling, str | os.PathLike) else None
    if path is not None and path.suffix.lower() in FILE_SUFFIXES:
        return load(spelling)
    for device in (*DEVICES, *_LOADED.values()):
        if spelling in (device.kind, device.name):
            return device
        if device.env_id != device_file.AXIS_ENV_ID and spelling == device.env_id:
            return device
        if re.fullmatch(rf"frictiongym/{device.name}-v\d+", str(spelling)):
            return device  # another version of its env: the same device, another reward
    if path is not None and path.is_file():  # a description file named otherwise
        return load(spelling)
    names = ", ".join(f"{d.kind}, {d.name}, {d.env_id}" for d in DEVICES)
    raise ValueError(
        f"unknown device {spelling!r}; use one of {names}, or the path of a device "
        "description file (.toml or .json, docs/devices.md)"
    )


def device_of(env: Any) -> Device:
    """Return the device an env drives (single or vector, wrapped or not, simulated or not).

    Raises
    ------
    TypeError
        If ``env`` is not a frictiongym env.
    """
    base = getattr(env, "unwrapped", env)
    device = getattr(base, "device", None)  # set by every frictiongym env class
    if not isinstance(device, Device):
        raise TypeError(
            f"{type(base).__name__} is not a frictiongym env: make it with gym.make("
            f"{', '.join(repr(d.env_id) for d in DEVICES)})"
        )
    return device
