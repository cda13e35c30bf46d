"""The batched simulation behind both env classes: N envs of one device on the env kernel.

:class:`Simulation` holds the state and parameters of N envs of a
:class:`~frictiongym.devices.Device`, prepares resets from each env's own generator and steps
them all with one call of the env kernel. The single env is a ``Simulation`` of one; the
vector env one of N: same code, same draws, same trajectories.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple, Protocol

import numpy as np
import numpy.typing as npt

from frictiongym._validation import real_number
from frictiongym.devices import Device
from frictiongym.envs import _kernel as env_kernel
from frictiongym.envs.references import Reference, resolve_reference
from frictiongym.friction import FrictionModel
from frictiongym.params import DeviceParams, device_physics
from frictiongym.plants._batch import first_non_finite
from frictiongym.plants.plant import Plant, PlantParams, default_substeps
from frictiongym.plants.randomization import DomainRandomization, apply_factors
from frictiongym.plants.sensors import ir_quantum, noise_std, velocity_floor

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: Keys accepted in ``reset(options=...)``.
RESET_OPTIONS = ("position", "velocity", "reference")


class Frame(NamedTuple):
    """What a frame of env ``i`` draws: its position (plant coordinates) and task."""

    position: float
    reference: float
    stuck: bool
    steps: float  #: steps of the episode so far
    command: float


class EnvCore(Protocol):
    """What the env classes drive: a :class:`Simulation` of N envs, or a device session of one.

    ``run`` after ``prepare_reset`` observes the envs of its mask; then each ``run`` steps them
    (:class:`~frictiongym.envs.device.DeviceSession` on a device).
    """

    device: Device
    num_envs: int
    dt: float
    plant: PlantParams
    params: DeviceParams | None
    model_friction: FrictionModel
    limit: float
    #: Largest tracking term of a step's reward, in reward units (inf: none, the v0 reward)
    tracking_cap: float
    horizon: int  #: episodes the v1 reward's terminal cost covers, steps (0: v0's reward)
    #: Whether a device runs the env (then it is nondeterministic).
    on_device: bool

    @property
    def observation_size(self) -> int:
        """Length of one env's observation."""

    def prepare_reset(
        self,
        mask: BoolArray,
        rng_of: Callable[[int], np.random.Generator],
        options: Mapping[str, Any] | None = None,
    ) -> None:
        """Reset the envs of ``mask``; the next :meth:`run` with ``fresh=mask`` observes them."""

    def run(
        self,
        command: npt.NDArray[np.floating[Any]],
        fresh: BoolArray,
        obs: npt.NDArray[np.float32],
        out: FloatArray,
        flags: BoolArray,
    ) -> int:
        """Step the envs not ``fresh`` under ``command``, observe all; write the outputs.

        Returns how many envs ended their episode (terminated or truncated).
        """

    def frame(self, i: int) -> Frame:
        """Return what a frame of env ``i`` draws."""

    def stop(self) -> None:
        """Zero a device's motor after an error."""

    def close(self) -> None:
        """Release what the core holds (a device's link)."""


def _bad_action(command: npt.NDArray[np.floating[Any]], bad: int) -> str:
    """Say what is wrong with the non-finite action ``bad``, and what to send instead."""
    return (
        f"action {command[bad]!r} (env {bad}) is not a finite number; actions must be finite "
        "commands in physical units"
    )


class Simulation:
    """N simulated envs of one device: the task (sensor, reference, reward, resets) on a plant.

    The plant is a :class:`~frictiongym.plants.Plant` of N (:attr:`plants`) whose kernel is the
    env kernel: it steps the plant, reads the sensor and scores the step in one compiled loop.

    Parameters
    ----------
    device : Device
        What to simulate.
    num_envs : int
        Batch size.
    **settings
        The env's arguments, as the env classes document them (``friction``, ``dt``,
        ``reference``, ``sensor_noise``, ``quantize``, ``delay``, ``deadzone``, ``backlash``,
        ``jitter``, ``randomize``,
        ``plant``, ``params``, ``effort_weight``, ``safety_limit``, ``limit_penalty``; see
        :class:`~frictiongym.envs.RotaryServoEnv`), and the vector env's ``max_episode_steps``
        (None: the single env's ``TimeLimit`` ends episodes) and ``parallel``.
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
    reference: Reference
    randomize: DomainRandomization | None
    limit: float
    config: FloatArray
    tracking_cap: float = math.inf
    horizon: int = 0  #: the v1 reward's episode length (0: v0's reward)
    #: The N plants, stepped by the env kernel (their state has the env's columns after theirs).
    plants: Plant
    on_device = False
    _nominal_row: FloatArray
    _default_start: tuple[FloatArray, FloatArray]
    _start: FloatArray
    _default_reference_row: FloatArray
    _rows_default: bool

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
        deadzone: float | None = None,
        backlash: float | None = None,
        jitter: float | None = None,
        randomize: Mapping[str, Any] | DomainRandomization | None = None,
        plant: PlantParams | None = None,
        params: str | os.PathLike[str] | DeviceParams | None = None,
        effort_weight: float | None = None,
        safety_limit: float | None = None,
        limit_penalty: float | None = None,
        terminal_cost: bool = True,
        horizon: int | None = None,
        max_episode_steps: int | None = None,
        parallel: bool | None = None,
    ) -> None:
        if not isinstance(num_envs, numbers.Integral) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.device = device
        self.num_envs = int(num_envs)
        self.dt = device.dt if dt is None else real_number("dt", dt, "> 0")
        physics = device_physics(
            device, self.dt, friction, plant, params, delay, deadzone, backlash, jitter
        )
        self.params, self.friction, self.model_friction, self.plant = physics
        self.reference = resolve_reference(reference, device.references)
        self.randomize = DomainRandomization.from_spec(randomize)
        if self.randomize is not None:
            self.randomize.check(self.plant)
        self.limit = (
            device.limit
            if safety_limit is None
            else real_number("safety_limit", safety_limit, ">= 0")
        )
        self.config = self._task_config(
            sensor_noise, quantize, effort_weight, limit_penalty, max_episode_steps
        )
        if horizon is None:  # the episode's length, where the env knows it (the vector env)
            horizon = max_episode_steps or device.episode_steps
        self._bound_reward(terminal_cost, horizon)
        #: Whether a reset draws from the envs' generators (randomised factors, a random
        #: reference, the seed of the sensor noise): a refused step must not have drawn.
        self.resets_draw: bool = (
            self.randomize is not None
            or self.reference.random
            or env_kernel.setting(self.config, "noise") > 0.0
            or self.plant.jitter > 0.0
        )
        self.plants = self._new_plants(parallel)
        self._default_start = (np.array([device.direction * device.start]), np.zeros(1))
        #: The same start as one array (position, velocity), for the kernel's autoresets.
        self._start = np.concatenate(self._default_start)
        # A random reference is sampled per env at reset; the zero row only fills the argument.
        self._default_reference_row = (
            self.reference.sample() if not self.reference.random else np.zeros(env_kernel.REF_SIZE)
        )
        self.rows: FloatArray = np.zeros((env_kernel.TASK_ROW_SIZE, self.num_envs))
        #: Whether every env's task rows hold what a reset that draws nothing sets (unit gain,
        #: the default reference, the plant's command limit): then an autoreset leaves them.
        self._rows_default = False
        self.noise_state: npt.NDArray[np.uint64] = np.zeros(self.num_envs, dtype=np.uint64)

    def _task_config(
        self,
        sensor_noise: bool | float,
        quantize: bool,
        effort_weight: float | None,
        limit_penalty: float | None,
        max_episode_steps: int | None,
    ) -> FloatArray:
        """Return the env kernel's settings: sensor, velocity filter, reward and episode end."""
        device = self.device
        if not isinstance(quantize, bool | np.bool_):
            raise TypeError(f"quantize must be True or False, got {quantize!r}")
        if max_episode_steps is not None and (
            not isinstance(max_episode_steps, numbers.Integral) or max_episode_steps < 1
        ):
            raise ValueError(
                f"max_episode_steps must be a positive integer, got {max_episode_steps!r}"
            )
        cutoff = device.velocity_cutoff
        pole = 0.0 if cutoff is None else math.exp(-cutoff * self.dt)
        return env_kernel.pack_config(
            sensor=device.sensor,
            quantize=float(quantize),
            noise=noise_std(sensor_noise, device.noise_std),
            encoder_step=device.encoder_step,
            pole=pole,
            velocity_floor=velocity_floor(device.encoder_step or ir_quantum(), pole, self.dt),
            error_scale=device.error_scale,
            effort_weight=device.effort_weight
            if effort_weight is None
            else real_number("effort_weight", effort_weight, ">= 0"),
            penalty=device.limit_penalty
            if limit_penalty is None
            else real_number("limit_penalty", limit_penalty, ">= 0"),
            limit=self.limit,
            max_steps=max_episode_steps or 0,
        )

    def _bound_reward(self, terminal_cost: bool, horizon: int) -> None:
        """Set the v1 reward's cap and terminal cost (the env classes' "Rewards")."""
        if not isinstance(terminal_cost, bool | np.bool_):
            raise TypeError(f"terminal_cost must be True or False, got {terminal_cost!r}")
        if not isinstance(horizon, numbers.Integral) or horizon < 1:
            raise ValueError(f"horizon must be a positive number of steps, got {horizon!r}")
        if terminal_cost:
            self.tracking_cap = self.device.error_cap / self.device.error_scale
            self.horizon = int(horizon)
            self.config[env_kernel.CONFIG["error_cap"]] = self.tracking_cap
            self.config[env_kernel.CONFIG["horizon"]] = horizon

    def _new_plants(self, parallel: bool | None) -> Plant:
        """Build the N plants on the env kernel; randomised envs get a parameter row each."""
        worst = self.plant if self.randomize is None else self.randomize.lightest(self.plant)
        plants = Plant(
            self.plant,
            self.friction,
            self.dt,
            self.num_envs,
            substeps=default_substeps([worst], [self.friction], self.dt),
            parallel=parallel,
            task_columns=env_kernel.TASK_COLUMNS,
            kernels=(env_kernel.step_envs, env_kernel.step_envs_parallel),
        )
        self._nominal_row = plants.rows[0].copy()
        if self.randomize is not None:
            plants.own_rows()
        return plants

    @property
    def state(self) -> FloatArray:
        """The envs' state: the plant's columns, then the env kernel's own."""
        return self.plants.state

    def close(self) -> None:
        """Release what the simulation holds (nothing)."""

    def stop(self) -> None:
        """Zero a device's motor after an error (a simulation has none to stop)."""

    @property
    def observation_size(self) -> int:
        """Length of one env's observation."""
        return len(self.device.observation_names)

    def frame(self, i: int) -> Frame:
        """Return what a frame of env ``i`` draws: its true position and the task's state."""
        plants = self.plants
        return Frame(
            float(plants.position[i]),
            float(env_kernel.task_state(self.state, "reference")[i]),
            bool(plants.stuck[i]),
            float(env_kernel.task_state(self.state, "steps")[i]),
            float(plants.command[i]),
        )

    def start_state(self, options: Mapping[str, Any], count: int) -> tuple[FloatArray, FloatArray]:
        """Plant position and velocity at reset, from the options (in env units) or defaults.

        Arrays of ``count`` entries, or of one for all (the defaults, kept: an autoreset of a
        few envs per step needs no new arrays).
        """
        if "position" not in options and "velocity" not in options:
            return self._default_start
        pos = np.broadcast_to(
            np.asarray(options.get("position", self.device.start), np.float64), count
        )
        vel = np.broadcast_to(np.asarray(options.get("velocity", 0.0), np.float64), count)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
            raise ValueError("reset options 'position' and 'velocity' must be finite numbers")
        device, unit = self.device, self.device.position_unit
        if device.sensor == env_kernel.SENSOR_IR:
            if np.any(pos <= self.limit):
                raise ValueError(
                    f"reset option 'position' is the distance to the wall in {unit} and must "
                    f"exceed the safety limit {self.limit} {unit}, got {options['position']!r}"
                )
        elif np.any(np.abs(pos) > self.limit):
            raise ValueError(
                f"reset option 'position' must lie within the safety limit ±{self.limit} {unit}, "
                f"got {options['position']!r}"
            )
        return device.direction * pos, device.direction * vel  # plant coordinates

    def prepare_reset(
        self,
        mask: BoolArray,
        rng_of: Callable[[int], np.random.Generator],
        options: Mapping[str, Any] | None = None,
    ) -> None:
        """Reset the envs of ``mask``; the next :meth:`run` with ``fresh=mask`` observes them.

        Each env draws, from its own generator and in this order: the randomised factors,
        the reference (if random), the seed of its sensor noise (if noisy) and the seed of its
        drive's jitter (if any). Envs that draw nothing are reset in one compiled call (an
        autoreset costs a few µs).
        """
        plants = self.plants
        if not options and self._rows_default:  # an autoreset: the rows hold what it would set
            env_kernel.reset_envs(mask, *self._reset_args(), False)
            return
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
        x0, v0 = self.start_state(options, int(np.count_nonzero(mask)) if options else 1)
        noisy = env_kernel.setting(self.config, "noise") > 0.0
        draws = self.resets_draw or reference.random  # an option's reference may be random
        ref_row = self._default_reference_row  # set by reset_envs only when nothing is drawn
        if not draws and reference is not self.reference:
            ref_row = reference.sample()
        jittery, jitter_seeds = self.plant.jitter > 0.0, []
        if draws:
            for j in np.flatnonzero(mask):
                rng = rng_of(int(j))
                gain = 1.0
                if self.randomize is not None:
                    factors = self.randomize.draw(rng)
                    self.plants.rows[j], gain = apply_factors(self._nominal_row, factors)
                env_kernel.set_episode(self.rows, int(j), gain, reference.sample(rng))
                if noisy:
                    self.noise_state[j] = rng.integers(2**64, dtype=np.uint64)
                if jittery:
                    jitter_seeds.append(rng.integers(2**52))
            if self.randomize is not None:
                self.plants.prime_rows(mask)
        # Every env's task rows are the default ones after a reset of all to the default; any
        # other reset may leave some that are not (nothing drawn: at most this reset's envs).
        self._rows_default = (
            not draws and reference is self.reference and (self._rows_default or bool(mask.all()))
        )
        env_kernel.reset_envs(mask, *self._reset_args((x0, v0), ref_row), not draws)
        if jittery:  # after the reset, which zeroes the plant's state
            plants.seed_jitter(np.array(jitter_seeds, dtype=np.float64), mask)

    def _reset_args(
        self,
        start: tuple[FloatArray, FloatArray] | None = None,
        reference: FloatArray | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """Return what :func:`~frictiongym.envs._kernel.reset_envs` takes after the mask.

        The arrays it writes, then the start (positions, velocities) and the reference row:
        the default ones unless given.
        """
        x0, v0 = self._default_start if start is None else start
        row = self._default_reference_row if reference is None else reference
        plants = self.plants
        return (plants.state, plants.delay_buffer, plants.rows, self.rows, x0, v0, row)

    def run(
        self,
        command: npt.NDArray[np.floating[Any]],
        fresh: BoolArray,
        obs: npt.NDArray[np.float32],
        out: FloatArray,
        flags: BoolArray,
        autoreset: Callable[[int], np.random.Generator] | None = None,
    ) -> int:
        """Step the envs not ``fresh`` under ``command``, observe all; write the outputs.

        With ``autoreset`` (each env's generator, as :meth:`prepare_reset` takes them) the
        fresh envs are reset first: a vector env's autoreset. A non-finite command raises the
        ValueError before anything changes (no env reset, no draw). A reset that draws nothing
        is done by the kernel, in the block that steps the env (it runs on most steps of an env
        whose episodes end every few hundred steps).

        Returns how many envs ended their episode (their ``F_DONE`` flags).
        """
        in_kernel = autoreset is not None and self._rows_default  # the rows hold what it sets
        if autoreset is not None and not in_kernel:
            self.check_commands(command)
            self.prepare_reset(fresh, autoreset)
        bad = self.plants.run(
            command,
            self.rows,
            self.noise_state,
            self.config,
            fresh,
            in_kernel,
            self._start,
            obs,
            out,
            flags,
        )
        if bad >= 0:
            raise ValueError(_bad_action(command, bad))
        return -1 - bad

    def bind(
        self,
        command: npt.NDArray[np.floating[Any]],
        fresh: BoolArray,
        obs: npt.NDArray[np.float32],
        out: FloatArray,
        flags: BoolArray,
    ) -> Callable[[], int]:
        """Return :meth:`run` on these very arrays, bound once (:meth:`Plant.bind`): faster.

        The caller updates ``command`` and ``fresh`` in place between calls.
        """

        def refuse(bad: int) -> None:
            raise ValueError(_bad_action(command, bad))

        task = (self.rows, self.noise_state, self.config, fresh, False, self._start)
        return self.plants.bind(command, *task, obs, out, flags, refuse=refuse)

    def check_commands(self, command: npt.NDArray[np.floating[Any]]) -> None:
        """Raise the ValueError :meth:`run` would raise for a non-finite command, now."""
        bad = first_non_finite(command)  # the kernel's own check: no temporaries, SIMD lanes
        if bad >= 0:
            raise ValueError(_bad_action(command, bad))

    def observations(self) -> npt.NDArray[np.float32]:
        """Return every env's last observation again, rebuilt from what its state keeps."""
        obs = np.empty((self.num_envs, self.observation_size), np.float32)
        env_kernel.publish_envs(self.plants.state, self.config, obs)
        return obs

    def observe(
        self, mask: BoolArray, obs: npt.NDArray[np.float32], out: FloatArray, flags: BoolArray
    ) -> None:
        """Observe the envs of ``mask`` just reset by :meth:`prepare_reset`; step none."""
        plants = self.plants
        env_kernel.observe_envs(
            mask,
            plants.state,
            self.rows,
            self.noise_state,
            self.config,
            plants.dt,
            obs,
            out,
            flags,
        )
