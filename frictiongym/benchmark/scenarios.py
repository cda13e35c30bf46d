"""Named benchmark scenarios: the paper's experiments and the robustness grids around them.

A :class:`Scenario` is an env id with its keyword arguments, a controller recipe (PID gains,
and the compensator's variant and model mismatch if any) and the seeds to run. Scenarios
that differ only in their seed run side by side in one vector env.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from frictiongym import devices
from frictiongym.controllers import PID, Controller, FrictionCompensator, PIDGains
from frictiongym.controllers.compensation import MODES, Mode
from frictiongym.controllers.residual import ResidualController, read_metadata
from frictiongym.devices import ALTINO, DEVICES, ROTARY, Device
from frictiongym.envs import AXIS_ID
from frictiongym.friction import FRICTION_NAMES

#: The compensator's model mismatch grid: ±20 % and ±50 % in friction level.
MISMATCH_SCALES = (0.5, 0.8, 1.0, 1.2, 1.5)
#: Seeds of the noisy scenarios (the noiseless ones are deterministic: one run).
NOISE_SEEDS = (0, 1, 2, 3, 4)
GROUPS = ("paper", "mismatch", "noise", "friction", "drivetrain", "residual")
#: Widths of the actuator dead zone in the ``drivetrain`` group, as fractions of the device's
#: break-away level (the larger of its two directions, paper friction).
DEAD_ZONE_FRACTIONS = (0.25, 0.5, 1.0)
#: Plays between motor and load in the ``drivetrain`` group, in each device's position units.
#: Servo: 0.5, 1 and 2 degrees of the disc, from a good small gearbox to a worn hobby servo's
#: output (the QUBE itself has none: its disc sits on the motor shaft). Altino: 0.05, 0.1 and
#: 0.2 cm of car travel, 1 to 5 degrees of wheel play on a wheel of about 2.5 cm radius. Both
#: assumed, not measured (docs/results.md).
BACKLASH_WIDTHS = {  # device: (label, width in its position unit)
    "rotary": tuple((f"{degrees:g}deg", math.radians(degrees)) for degrees in (0.5, 1.0, 2.0)),
    "altino": tuple((f"{cm:g}cm", cm) for cm in (0.05, 0.1, 0.2)),
}
#: Plays of a described device with an encoder (docs/devices.md), in its encoder counts.
BACKLASH_COUNTS = (4, 8, 16)
#: Seeds of the held-out randomised plants of the ``residual`` group: disjoint from training,
#: whose env copies are seeded ``S + i`` for small ``S`` (``frictiongym train --seed``).
HELDOUT_SEED = 1000
#: Held-out plants per device (``--heldout``; 4 with ``--quick``).
HELDOUT_PLANTS = 20


@dataclass(frozen=True)
class Scenario:
    """One benchmark case.

    Parameters
    ----------
    name : str
        Unique name, e.g. ``paper-rotary-pid``.
    group : str
        ``paper``, ``mismatch``, ``noise``, ``friction``, ``drivetrain`` or ``residual``.
    env_id : str
    gains : PIDGains
    mode : str or None
        Compensator variant (:data:`frictiongym.controllers.MODES`); None: plain PID.
    scale : float
        Compensator model mismatch (friction levels times ``scale``).
    env_kwargs : dict
        ``gym.make`` keyword arguments (friction law, noise, ...).
    seeds : tuple of int
        One run per seed.
    description : str
        What the scenario shows, for the report.
    residual : str or None
        Path of a residual model (``frictiongym train``'s ``model.zip``): the controller is
        :class:`~frictiongym.controllers.ResidualController` on the base it was trained with,
        and ``gains`` and ``mode`` only describe that base.
    dead_zone : float
        The actuator dead zone the compensator models (its ``dead_zone=``; 0: none).
    """

    name: str
    group: str
    env_id: str
    gains: PIDGains
    mode: Mode | None = None
    scale: float = 1.0
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    seeds: tuple[int, ...] = (0,)
    description: str = ""
    residual: str | None = None
    dead_zone: float = 0.0

    @property
    def controller_name(self) -> str:
        """``pid``, ``compensated-pid`` or ``residual``."""
        if self.residual is not None:
            return "residual"
        return "pid" if self.mode is None else "compensated-pid"

    @property
    def steps(self) -> int:
        """Steps per run (the device's ``benchmark_steps``)."""
        return devices.get(self.env_id).benchmark_steps

    @property
    def device(self) -> str:
        """The device's kind: ``rotary`` or ``altino``."""
        return devices.get(self.env_id).kind

    def controller(self, env: Any) -> Controller:
        """Build the scenario's controller for ``env``."""
        if self.residual is not None:
            return ResidualController.load(self.residual, env)
        pid = PID.for_env(env, self.gains)
        if self.mode is None:
            return pid
        return FrictionCompensator(pid, mode=self.mode, scale=self.scale, dead_zone=self.dead_zone)

    def compensator_record(self) -> dict[str, Any]:
        """Return the compensator's settings as ``results.json`` records them."""
        zone = {"dead_zone": self.dead_zone} if self.dead_zone else {}
        return {"mode": self.mode, "scale": self.scale, **zone}


def paper_scenarios() -> list[Scenario]:
    """Return the paper's experiments with its gains (§3.1, §3.2, §5), on the default models."""
    rotary, servo = {"friction": "paper"}, PIDGains(**ROTARY.paper_gains["pid"])
    car = {name: PIDGains(**gains) for name, gains in ALTINO.paper_gains.items()}
    return [
        Scenario(
            "paper-rotary-nominal",
            "paper",
            ROTARY.env_id,
            servo,
            env_kwargs={"friction": "none"},
            description="the paper's PID on the nominal (frictionless) servo: the specs check",
        ),
        Scenario(
            "paper-rotary-pid",
            "paper",
            ROTARY.env_id,
            servo,
            env_kwargs=rotary,
            description="PID on the servo with the paper's friction (Figs. 6, 7)",
        ),
        Scenario(
            "paper-rotary-compensated",
            "paper",
            ROTARY.env_id,
            servo,
            mode="command",
            env_kwargs=rotary,
            description="the same PID plus the friction compensator",
        ),
        Scenario(
            "paper-altino-pid-ki10",
            "paper",
            ALTINO.env_id,
            car["pid"],
            description="Altino PID Kp 25, Ki 10, Kd 12: the paper sees an offset (Fig. 11)",
        ),
        Scenario(
            "paper-altino-pid-ki20",
            "paper",
            ALTINO.env_id,
            car["pid-ki20"],
            description="Altino PID with Ki 20: the paper sees a limit cycle (Fig. 11)",
        ),
        Scenario(
            "paper-altino-compensated",
            "paper",
            ALTINO.env_id,
            car["compensated"],
            mode="command",
            description="compensated PID Kp 25, Ki 0.5, Kd 7: the paper "
            "sees rise and settling under 1 s (Fig. 12)",
        ),
    ]


def env_id_of(device: Device) -> str:
    """Return the ``env_id`` of ``device``'s scenarios: its env id, or its description file."""
    return device.source if device.env_id == AXIS_ID and device.source else device.env_id


def _devices(among: Sequence[Device] = DEVICES) -> Iterator[tuple[str, str, PIDGains, PIDGains]]:
    """Yield (kind, env id, PID gains, compensated-PID gains) of every device ``among``."""
    for device in among:
        gains = device.paper_gains
        pid, compensated = PIDGains(**gains["pid"]), PIDGains(**gains["compensated"])
        yield device.kind, env_id_of(device), pid, compensated


def device_scenarios(device: Device) -> list[Scenario]:
    """Return the paper group of a described device: its PID and compensated PID, its step."""
    variants: tuple[tuple[str, str, Mode | None, str], ...] = (
        ("pid", "pid", None, "PID (the file's gains)"),
        ("compensated", "compensated", "command", "PID + compensator (the file's gains)"),
    )
    return [
        Scenario(
            f"paper-{device.kind}-{kind}",
            "paper",
            env_id_of(device),
            PIDGains(**device.paper_gains[gains]),
            mode=mode,
            description=what,
        )
        for kind, gains, mode, what in variants
    ]


def _backlash_widths(device: Device) -> tuple[tuple[str, float], ...]:
    """Return the plays of ``device``: the built-in ones' (assumed), or a few encoder counts."""
    if device.kind in BACKLASH_WIDTHS:
        return BACKLASH_WIDTHS[device.kind]
    if not device.encoder_step:
        return ()
    return tuple((f"{n}counts", n * device.encoder_step) for n in BACKLASH_COUNTS)


def mismatch_scenarios(
    modes: tuple[Mode, ...] = MODES,
    scales: tuple[float, ...] = MISMATCH_SCALES,
    among: Sequence[Device] = DEVICES,
) -> list[Scenario]:
    """Return every compensator variant with its model's friction levels scaled (paper friction)."""
    return [
        Scenario(
            f"mismatch-{device}-{mode}-x{scale:g}",
            "mismatch",
            env_id,
            gains,
            mode=mode,
            scale=scale,
            description=f"{mode} variant, model friction x{scale:g}",
        )
        for device, env_id, _, gains in _devices(among)
        for mode in modes
        for scale in scales
    ]


def _pid_and_compensated(
    name: str,
    group: str,
    what: str,
    env_kwargs: dict[str, Any],
    seeds: tuple[int, ...] = (0,),
    among: Sequence[Device] = DEVICES,
) -> list[Scenario]:
    """Return the PID and compensated PID of each device ``among`` (``name``: a template)."""
    out = []
    for device, env_id, pid_gains, comp_gains in _devices(among):
        variants: tuple[tuple[str, PIDGains, Mode | None], ...] = (
            ("pid", pid_gains, None),
            ("compensated", comp_gains, "command"),
        )
        for kind, gains, mode in variants:
            out.append(
                Scenario(
                    name.format(device=device, kind=kind),
                    group,
                    env_id,
                    gains,
                    mode=mode,
                    env_kwargs=env_kwargs,
                    seeds=seeds,
                    description=f"{kind}, {what}",
                )
            )
    return out


def noise_scenarios(
    seeds: tuple[int, ...] = NOISE_SEEDS, among: Sequence[Device] = DEVICES
) -> list[Scenario]:
    """Return PID and compensated PID with sensor noise off, on (several seeds) and ideal."""
    variants: tuple[tuple[str, str, dict[str, Any], tuple[int, ...]], ...] = (
        ("off", "sensor noise off", {"sensor_noise": False}, (0,)),
        ("on", "sensor noise on", {"sensor_noise": True}, seeds),
        ("ideal", "ideal sensor: no noise, no quantisation", {"quantize": False}, (0,)),
    )
    return [
        s
        for label, what, kwargs, runs in variants
        for s in _pid_and_compensated(
            f"noise-{{device}}-{{kind}}-{label}", "noise", what, kwargs, runs, among
        )
    ]


def friction_scenarios(
    laws: tuple[str, ...] = FRICTION_NAMES, among: Sequence[Device] = DEVICES
) -> list[Scenario]:
    """Return PID and compensated PID (paper model) against each friction law of the plant."""
    return [
        s
        for law in laws
        for s in _pid_and_compensated(
            f"friction-{{device}}-{law}-{{kind}}",
            "friction",
            f"{law} law",
            {"friction": law},
            among=among,
        )
    ]


def drivetrain_scenarios(
    fractions: tuple[float, ...] = DEAD_ZONE_FRACTIONS, among: Sequence[Device] = DEVICES
) -> list[Scenario]:
    """Return PID and compensated PID with an actuator dead zone, then a play, in the plant.

    The dead zone's half-width is a fraction of each device's break-away level. The
    compensator models friction only (``compensated``), or friction and the zone
    (``compensated-zone``: it sends the zone's inverse). The plays are
    :data:`BACKLASH_WIDTHS`; the compensator models friction only.
    """
    return _dead_zone_scenarios(fractions, among) + _backlash_scenarios(among)


def _backlash_scenarios(among: Sequence[Device]) -> list[Scenario]:
    out = []
    for device_kind, env_id, pid_gains, comp_gains in _devices(among):
        described = devices.get(env_id)
        unit = described.position_unit
        variants: tuple[tuple[str, PIDGains, Mode | None], ...] = (
            ("pid", pid_gains, None),
            ("compensated", comp_gains, "command"),
        )
        for label, width in _backlash_widths(described):
            for kind, gains, mode in variants:
                out.append(
                    Scenario(
                        f"drivetrain-{device_kind}-backlash-{label}-{kind}",
                        "drivetrain",
                        env_id,
                        gains,
                        mode=mode,
                        env_kwargs={"backlash": width},
                        description=f"{kind}, play of {width:.3g} {unit} ({label}) between "
                        "motor and load",
                    )
                )
    return out


def _dead_zone_scenarios(fractions: tuple[float, ...], among: Sequence[Device]) -> list[Scenario]:
    out = []
    for device_kind, env_id, pid_gains, comp_gains in _devices(among):
        device = devices.get(env_id)
        breakaway = max(device.paper_friction.breakaway)
        variants: tuple[tuple[str, PIDGains, Mode | None, bool], ...] = (
            ("pid", pid_gains, None, False),
            ("compensated", comp_gains, "command", False),
            ("compensated-zone", comp_gains, "command", True),
        )
        for fraction in fractions:
            width = fraction * breakaway
            for kind, gains, mode, modelled in variants:
                out.append(
                    Scenario(
                        f"drivetrain-{device_kind}-deadzone-x{fraction:g}-{kind}",
                        "drivetrain",
                        env_id,
                        gains,
                        mode=mode,
                        env_kwargs={"deadzone": width},
                        description=f"{kind}, dead zone ±{width:g} {device.command_unit} "
                        f"({fraction:g} x break-away)",
                        dead_zone=width if modelled else 0.0,
                    )
                )
    return out


def residual_scenarios(
    device: str,
    model: str,
    plants: int = HELDOUT_PLANTS,
    randomize: dict[str, Any] | None = None,
    first_seed: int = HELDOUT_SEED,
) -> list[Scenario]:
    """Return compensated PID and a residual model side by side on the paper's step.

    Two pairs per device: the paper's plant with its nominal parameters (``nominal``) and
    ``plants`` held-out randomised plants (``heldout``, seeds ``first_seed...``, factors
    drawn from ``randomize``, by default the training ranges of ``frictiongym train``). A
    plant's factors depend only on its seed, so both controllers meet the same plants: the
    comparison is paired.
    """
    described = devices.get(device)  # ValueError naming the devices
    if plants < 1:
        raise ValueError(f"the held-out plants must be at least 1, got {plants}")
    env_id, device = env_id_of(described), described.kind
    gains = PIDGains(**described.paper_gains["compensated"])
    ranges = randomize or described.randomization
    heldout = {"randomize": {k: tuple(v) for k, v in ranges.items()}}
    seeds = tuple(range(first_seed, first_seed + plants))
    out = []
    for plant, kwargs, plant_seeds, what in (
        ("nominal", {}, (0,), "the paper's plant, nominal parameters"),
        ("heldout", heldout, seeds, f"{plants} held-out randomised plants"),
    ):
        for kind, path in (("compensated", None), ("residual", model)):
            out.append(
                Scenario(
                    f"residual-{device}-{plant}-{kind}",
                    "residual",
                    env_id,
                    gains,
                    mode="command",
                    env_kwargs=kwargs,
                    seeds=plant_seeds,
                    description=f"{kind}, {what}",
                    residual=path,
                )
            )
    return out


def model_scenarios(
    device: str, model: str, plants: int = HELDOUT_PLANTS, first_seed: int = HELDOUT_SEED
) -> list[Scenario]:
    """Return :func:`residual_scenarios` of a model zip, on plants from its training ranges.

    What ``frictiongym benchmark --residual DEVICE=MODEL`` runs (and ``frictiongym sweep``
    for each trial's ``best.zip``).

    Raises
    ------
    FileNotFoundError, ValueError
        For a missing or unreadable model, or one trained on another device than ``device``.
    """
    meta = read_metadata(model)
    if meta["config"]["device"] != devices.get(device).name:
        raise ValueError(
            f"--residual {device}={model}: the model is for {meta['config']['device']}, "
            f"not for {device}"
        )
    randomize = meta.get("env_kwargs", {}).get("randomize")
    return residual_scenarios(device, model, plants, randomize, first_seed)


def all_scenarios(quick: bool = False, device: Device | None = None) -> list[Scenario]:
    """Return the default benchmark; ``quick``: the paper's scenarios and a small mismatch grid.

    ``device``: only that device's scenarios (a described device's paper group is its PID and
    compensated PID on its default step, :func:`device_scenarios`).
    """
    among = DEVICES if device is None else (device,)
    if device is None:
        paper = paper_scenarios()
    elif device in DEVICES:
        paper = [s for s in paper_scenarios() if s.device == device.kind]
    else:
        paper = device_scenarios(device)
    if quick:
        return paper + mismatch_scenarios(("command",), (0.5, 1.5), among)
    return (
        paper
        + mismatch_scenarios(among=among)
        + noise_scenarios(among=among)
        + friction_scenarios(among=among)
        + drivetrain_scenarios(among=among)
    )
