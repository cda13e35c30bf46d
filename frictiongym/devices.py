"""One description per device: everything that differs between the servo and the Altino.

Every module that depends on the device reads its :class:`Device`: :func:`get` finds one by
any spelling, :func:`device_of` an env's. The paper's numbers and the models' presets keep
their sources in :mod:`frictiongym.plants.presets` and :mod:`frictiongym.friction.presets`;
every other value cites its source here. Adding a device: docs/architecture.md.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from frictiongym.friction import LuGre, StictionCoulomb
from frictiongym.friction import presets as friction
from frictiongym.plants import presets, sensors
from frictiongym.plants.plant import PlantParams

__all__ = ["ALTINO", "DEVICES", "ROTARY", "Device", "Figures", "device_of", "get"]

#: Largest count of the wire format's ``int16`` command fields (``Command``, ``Hello``).
INT16_MAX = 0x7FFF


class Figures(NamedTuple):
    """What the benchmark's figures say of a device (:mod:`frictiongym.benchmark.figures`)."""

    response: str  #: title of its paper scenarios' responses
    residual: str  #: title of its residual policy's response
    friction: str  #: title of its friction curves
    speed: float  #: the friction curves' velocity range, ±
    zoom: float  #: error axis of the paper responses, ±
    residual_zoom: float  #: error axis of the residual response, ±


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

    def __post_init__(self) -> None:
        counts = round(self.plant.command_limit * self.command_scale)
        if not 0 < counts <= INT16_MAX:
            raise ValueError(
                f"{self.name}: plant.command_limit * command_scale = {counts} counts must fit "
                f"the wire format's int16 commands (1..{INT16_MAX}): lower command_scale"
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


#: Domain randomisation (docs/envs.md): friction ±30 % (the compensator keeps the paper's
#: model, so the policy meets a compensator up to 30 % too weak or too strong, where the
#: Altino's limit-cycles), inertia and damping ±20 %, and a sensor gain.
_RANDOMIZATION = {"friction": (0.7, 1.3), "inertia": (0.8, 1.2), "damping": (0.8, 1.2)}

ROTARY = Device(
    name="RotaryServo",
    kind="rotary",
    env_id="frictiongym/RotaryServo-v1",
    title="a QUBE-Servo 2",
    plant=presets.ROTARY_PLANT,
    dt=presets.ROTARY_DT,
    paper_friction=friction.ROTARY_PAPER,
    lugre_friction=friction.ROTARY_LUGRE,
    sensor=sensors.SENSOR_ENCODER,
    velocity_cutoff=presets.ROTARY_VELOCITY_CUTOFF,
    noise_std=sensors.QUBE_ENCODER_STEP,  # assumed: one encoder count of vibration or noise
    episode_steps=2500,  # 5 s at the default 2 ms period (the paper's servo plots)
    start=0.0,
    # Defaults of each reference kind (rad); the step is the paper's demo step of 1 rad.
    references={
        "step": {"value": 1.0},
        "step_sequence": {"values": (1.0, -0.5, 0.5, 0.0), "period": 1.25},
        "ramp": {"slope": 0.5},
        "sine": {"amplitude": 1.0, "period": 2.0},
        "random_steps": {"low": -math.pi, "high": math.pi, "period": 1.0},
    },
    error_scale=1.0,  # rad: the default step costs 1 per step until it moves
    # One turn: twice the largest error of a random step (a level in ±π); the safety limit
    # (two turns) ends an episode before the error reaches 5π anyway.
    error_cap=2.0 * math.pi,
    effort_weight=0.01,  # small: 10 V for a whole step costs as much as 10 mrad of error
    limit=4.0 * math.pi,  # assumed run-away guard (two turns); the disk has no end stops
    limit_penalty=100.0,
    observation_names=("angle", "velocity", "reference"),
    output="angle",
    # Assumed: at rest the filtered encoder derivative decays from a last count's pulse
    # (1.5 rad/s for one count per period, times 1 - exp(-50 dt) = 0.095) toward 0; 0.1 rad/s
    # is below that first pulse and 3 % of the paper's v0 (docs/controllers.md).
    rest_speed=0.1,
    position_unit="rad",
    command_unit="V",
    paper_gains={"pid": presets.ROTARY_PAPER_GAINS, "compensated": presets.ROTARY_PAPER_GAINS},
    benchmark_steps=2500,  # the registered 5 s episode (the paper's plots)
    # The encoder scale ±1 %: a calibration error.
    randomization={**_RANDOMIZATION, "sensor_gain": (0.99, 1.01)},
    # Constant levels from just above break-away to 6 times it (the map of Fig. 8(a)), three
    # slow ramps per direction, velocity steps between 3 and 6 times break-away (J and B). The
    # disk has no end stops: the run-away guard is widened (a 4.5 s run at 26 rad/s turns
    # 120 rad).
    identification={
        "levels": (1.03, 1.06, 1.1, 1.15, 1.2, 1.3, 1.45, 1.65, 2.0, 2.5, 3.2, 4.0, 5.0, 6.0),
        "constant_duration": 4.5,
        "ramp_repeats": 3,
        "ramp_from": 0.6,
        "ramp_to": 1.2,
        "ramp_duration": 8.0,
        "step_levels": (3.0, 6.0),
        "step_time": 2.0,
        "step_duration": 4.0,
        "step_repeats": 2,
        "probe_to": 0.3,
        "probe_duration": 3.0,
        "env_kwargs": {"safety_limit": 1.0e5},
        # The reversal test of `identify --backlash` (ReversalPlan). 1.5 times break-away gives
        # 3.9 rad/s forward; a leg of 1 s is six time constants (J/B = 0.16 s). The play is a
        # small part of the overshoot after each reversal, so the rigid model's errors weigh:
        # 0.3 % on u_s moves the estimate by 8 %, on B by 34 % (slower legs trade the second
        # for the first, and resolve less: at 1.3 times the bound is 0.0085 rad, at 1.5 times
        # 0.005 rad). The disc turns freely, so the legs need no band.
        "reversal": {
            "level": 1.5,
            "hold": 1.0,
            "reversals": 12,
            "max_width": 0.2,  # rad, 11.5 degrees
            "resolution": sensors.QUBE_ENCODER_STEP,  # one count
        },
    },
    residual={
        # 10 % of the limit = 1 V, about 5 times the break-away level (0.21 V): enough to
        # supply or cancel the whole friction of a plant whose friction is off by a factor of
        # 2, while the base controller keeps the large-signal response (docs/residual.md).
        "scale": 0.1 * 10.0,
        "error_scale": 1.0,  # rad: the reward's unit and the paper's 1 rad step
        "fine_error": 0.02,  # rad: the 2 % settling band of a 1 rad step, 6.5 encoder counts
        "velocity_scale": 10.0,  # rad/s: a 1 rad step under the paper's PID peaks near 10-20
        "reference_scale": math.pi,  # random-step references lie in ±π
    },
    # Random set-point steps (the benchmark's step references are held out) for 2 s: two
    # set-points, shorter than the registered 5 s so PPO's rollouts span several episodes.
    training_env={"reference": "random_steps", "max_episode_steps": 1000},
    training_precision=sensors.QUBE_ENCODER_STEP,  # one count: an error of one count costs log 2
    # A horizon 1 / (1 - gamma) of 200 steps = 0.4 s, long enough to see a stuck disk's offset
    # after a step's transient (SB3's 0.99 sees 0.2 s).
    training_gamma=0.995,
    command_scale=1000,  # mV (protocol.DeviceKind)
    figures=Figures(
        response="QUBE-Servo 2, 1 rad step (paper Figs. 6, 7)",
        residual="QUBE-Servo 2, 1 rad step, nominal plant: residual policy",
        friction="QUBE-Servo 2 (B_e's viscous part is in the plant)",
        speed=6.0,
        zoom=0.03,
        residual_zoom=0.02,
    ),
    counts_per_rev=sensors.QUBE_COUNTS_PER_REV,
    drawing="draw_servo",
)

ALTINO = Device(
    name="AltinoDistance",
    kind="altino",
    env_id="frictiongym/AltinoDistance-v1",
    title="an Altino car",
    plant=presets.ALTINO_PLANT,
    dt=presets.ALTINO_DT,
    paper_friction=friction.ALTINO_PAPER,
    lugre_friction=friction.ALTINO_LUGRE,
    sensor=sensors.SENSOR_IR,
    velocity_cutoff=None,  # backward difference of the estimate, as docs/altino-model.md
    noise_std=2.0,  # assumed: readout units (0.05 cm at 5 cm); docs/altino-model.md has none
    # 20 s at the default 50 ms period (the paper's runs settle or cycle within it;
    # docs/altino-model.md).
    episode_steps=400,
    start=presets.ALTINO_START_CM,
    # Defaults of each reference kind (cm from the wall); the step is the paper's 5 cm target.
    references={
        "step": {"value": presets.ALTINO_TARGET_CM},
        "step_sequence": {"values": (5.0, 10.0, 7.0, 12.0), "period": 5.0},
        "ramp": {"slope": -0.5, "start": 0.0, "initial": 20.0},  # 20 to 10 cm over 20 s
        "sine": {"amplitude": 3.0, "period": 10.0, "offset": 10.0},
        "random_steps": {"low": 3.0, "high": 18.0, "period": 5.0},
    },
    error_scale=presets.ALTINO_TARGET_CM,  # cm: the target distance costs 1 per step
    # 40 cm: beyond the start (30 cm) and the IR's range (21.5 cm), where the readout is 0 and
    # the car cannot see how far it is; a target of 3-18 cm never costs more from closer.
    error_cap=40.0,
    effort_weight=0.01,
    limit=0.0,  # touching the wall
    limit_penalty=100.0,
    observation_names=("readout", "distance", "velocity", "reference"),
    output="distance",
    # Assumed: at rest the noiseless backward difference is exactly 0, and one IR count at
    # 5 cm per period is 0.52 cm/s; half of it separates the two (docs/controllers.md).
    rest_speed=0.25,
    position_unit="cm",
    command_unit="units",
    paper_gains={
        "pid": presets.ALTINO_PAPER_GAINS_KI10,
        "compensated": presets.ALTINO_PAPER_GAINS_COMPENSATED,
        "pid-ki20": presets.ALTINO_PAPER_GAINS_KI20,
    },
    # 60 s: long enough to tell a slow limit cycle from a stop (docs/altino-model.md §3).
    benchmark_steps=1200,
    # The IR reflectivity ±10 % (assumed; docs/residual.md).
    randomization={**_RANDOMIZATION, "sensor_gain": (0.9, 1.1)},
    # The IR sensor reads only the last 21.47 cm before the wall (paper Eq. (1)), and resolves
    # 0.026 cm at 5 cm but only 0.41 cm at 20 cm. The runs use 3 to 19.5 cm (beyond 19.5 cm, 2
    # counts of noise would push the readout to 0, out of range); the fastest levels cannot
    # reach a steady speed there. Twenty relay runs of 20 s each between 4 and 15 cm, at levels
    # spread geometrically from 1.03 to 2.5 times break-away, cover the map where the sensor
    # resolves it; the output-error refinement fits them in readout counts. (Ten gave standard
    # errors near 1 % on u_c-, too close to the 3 % tolerance; twenty bring them to 0.6 %.)
    identification={
        "levels": (1.03, 1.06, 1.1, 1.15, 1.2, 1.3, 1.45, 1.65, 2.0, 2.5),
        "constant_duration": 20.0,
        "ramp_repeats": 3,
        "ramp_from": 0.6,
        "ramp_to": 1.1,
        "ramp_duration": 15.0,
        "step_levels": (1.5, 2.5),
        "step_time": 0.6,
        "step_duration": 2.0,
        "step_repeats": 0,
        "probe_to": 0.4,
        "probe_duration": 3.0,
        "relay_levels": tuple(round(float(m), 2) for m in np.geomspace(1.03, 2.5, 20)),
        "relay_band": (4.0, 15.0),
        "relay_duration": 20.0,
        "refine": True,
        "reading": (sensors.IR_NUMERATOR, sensors.IR_OFFSET, sensors.IR_MAX_READOUT),
        "span": (3.0, 19.5, 0.5),
        "ramp_positions": (10.0, 4.0),
        # The reversal test: 1.2 times break-away, 5.5 cm/s toward the wall and 11 cm/s away
        # (its map is asymmetric), so a leg across the band takes 1.8 and 0.9 s, six and four
        # time constants. The band lies near the wall, where the IR sensor resolves 0.02 to
        # 0.2 cm per readout count; 24 reversals (about 45 s) halve the scatter of 12 under 2
        # counts of noise.
        "reversal": {
            "level": 1.2,
            "hold": 3.0,
            "reversals": 24,
            "max_width": 1.0,  # cm
            "resolution": 1.0,  # one readout count
            "band": (4.0, 14.0),
        },
    },
    residual={
        # 20 % of the limit = 200 motor units = the break-away level u_s: its friction is a
        # fifth of the command range, so 10 % could not even correct a 50 % error in the
        # compensator's u_s (docs/residual.md).
        "scale": 0.2 * 1000.0,
        "error_scale": 5.0,  # cm: the reward's unit and the paper's 5 cm target
        "fine_error": 0.25,  # cm: 5 % of the target, 5 IR counts at 5 cm
        "velocity_scale": 10.0,  # cm/s
        "reference_scale": 10.0,  # random-step references lie in 3-18 cm: about ±1
        "reference_offset": 10.0,
    },
    # Random set-point steps over the registered 20 s (four set-points).
    training_env={"reference": "random_steps", "max_episode_steps": 400},
    # One IR count at the 5 cm target: |dd/dx| = 966/(x+45)² at x = 966/5 - 45.
    training_precision=5.0**2 / 966.0,
    training_gamma=0.99,  # SB3's: 100 steps = 5 s, a set-point of the training episodes
    command_scale=1,  # the Altino's own motor units
    figures=Figures(
        response="Altino, 30 → 5 cm from the wall (paper Figs. 11, 12)",
        residual="Altino, 30 → 5 cm, nominal plant: residual policy",
        friction="Altino",
        speed=30.0,
        zoom=2.0,
        residual_zoom=1.0,
    ),
    end_stop=0.0,  # the wall: the plant's position is minus the distance to it
    drawing="draw_altino",
)

#: Every device, in the order of the protocol's device kinds.
DEVICES = (ROTARY, ALTINO)


def get(spelling: str | Device) -> Device:
    """Return the device named ``spelling``: its kind, name or an env id of any version.

    Raises
    ------
    ValueError
        If no device has that name; the message lists the valid ones.
    """
    if isinstance(spelling, Device):
        return spelling
    for device in DEVICES:
        if spelling in (device.kind, device.name, device.env_id):
            return device
        if re.fullmatch(rf"frictiongym/{device.name}-v\d+", str(spelling)):
            return device  # another version of its env: the same device, another reward
    names = ", ".join(f"{d.kind}, {d.name}, {d.env_id}" for d in DEVICES)
    raise ValueError(f"unknown device {spelling!r}; use one of {names}")


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
