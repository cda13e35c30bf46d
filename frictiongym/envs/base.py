"""The single env class shared by the devices, and what the native vector env shares with it.

Both env classes drive an :class:`~frictiongym.envs.core.EnvCore`: a
:class:`~frictiongym.envs.core.Simulation` of 1 or of N envs, or a single env's
:class:`~frictiongym.envs.device.DeviceSession`. They differ only in how they seed, return and
reset: the single env draws from ``self.np_random``, env ``i`` of the vector env
(:mod:`frictiongym.envs.vector`) from a generator seeded ``seed + i`` (as ``SyncVectorEnv``
seeds its copies), so ``vector_env.reset(seed=s)`` and ``single_env.reset(seed=s + i)`` give
identical trajectories for the same actions.
"""

from __future__ import annotations

import difflib
import functools
import inspect
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.envs.registration import EnvSpec

from frictiongym.envs import _kernel as env_kernel
from frictiongym.envs import rendering
from frictiongym.envs.core import Device, EnvCore, Simulation
from frictiongym.envs.device import DeviceSession
from frictiongym.hardware import SIM
from frictiongym.plants.sensors import IR_MAX_READOUT, ir_estimate

ObsArray = npt.NDArray[np.float32]
ActArray = npt.NDArray[np.float32]

INFO_KEYS = ("position", "velocity", "command", "reference", "time")
_OUT_ROWS = (
    env_kernel.O_POSITION,
    env_kernel.O_VELOCITY,
    env_kernel.O_COMMAND,
    env_kernel.O_REFERENCE,
    env_kernel.O_TIME,
)
_O_POSITION, _O_VELOCITY, _O_COMMAND, _O_REFERENCE, _O_TIME = _OUT_ROWS
_F_STUCK = env_kernel.F_STUCK
if INFO_KEYS != ("position", "velocity", "command", "reference", "time"):  # _info spells them out
    raise ImportError(
        "FrictionEnv._info and FrictionVectorEnv._info must list every key of INFO_KEYS"
    )
_RENDER_FPS = 50


#: The task's settings, as the simulation takes them (after ``device`` and ``num_envs``).
_TASK_ARGUMENTS = tuple(inspect.signature(Simulation).parameters)[2:]
_VECTOR_ONLY = ("max_episode_steps", "parallel")  #: the single env's TimeLimit, one env
#: Settings of device runs only (``backend=`` other than ``"sim"``).
_DEVICE_ARGUMENTS = ("log", "run_metadata")
_SINGLE_ARGUMENTS = (
    "render_mode",
    "backend",
    *(name for name in _TASK_ARGUMENTS if name not in _VECTOR_ONLY),
    *_DEVICE_ARGUMENTS,
)
_VECTOR_ARGUMENTS = ("num_envs", "render_mode", "autoreset_mode", *_TASK_ARGUMENTS)


def _check_arguments(env: object, given: Any, valid: tuple[str, ...]) -> None:
    """Raise a TypeError naming the env, any unknown keyword and the valid ones."""
    unknown = sorted(set(given) - set(valid))
    if not unknown:
        return
    hints = []
    for name in unknown:
        close = [v for v in valid if name in v] or difflib.get_close_matches(name, valid, n=1)
        hints.append(f"{name!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    raise TypeError(
        f"{type(env).__name__} got unknown argument{'s' if len(unknown) > 1 else ''} "
        f"{', '.join(hints)}; its arguments are {', '.join(sorted(valid))} "
        f"(help(frictiongym.envs.{type(env).__name__}) explains each)"
    )


def _spaces(device: Device, sim: EnvCore) -> tuple[spaces.Space[Any], spaces.Space[Any]]:
    limit = sim.plant.command_limit
    action = spaces.Box(-limit, limit, shape=(1,), dtype=np.float32)
    low = np.full(sim.observation_size, -np.inf, dtype=np.float32)
    high = np.full(sim.observation_size, np.inf, dtype=np.float32)
    if device.sensor == env_kernel.SENSOR_IR:  # readout 0..800 and the distance it can stand for
        low[0], high[0] = 0.0, IR_MAX_READOUT
        low[1], high[1] = ir_estimate(IR_MAX_READOUT), ir_estimate(0.0)
    return action, spaces.Box(low, high, dtype=np.float32)


class FrictionEnv(gym.Env[ObsArray, ActArray]):
    """Base class of the single envs; see :class:`~frictiongym.envs.RotaryServoEnv`."""

    device: Device  #: a class attribute of the built-in envs, set per env by the Axis envs
    metadata = {  # noqa: RUF012  (gymnasium declares it an instance attribute)
        "render_modes": ["human", "rgb_array"],
        "render_fps": _RENDER_FPS,
    }

    def __init__(
        self, *, render_mode: str | None = None, backend: object = "sim", **kwargs: Any
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        _check_arguments(self, kwargs, _SINGLE_ARGUMENTS)
        self.render_mode = render_mode
        self._spec: EnvSpec | None = None
        self.sim: EnvCore
        if backend is None or backend in SIM:
            device_only = sorted(set(_DEVICE_ARGUMENTS) & set(kwargs))
            if device_only:
                raise ValueError(
                    f"{' and '.join(device_only)}: settings of device runs; they apply with a "
                    "device backend (backend='serial://...' or 'emulator://...'), not with the "
                    "simulator"
                )
            self.sim = Simulation(self.device, 1, **kwargs)
        else:
            self.sim = DeviceSession(self.device, backend, **kwargs)
        #: Whether a device backend runs the env (then it is nondeterministic).
        self.on_device = self.sim.on_device
        self.dt = self.sim.dt
        #: Largest tracking term of a step's reward (inf: no cap; v1's cap: "Rewards"), and the
        #: episode length its terminal cost covers (0: v0's reward)
        self.tracking_cap, self.horizon = self.sim.tracking_cap, self.sim.horizon
        self.action_space, self.observation_space = _spaces(self.device, self.sim)
        self._command = np.zeros(1)
        self._fresh = np.zeros(1, dtype=bool)
        self._obs = np.zeros((1, self.sim.observation_size), dtype=np.float32)
        self._out = np.zeros((env_kernel.OUT_SIZE, 1))
        self._flags = np.zeros((env_kernel.FLAG_SIZE, 1), dtype=bool)
        self._bind()
        self._window: Any = None
        self._render_every = max(1, round(1.0 / (_RENDER_FPS * self.dt)))
        self._needs_reset = True

    @property
    def spec(self) -> EnvSpec | None:
        """The env's spec; on a device, marked nondeterministic whatever the id registered."""
        return self._spec

    @spec.setter
    def spec(self, value: EnvSpec | None) -> None:
        if value is not None and getattr(self, "on_device", False) and not value.nondeterministic:
            value = replace(value, nondeterministic=True)
        self._spec = value

    def _info(self) -> dict[str, Any]:
        # written out (keys in INFO_KEYS order, then "stuck"): twice as fast as a loop over
        # INFO_KEYS, and the info is built at every step
        out = self._out_values.tolist()
        return {
            "position": out[_O_POSITION],
            "velocity": out[_O_VELOCITY],
            "command": out[_O_COMMAND],
            "reference": out[_O_REFERENCE],
            "time": out[_O_TIME],
            "stuck": self._flags_values.item(_F_STUCK),
        }

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsArray, dict[str, Any]]:
        """Start an episode at rest (or as ``options`` say); see the class docstring."""
        super().reset(seed=seed)
        self._fresh[0] = True
        self._command[0] = 0.0  # not a refused action's NaN: a reset sends no command
        self.sim.prepare_reset(self._fresh, lambda _: self.np_random, options)
        self.sim.run(self._command, self._fresh, self._obs, self._out, self._flags)
        self._fresh[0] = False
        self._needs_reset = False
        if self.render_mode == "human":
            self.render()
        return self._obs[0].copy(), self._info()

    def step(self, action: ActArray) -> tuple[ObsArray, float, bool, bool, dict[str, Any]]:
        """Hold ``action`` (saturated at the command limit) over one control period."""
        if self._needs_reset:
            raise gym.error.ResetNeeded("Cannot call env.step() before calling env.reset()")
        try:  # any error here stops a device's motor (a refused action, a failed draw)
            if type(action) is np.ndarray and action.shape == (1,) and action.dtype.kind == "f":
                self._command[0] = action[0]  # the common case, without a conversion
            else:
                self._command[0] = _one_number(action)
            self._run()
            if self.render_mode == "human" and self.sim.frame(0).steps % self._render_every == 0:
                self.render()
        except BaseException:
            self.sim.stop()
            raise
        return (
            self._obs[0].copy(),
            self._out_values.item(env_kernel.O_REWARD),
            self._flags_values.item(env_kernel.F_TERMINATED),
            False,
            self._info(),
        )

    def render(self) -> npt.NDArray[np.uint8] | None:
        """Draw the current state: an RGB array (``rgb_array``) or a window (``human``)."""
        if self.render_mode is None:
            gym.logger.warn(
                "render() called without a render mode; pass render_mode='rgb_array' or 'human' "
                f"to gym.make (e.g. gym.make({self.spec.id if self.spec else '...'!r}, "
                "render_mode='rgb_array'))"
            )
            return None
        if self._needs_reset:  # no state to draw yet (as gymnasium's order check says)
            raise gym.error.ResetNeeded("Cannot call env.render() before calling env.reset()")
        if self._window is not None and not self._window.shown:
            return None  # no display (the window warned once): skip drawing unseen frames
        frame = _frame(self.sim, 0)
        if self.render_mode == "rgb_array":
            return frame
        if self._window is None:
            self._window = rendering.Window(f"frictiongym {self.device.name}", _RENDER_FPS)
        self._window.show(frame)
        return None

    def close(self) -> None:
        """Close the window, if one is open, and a device's link (its motor zeroed first)."""
        if self._window is not None:
            self._window.close()
            self._window = None
        self.sim.close()

    def _bind(self) -> None:
        self._out_values, self._flags_values = self._out.ravel(), self._flags.ravel()  # views
        outputs = (self._command, self._fresh, self._obs, self._out, self._flags)
        #: One step on the arrays above: the simulation's bound run, or the device's.
        self._run: Callable[[], object] = (
            self.sim.bind(*outputs)
            if isinstance(self.sim, Simulation)
            else functools.partial(self.sim.run, *outputs)
        )

    def __getstate__(self) -> dict[str, Any]:
        """Pickle without the window (it is reopened on the next render) or the bound step."""
        state = self.__dict__.copy()
        state["_window"] = None
        for bound in ("_run", "_out_values", "_flags_values"):
            del state[bound]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickle, then bind the step to the unpickled arrays."""
        self.__dict__.update(state)
        self._bind()


def _refuse_masked(action: object) -> None:
    """Raise a ValueError for a masked array: its masked values would be sent as they are."""
    if isinstance(action, np.ma.MaskedArray):
        raise ValueError(
            f"actions must be plain numbers or arrays, got a masked array {action!r}; fill it "
            "first (e.g. .filled(0.0)) so that no hidden value reaches the motor"
        )


def _one_number(action: object) -> float:
    """Return the single env's action as a float, or raise a ValueError saying what is wrong."""
    _refuse_masked(action)
    array = np.asarray(action) if not isinstance(action, str | bytes) else None
    if array is None or array.dtype.kind not in "fiu":
        kind = type(action).__name__ if array is None or array.ndim == 0 else array.dtype
        raise ValueError(
            f"action must be one number (shape (1,)) in command units, got {action!r} ({kind}); "
            "e.g. env.step(np.array([0.5]))"
        )
    if array.shape != (1,):
        hint = f" (wrap it: env.step([{action!r}]))" if array.shape == () else ""
        raise ValueError(
            f"action must be one number (shape (1,)), got shape {array.shape}: {action!r}{hint}"
        )
    return float(array[0])


def _frame(sim: EnvCore, i: int) -> npt.NDArray[np.uint8]:
    """Draw env ``i`` with its device's drawing, at its position in env units."""
    if sim.device.drawing is None:
        raise NotImplementedError(f"{sim.device.name} has no drawing (Device.drawing)")
    x, reference, stuck, steps, command = sim.frame(i)
    draw = getattr(rendering, sim.device.drawing)
    position = sim.device.direction * x + 0.0  # + 0.0: the wall at 0.0, not -0.0
    if draw is rendering.draw_axis:  # its rail spans the safety limit, in the device's unit
        unit = sim.device.position_unit
        draw = functools.partial(draw, span=abs(sim.limit) or 1.0, unit=unit)
    return draw(position, reference, stuck=stuck, time=steps * sim.dt, command=command)
