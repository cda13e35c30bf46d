"""The batched simulation behind both env classes: N envs of one device on the env kernel.

:class:`Device` describes what an env id simulates (plant, sensor, task defaults);
:class:`Simulation` holds the state and parameters of N such envs, prepares resets from each
env's own generator and steps them all with one call of the env kernel. The single env is a
``Simulation`` of one; the vector env one of N: same code, same draws, same trajectories.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym.devices import Device
from frictiongym.envs import _kernel as ek
from frictiongym.envs.randomization import DomainRandomization, apply_factors
from frictiongym.envs.references import Reference, resolve_reference
from frictiongym.friction import FrictionModel, friction_from_name
from frictiongym.params import DeviceParams, ParamsFileError, resolve_params
from frictiongym.plants.plant import PlantParams, default_substeps, plant_row
from frictiongym.plants.sensors import QUBE_ENCODER_STEP, ir_quantum, velocity_floor
from frictiongym.plants.threads import select_kernel

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: Keys accepted in ``reset(options=...)``.
RESET_OPTIONS = ("position", "velocity", "reference")


def _number(name: str, value: object, rule: str = "finite") -> float:
    """``value`` as a float, checked to be finite and, by ``rule``, ``">= 0"`` or ``"> 0"``."""
    if not (isinstance(value, numbers.Real) and not isinstance(value, bool)):
        raise TypeError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or (rule == ">= 0" and v < 0.0) or (rule == "> 0" and v <= 0.0):
        raise ValueError(f"{name} must be {rule}, got {value!r}")
    return v


def _device_params(
    device: Device,
    params: str | os.PathLike[str] | DeviceParams,
    friction: object,
    plant: object,
) -> DeviceParams:
    """Load ``params`` and check it fits this device and is the only source of the physics.

    ``friction="paper"``, the default law, is accepted: the file's law replaces it.
    """
    pairs = (("friction", None if friction == "paper" else friction), ("plant", plant))
    given = [name for name, value in pairs if value is not None]
    if given:
        raise ValueError(
            f"params and {' and '.join(given)} both set the simulated physics; pick one: "
            "params=PATH (the identified file) or friction=/plant= (presets or objects)"
        )
    loaded = resolve_params(params)
    if loaded.device is not None and loaded.device != device.name:
        raise ParamsFileError(
            f"{loaded.source or 'params'}: identified on device {loaded.device!r}, but this env "
            f"simulates {device.name!r}; their units differ (identify this device, or make the "
            f"env of {loaded.device!r})"
        )
    return loaded


class Simulation:
    """N simulated envs of one device.

    Parameters
    ----------
    device : Device
        What to simulate.
    num_envs : int
        Batch size.
    friction : str or FrictionModel, optional
        A law's name (``paper``, ``none``, ``coulomb``, ``stribeck``, ``lugre``) built from the
        device's presets, or a model (default ``"paper"``; with ``params``, the file's law).
    dt : float, optional
        Control period, s (default: the device's).
    reference : str, float or Reference, default "step"
        Default reference of every episode (see :func:`resolve_reference`).
    sensor_noise : bool or float, default False
        Additive sensor noise: False (none), True (the device's default level) or a standard
        deviation in sensor units (rad for the encoder, readout units for the IR sensor).
    quantize : bool, default True
        Quantise as the sensor does (encoder counts, integer IR readout).
    delay : float, optional
        Actuator dead time, s, a whole number of periods (default: the device's, rounded to
        whole periods).
    randomize : dict or DomainRandomization, optional
        Factors drawn at each reset.
    plant : PlantParams, optional
        Nominal plant (default: the device's).
    params : str, PathLike or DeviceParams, optional
        Identified parameters (a ``friction.json``, its directory, or loaded): the plant gets
        the file's ``J`` and total damping ``B``, the friction its law without the viscous
        slope (``B`` includes it; :mod:`frictiongym.params`). Excludes ``plant`` and
        a ``friction`` other than ``"paper"``. Also the compensators' default model
        (:attr:`model_friction`).
    effort_weight, safety_limit, limit_penalty : float, optional
        Reward and safety settings (defaults: the device's).
    max_episode_steps : int, optional
        Truncate episodes after this many steps (the vector env; the single env leaves it to
        the registered ``TimeLimit``).
    parallel : bool, optional
        ``True``: numba's threads; ``False``: one thread. Default: from
        ``PARALLEL_MIN_PLANTS`` envs on, whichever is faster at the moment
        (:class:`~frictiongym.plants.threads.AdaptiveKernel`; results are bit-identical).
    """

    device: Device
    num_envs: int
    dt: float
    friction: FrictionModel
    #: The identified friction a compensator models by default: ``params.friction``, else the
    #: device's paper preset (whatever law the plant runs).
    model_friction: FrictionModel
    params: DeviceParams | None
    plant: PlantParams
    delay_steps: int
    reference: Reference
    randomize: DomainRandomization | None
    limit: float
    config: FloatArray
    substeps: int
    head: int
    parallel: bool
    _kernel: Callable[..., int]
    _nominal_row: FloatArray
    _default_x0: float
    _default_reference_row: FloatArray

    def __init__(
        self,
        device: Device,
        num_envs: int = 1,
        *,
        friction: str | FrictionModel | None = None,
        dt: float | None = None,
        reference: str | float | Reference = "step",
        sensor_noise: bool | float = False,
        quantize: bool = True,
        delay: float | None = None,
        randomize: Mapping[str, Any] | DomainRandomization | None = None,
        plant: PlantParams | None = None,
        params: str | os.PathLike[str] | DeviceParams | None = None,
        effort_weight: float | None = None,
        safety_limit: float | None = None,
        limit_penalty: float | None = None,
        max_episode_steps: int | None = None,
        parallel: bool | None = None,
    ) -> None:
        if not isinstance(num_envs, numbers.Integral) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.device = device
        self.num_envs = int(num_envs)
        self.dt = device.dt if dt is None else _number("dt", dt, "> 0")
        self.params = None if params is None else _device_params(device, params, friction, plant)
        if self.params is not None:
            friction = self.params.plant_friction()
            plant = self.params.plant(device.plant)
        elif friction is None:
            friction = "paper"
        if isinstance(friction, str):
            friction = friction_from_name(friction, device.paper_friction, device.lugre_friction)
        if not isinstance(friction, FrictionModel):
            raise TypeError(f"friction must be a law's name or a FrictionModel, got {friction!r}")
        self.friction = friction
        self.model_friction = device.paper_friction if self.params is None else self.params.friction
        nominal = device.plant if plant is None else plant
        if not isinstance(nominal, PlantParams):
            raise TypeError(f"plant must be a PlantParams, got {nominal!r}")
        if delay is None:  # the device's dead time, in whole periods of this dt
            delay = round(nominal.dead_time / self.dt) * self.dt
        self.plant = replace(
            nominal,
            dead_time=_number("delay", delay, ">= 0"),
            end_stop=min(nominal.end_stop, device.end_stop),
        )
        self.delay_steps = self.plant.delay_steps(self.dt)
        self.reference = resolve_reference(reference, device.references)
        self.randomize = DomainRandomization.from_spec(randomize)
        if sensor_noise is True:
            noise = device.noise_std
        elif sensor_noise is False:
            noise = 0.0
        else:
            noise = _number("sensor_noise", sensor_noise, ">= 0")
        if not isinstance(quantize, bool | np.bool_):
            raise TypeError(f"quantize must be True or False, got {quantize!r}")
        if max_episode_steps is not None and (
            not isinstance(max_episode_steps, numbers.Integral) or max_episode_steps < 1
        ):
            raise ValueError(
                f"max_episode_steps must be a positive integer, got {max_episode_steps!r}"
            )
        self.limit = (
            device.limit if safety_limit is None else _number("safety_limit", safety_limit, ">= 0")
        )
        self.config = np.zeros(ek.CONFIG_SIZE)
        self.config[ek.C_SENSOR] = device.sensor
        self.config[ek.C_QUANTIZE] = float(quantize)
        self.config[ek.C_NOISE] = noise
        self.config[ek.C_ENCODER_STEP] = QUBE_ENCODER_STEP
        cutoff = device.velocity_cutoff
        pole = 0.0 if cutoff is None else math.exp(-cutoff * self.dt)
        self.config[ek.C_POLE] = pole
        quantum = QUBE_ENCODER_STEP if device.sensor == ek.SENSOR_ENCODER else ir_quantum()
        self.config[ek.C_VELOCITY_FLOOR] = velocity_floor(quantum, pole, self.dt)
        self.config[ek.C_ERROR_SCALE] = device.error_scale
        self.config[ek.C_EFFORT_WEIGHT] = (
            device.effort_weight
            if effort_weight is None
            else _number("effort_weight", effort_weight, ">= 0")
        )
        self.config[ek.C_PENALTY] = (
            device.limit_penalty
            if limit_penalty is None
            else _number("limit_penalty", limit_penalty, ">= 0")
        )
        self.config[ek.C_LIMIT] = self.limit
        self.config[ek.C_MAX_STEPS] = max_episode_steps or 0

        worst = self.plant  # the smallest inertia a reset can draw sets the substeps
        if self.randomize is not None and self.randomize.inertia is not None:
            worst = replace(self.plant, inertia=self.plant.inertia * self.randomize.inertia[0])
        self.substeps = default_substeps([worst], [friction], self.dt)
        self._nominal_row = plant_row(self.plant, friction)
        self._default_x0 = -device.start if device.sensor == ek.SENSOR_IR else device.start
        # A random reference is sampled per env at reset; the zero row only fills the argument.
        self._default_reference_row = (
            self.reference.sample() if not self.reference.random else np.zeros(ek.REF_SIZE)
        )
        n = self.num_envs
        self.plant_rows: FloatArray = self._nominal_row[None].copy()
        if self.randomize is not None:
            self.plant_rows = np.repeat(self.plant_rows, n, axis=0)
        self.rows: FloatArray = np.zeros((n, ek.TASK_ROW_SIZE))
        self.state: FloatArray = np.zeros((n, ek.ENV_STATE_SIZE))
        self.delay_buffer: FloatArray = np.zeros((n, self.delay_steps))
        self.noise_state: npt.NDArray[np.uint64] = np.zeros(n, dtype=np.uint64)
        self.head = 0
        self._kernel = select_kernel(ek.step_envs, ek.step_envs_parallel, n, parallel)
        self.parallel = self._kernel is not ek.step_envs  # threads may run

    def close(self) -> None:
        """Release what the simulation holds (nothing; a device session closes its link)."""

    def stop(self) -> None:
        """Zero a device's motor after an error (a simulation has none to stop)."""

    @property
    def observation_size(self) -> int:
        """Length of one env's observation."""
        return len(self.device.observation_names)

    def _start_state(self, options: Mapping[str, Any], count: int) -> tuple[FloatArray, FloatArray]:
        """Plant position and velocity at reset, from the options (in env units) or defaults."""
        if "position" not in options and "velocity" not in options:
            return np.full(count, self._default_x0), np.zeros(count)
        pos = np.broadcast_to(
            np.asarray(options.get("position", self.device.start), np.float64), count
        )
        vel = np.broadcast_to(np.asarray(options.get("velocity", 0.0), np.float64), count)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
            raise ValueError("reset options 'position' and 'velocity' must be finite numbers")
        if self.device.sensor == ek.SENSOR_IR:
            if np.any(pos <= self.limit):
                raise ValueError(
                    f"reset option 'position' is the distance to the wall in cm and must exceed "
                    f"the safety limit {self.limit} cm, got {options['position']!r}"
                )
            return -pos, -vel  # the plant moves toward the wall
        if np.any(np.abs(pos) > self.limit):
            raise ValueError(
                f"reset option 'position' must lie within the safety limit ±{self.limit} rad, "
                f"got {options['position']!r}"
            )
        return np.array(pos), np.array(vel)

    def prepare_reset(
        self,
        mask: BoolArray,
        rng_of: Callable[[int], np.random.Generator],
        options: Mapping[str, Any] | None = None,
    ) -> None:
        """Reset the envs of ``mask``; the next :meth:`run` with ``fresh=mask`` observes them.

        Each env draws, from its own generator and in this order: the randomised factors,
        the reference (if random) and the seed of its sensor noise (if noisy). Envs that draw
        nothing are reset in one compiled call (an autoreset costs a few µs).
        """
        reference = self.reference
        if options:
            unknown = set(options) - set(RESET_OPTIONS)
            if unknown:
                raise ValueError(
                    f"unknown reset options {sorted(unknown)}; use {list(RESET_OPTIONS)}"
                )
            if "reference" in options:
                reference = resolve_reference(options["reference"], self.device.references)
        else:
            options = {}
        x0, v0 = self._start_state(options, int(np.count_nonzero(mask)))
        noisy = self.config[ek.C_NOISE] > 0.0
        draws = self.randomize is not None or reference.random or noisy
        ref_row = self._default_reference_row  # set by reset_envs only when nothing is drawn
        if not draws and reference is not self.reference:
            ref_row = reference.sample()
        if draws:
            for j in np.flatnonzero(mask):
                rng = rng_of(int(j))
                gain = 1.0
                if self.randomize is not None:
                    factors = self.randomize.draw(rng)
                    self.plant_rows[j], gain = apply_factors(self._nominal_row, factors)
                self.rows[j, ek.T_GAIN] = gain
                self.rows[j, ek.T_REF :] = reference.sample(rng)
                if noisy:
                    self.noise_state[j] = rng.integers(2**64, dtype=np.uint64)
        ek.reset_envs(mask, self.state, self.delay_buffer, self.rows, x0, v0, ref_row, not draws)

    def run(
        self,
        command: npt.NDArray[np.floating[Any]],
        fresh: BoolArray,
        obs: npt.NDArray[np.float32],
        out: FloatArray,
        flags: BoolArray,
    ) -> None:
        """Step the envs not ``fresh`` under ``command``, observe all; write the outputs."""
        bad = self._kernel(
            self.state, self.delay_buffer, self.head, command, self.dt, self.substeps,
            self.plant_rows, self.rows, self.noise_state, self.config, fresh, obs, out, flags,
        )  # fmt: skip
        if bad >= 0:
            raise ValueError(
                f"action {command[bad]!r} (env {bad}) is not a finite number; actions must be "
                "finite commands in physical units"
            )
        if self.delay_steps:
            self.head = (self.head + 1) % self.delay_steps
