"""One env on a device: the simulated env's task around a hardware backend's samples.

:class:`DeviceSession` is an :class:`~frictiongym.envs.core.EnvCore` whose plant is the device:
its task (reference, sensor settings, reward, limits, resets) is a
:class:`~frictiongym.envs.core.Simulation` of one that is never stepped, and the observation
comes from the same compiled code (:func:`frictiongym.envs._kernel.observe_device`), so a
device whose readings equal the simulator's gives the same observations bit for bit. The device
knows no true state: ``info["position"]`` and ``info["velocity"]`` are the estimates.

Every run is logged as it goes (:mod:`frictiongym.hardware.runlog`), and the motor is zeroed
when an episode terminates, at the next ``reset()``, on close and on any error; an error that
ends a step (a watchdog trip, a timeout) is also written to the log's ``meta.json``. A time
limit (Gymnasium's ``TimeLimit`` wrapper) ends an episode outside the env, which cannot see it:
the motor then holds its last command until the next ``reset()`` or ``close()``, or until the
device's watchdog stops it (100 ms on the servo) if the host sends nothing more.

Each ``reset()`` keeps the objects alive at that moment out of the garbage collector's scans
until the env closes (:func:`frictiongym.hardware.realtime.freeze_heap`): a full collection of
a large process stalls a loop for longer than a watchdog allows.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym import devices
from frictiongym.envs import _kernel as env_kernel
from frictiongym.envs.core import BoolArray, FloatArray, Frame, Simulation
from frictiongym.hardware import resolve_backend
from frictiongym.hardware.base import Sample
from frictiongym.hardware.errors import HardwareError, ProtocolError
from frictiongym.hardware.protocol import Status
from frictiongym.hardware.realtime import freeze_heap, thaw_heap
from frictiongym.hardware.runlog import RunLog, Timing, default_directory

#: Simulator-only settings, refused with a device (what each would need to mean there).
SIM_ONLY = {
    "friction": "the device has its own friction; use params= for the compensators' model",
    "plant": "the device is the plant; use params= for the compensators' model",
    "randomize": "domain randomisation is for training in simulation",
    "sensor_noise": "the device's sensor has its own noise",
    "delay": "the device's dead time is what it is",
    "deadzone": "the device's actuator has the dead zone it has",
    "backlash": "the device's drivetrain has the play it has",
    "jitter": "the device's loop has the timing it has",
    "parallel": "a device is one env",
}


class DeviceSession:
    """The env core of one env on a device (see the module docstring).

    Parameters
    ----------
    device : Device
        The env's device description.
    backend : str or Backend
        The device (:func:`frictiongym.hardware.resolve_backend`); opened here.
    log : bool, str or PathLike, default True
        Log the run: True writes to a new directory under ``$FRICTIONGYM_RUNS`` (default
        ``./frictiongym-runs``), a path to that directory, False to nothing.
    run_metadata : mapping, optional
        Added to the log's ``meta.json`` (e.g. the controller and its gains).
    **kwargs
        The task's settings, as :class:`Simulation` takes them (``reference``, ``params``,
        ``effort_weight``, ``safety_limit``, ``limit_penalty``, ``dt`` if it is the
        device's period, ``quantize=True``).
    """

    num_envs = 1
    on_device = True

    def __init__(
        self,
        device: devices.Device,
        backend: object,
        *,
        log: bool | str | os.PathLike[str] = True,
        run_metadata: Mapping[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        refused = [k for k, v in kwargs.items() if k in SIM_ONLY and v not in (None, False)]
        if kwargs.get("friction") == "paper":
            refused.remove("friction")
        if refused:
            raise ValueError(
                "not with a device backend: " + "; ".join(f"{k} ({SIM_ONLY[k]})" for k in refused)
            )
        if kwargs.get("quantize", True) is not True:
            raise ValueError("quantize=False is not possible on a device: its sensor quantises")
        resolved = resolve_backend(backend, device.kind)
        if resolved is None:
            raise ValueError("DeviceSession needs a device backend, not the simulator")
        if device not in devices.DEVICES:  # a described device: its Hello names no kind
            resolved.described_kind = device.kind
        self.backend = resolved
        self.info = resolved.open()
        try:
            if self.info.kind != device.kind:
                raise ProtocolError(
                    f"the device at {self.info.link} is {devices.get(self.info.kind).title}, but "
                    f"this env drives {device.title}: pick the env of that device or the "
                    "other port"
                )
            if device not in devices.DEVICES:
                _check_described(device, self.info)
            dt = 1.0 / self.info.rate_hz
            given = kwargs.pop("dt", None)
            if given is not None and abs(given - dt) > 1e-9 * dt:
                raise ValueError(
                    f"dt={given!r} s, but the device ticks every {dt!r} s and its clock paces "
                    "the loop; omit dt (or change the firmware's rate)"
                )
            kwargs = {k: v for k, v in kwargs.items() if k not in SIM_ONLY}
            #: The task: reference, sensor settings, reward, limits and resets (its plant never
            #: runs).
            self.task = Simulation(device, 1, dt=dt, **kwargs)
            self.device, self.dt, self.plant = device, dt, self.task.plant
            self.params, self.model_friction = self.task.params, self.task.model_friction
            self.limit, self.tracking_cap = self.task.limit, self.task.tracking_cap
            self.horizon = self.task.horizon
            self.log: RunLog | None = None
            if log is not False:
                directory = default_directory(device.name) if log is True else Path(log)
                self.log = RunLog(directory, device.observation_names, self._metadata(run_metadata))
        except BaseException:
            self.backend.close()
            raise
        self._compile()
        self.last_sample: Sample | None = None
        self.last_sample_ns = 0
        self.episode = -1
        self._first: Sample | None = None
        self._periods: list[float] = []
        self._late = 0
        self._skipped = 0
        #: Errors that ended a step: episode, step and message (also in the log's meta.json).
        self.faults: list[dict[str, Any]] = []

    def _compile(self) -> None:
        """Compile the observation code now: a first step must not stall while the motor runs."""
        state, flags = self.task.state.copy(), np.zeros((env_kernel.FLAG_SIZE, 1), dtype=bool)
        obs = np.zeros((1, self.observation_size), dtype=np.float32)
        out, fresh = np.zeros((env_kernel.OUT_SIZE, 1)), np.ones(1, dtype=bool)
        task = (self.task.rows, self.task.config, 0.0, 0.0, 1.0, self.dt, fresh, obs, out, flags)
        env_kernel.observe_device(state, *task)

    @property
    def observation_size(self) -> int:
        """Length of the observation."""
        return self.task.observation_size

    def frame(self, i: int) -> Frame:
        """Return what a frame draws: the measured position (the device knows no other)."""
        frame = self.task.frame(i)
        estimate = float(env_kernel.task_state(self.task.state, "estimate")[i])
        return frame._replace(position=self.device.direction * estimate)

    def _metadata(self, extra: Mapping[str, Any] | None) -> dict[str, Any]:
        return {
            "device": self.device.name,
            "backend": self.info,
            "dt": self.dt,
            "reference": repr(self.task.reference),
            "params": None if self.params is None else self.params.to_dict(),
            "model_friction": self.model_friction,
            "safety_limit": self.limit,
            **(extra or {}),
        }

    def prepare_reset(
        self,
        mask: BoolArray,
        rng_of: Callable[[int], np.random.Generator],
        options: Mapping[str, Any] | None = None,
    ) -> None:
        """Stop the motor, put the device at its start if it can be placed, and arm it."""
        self.backend.stop()  # first: a refused option must not leave the motor running
        options = dict(options or {})
        position = options.pop("position", None)
        if options.pop("velocity", 0.0) != 0.0:
            raise ValueError("a device starts at rest: reset option 'velocity' must be 0")
        if self.info.can_place:
            start = self.device.start if position is None else position
            self.task.start_state({"position": start}, 1)  # the simulator's checks of the option
            self.backend.place(float(start))
        elif position is not None:
            raise ValueError(
                "this device cannot be moved to a position; omit reset option 'position' (the "
                "servo's encoder is zeroed where the disk is; put the Altino at its start by hand)"
            )
        self.task.prepare_reset(mask, rng_of, options)
        freeze_heap(self)
        self._first = self.backend.start(zero_position=True)
        self.episode += 1

    def run(
        self,
        command: npt.NDArray[np.floating[Any]],
        fresh: BoolArray,
        obs: npt.NDArray[np.float32],
        out: FloatArray,
        flags: BoolArray,
    ) -> int:
        """Hold ``command[0]`` on the device for one period (or observe its first sample).

        Any exception, wherever it comes from (the device, the observation, a log write that
        fails on a full disk, a ``KeyboardInterrupt``), zeroes the motor before it propagates.
        Returns 1 if the episode ended, else 0 (as :meth:`Simulation.run` counts).
        """
        try:
            requested = float(command[0])
            if fresh[0]:
                if self._first is None:
                    raise HardwareError("reset() the env before stepping it")
                sample = self._first
                self._first = None
            else:
                sample = self.backend.step(requested)
            task, umax = self.task, self.plant.command_limit
            reading = (sample.measured, sample.applied, umax, self.dt, fresh, obs, out, flags)
            env_kernel.observe_device(task.state, task.rows, task.config, *reading)
            if sample.status & Status.LIMIT and not fresh[0]:  # the device stopped itself
                if not flags[env_kernel.F_TERMINATED, 0]:
                    out[env_kernel.O_REWARD, 0] -= env_kernel.setting(task.config, "penalty")
                flags[env_kernel.F_TERMINATED, 0] = flags[env_kernel.F_DONE, 0] = True
            self.last_sample = sample
            self._account(sample, not fresh[0], 0.0 if fresh[0] else requested, obs, out, flags)
        except BaseException as exc:
            self.stop()
            if isinstance(exc, HardwareError | OSError):
                self._record_fault(exc)
            raise
        if flags[env_kernel.F_TERMINATED, 0]:
            self.backend.stop()
        return int(flags[env_kernel.F_DONE, 0])

    def stop(self) -> None:
        """Zero the motor after an error, unless a stop already did (the backend's own)."""
        if self.backend.armed:
            self.backend.stop()

    def _account(
        self,
        sample: Sample,
        requested_step: bool,
        requested: float,
        obs: npt.NDArray[np.float32],
        out: FloatArray,
        flags: BoolArray,
    ) -> None:
        previous = self.last_sample_ns
        self.last_sample_ns = sample.host_ns
        if requested_step:
            self._periods.append((sample.host_ns - previous) * 1e-9)
            self._late += sample.late
            self._skipped += sample.skipped
        if self.log is None:
            return
        self.log.record(
            (
                self.episode,
                self._steps(),
                out[env_kernel.O_TIME, 0],
                sample.host_ns,
                sample.tick_us,
                sample.seq,
                sample.seq_applied,
                int(sample.late),
                sample.skipped,
                sample.status,
                requested,
                sample.applied,
                sample.measured,
                *obs[0].tolist(),
                out[env_kernel.O_REWARD, 0],
                int(flags[env_kernel.F_TERMINATED, 0]),
            )
        )

    def _steps(self) -> int:
        return int(env_kernel.task_state(self.task.state, "steps")[0])

    def _record_fault(self, error: BaseException) -> None:
        fault = {
            "episode": self.episode,
            "step": self._steps() + 1,
            "error": type(error).__name__,
            "message": str(error),
        }
        self.faults.append(fault)
        if self.log is not None:
            try:
                self.log.update(faults=self.faults)
            except OSError:  # the disk that failed the step's row fails this too: keep the first
                pass

    @property
    def periods(self) -> list[float]:
        """Host time between consecutive steps of an episode, s, every step so far."""
        return list(self._periods)

    def timing(self) -> Timing:
        """Return the timing statistics of every step so far (all episodes)."""
        return Timing.from_periods(self._periods, self.dt, self._late, self._skipped)

    def close(self) -> None:
        """Zero the motor, close the link and finish the log (idempotent)."""
        self.backend.close()
        thaw_heap(self)
        if self.log is not None and not self.log.closed:
            self.log.close(timing=self.timing() if self._periods else None)


def _check_described(device: devices.Device, info: Any) -> None:
    """Refuse a device whose Hello disagrees with the description its env was made from.

    The wire names no described device (``DeviceKind.AXIS``); its encoder counts, command
    limit and rate tell two descriptions apart.
    """
    told = {
        "counts_per_rev": (info.counts_per_rev, device.counts_per_rev),
        "command limit": (info.command_limit, device.plant.command_limit),
        "rate (Hz)": (info.rate_hz, round(1.0 / device.dt)),  # whole Hz on the wire
    }
    differ = [
        f"{name} {theirs:g} (the file: {ours:g})"
        for name, (theirs, ours) in told.items()
        if abs(theirs - ours) > 1e-6 * max(abs(ours), 1e-12)
    ]
    if differ:
        raise ProtocolError(
            f"the device at {info.link} is not the one {device.source or device.name} "
            f"describes: {', '.join(differ)}; give the env the device's own file"
        )


__all__ = ["SIM_ONLY", "DeviceSession"]
