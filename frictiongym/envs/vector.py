"""The native vector env: N envs of one device stepped by one compiled call.

It follows Gymnasium 1.x's vector API as :class:`~gymnasium.vector.SyncVectorEnv` over N
single envs does, in each of the three autoreset modes (``autoreset_mode=``):

* ``NEXT_STEP`` (the default): an env whose episode ended is reset by the next ``step``,
  which spends that env's action on the reset (reward 0, the reset's observation and info);
* ``SAME_STEP`` (CleanRL's scripts, Stable-Baselines3): the ended env is reset within the
  step that ended it; the step returns the reset's observation and info, and the last
  observation and info of the episode in ``info["final_obs"]`` and ``info["final_info"]``;
* ``DISABLED``: nothing is reset for you; reset the ended envs with
  ``reset(options={"reset_mask": mask})`` before the next step.

``reset(options={"reset_mask": mask})`` works in every mode, and ``call``, ``get_attr`` and
``set_attr`` answer as ``SyncVectorEnv``'s do where a batch of envs sharing one compiled
simulation can (see :meth:`FrictionVectorEnv.call`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium.envs.registration import EnvSpec
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from frictiongym.envs import _kernel as env_kernel
from frictiongym.envs.base import (
    _O_COMMAND,
    _O_POSITION,
    _O_REFERENCE,
    _O_TIME,
    _O_VELOCITY,
    _OUT_ROWS,
    _RENDER_FPS,
    _VECTOR_ARGUMENTS,
    INFO_KEYS,
    ActArray,
    ObsArray,
    _check_arguments,
    _frame,
    _refuse_masked,
    _spaces,
)
from frictiongym.envs.core import Device, Simulation
from frictiongym.hardware import SIM

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
#: What ``call`` and ``get_attr`` read per env, as each single env of a SyncVectorEnv holds it.
_PER_ENV = ("np_random", "np_random_seed", "render")
#: Rows of a step's flags array: the kernel's flags, then the info's masks (``_position`` ...).
_FLAG_AND_MASK_ROWS = env_kernel.FLAG_SIZE + len(INFO_KEYS) + 1
#: Action dtypes the kernel takes as they are (native byte order: numba refuses others).
_KERNEL_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


def _autoreset_mode(value: AutoresetMode | str) -> AutoresetMode:
    """``value`` as an :class:`~gymnasium.vector.AutoresetMode` (the enum or its value)."""
    try:
        return AutoresetMode(value)
    except ValueError:
        names = ", ".join(f"AutoresetMode.{m.name} ({m.value!r})" for m in AutoresetMode)
        raise ValueError(f"autoreset_mode must be one of {names}; got {value!r}") from None


class FrictionVectorEnv(VectorEnv[ObsArray, ActArray, Any]):
    """Base class of the native vector envs; see :class:`~frictiongym.envs.RotaryServoVectorEnv`."""

    device: Device  #: a class attribute of the built-in envs, set per env by the Axis envs
    metadata = {  # noqa: RUF012  (gymnasium declares it an instance attribute)
        "render_modes": ["rgb_array"],
        "render_fps": _RENDER_FPS,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        *,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        parallel: bool | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        **kwargs: Any,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"the vector env renders 'rgb_array' only, got {render_mode!r}")
        backend = kwargs.pop("backend", "sim")
        _check_arguments(self, kwargs, _VECTOR_ARGUMENTS)
        if backend is not None and backend not in SIM:
            raise ValueError(
                f"backend={backend!r}: a device is one env; make it with gym.make (the vector "
                "env simulates only)"
            )
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}
        self.render_mode = render_mode
        self.sim = Simulation(
            self.device, num_envs, max_episode_steps=max_episode_steps, parallel=parallel, **kwargs
        )
        self.num_envs = self.sim.num_envs
        self.dt = self.sim.dt
        self.tracking_cap, self.horizon = self.sim.tracking_cap, self.sim.horizon  # as the single
        self.max_episode_steps = max_episode_steps
        self.single_action_space, self.single_observation_space = _spaces(self.device, self.sim)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._seeds: list[int | None] = [None] * self.num_envs
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        # Which envs ended on the last step (a row of its flags), and whether any did; fresh
        # for a step with none (the kernel only reads it).
        self._done = np.zeros(self.num_envs, dtype=bool)
        self._ended = False
        self._none_fresh = np.zeros(self.num_envs, dtype=bool)
        self._needs_reset = True
        self._set_by_user: set[str] = set()

    def _rng(self, i: int) -> np.random.Generator:
        """Env ``i``'s generator, created on first use (most tasks draw nothing)."""
        rng = self._rngs[i]
        if rng is None:
            rng, self._seeds[i] = seeding.np_random(self._seeds[i])
            self._rngs[i] = rng
        return rng

    def _seed_of(self, i: int) -> int | None:
        """Env ``i``'s seed, as ``Env.np_random_seed`` reads it (an unseeded env draws one)."""
        self._rng(i)
        return self._seeds[i]

    def _outputs(self) -> tuple[ObsArray, FloatArray, BoolArray]:
        """Return new arrays for a step's observation, outputs and flags.

        The flags come with one more row per info key below them, for the ``_key`` masks of
        :meth:`_info` (one allocation less per step; the kernel reads ``FLAG_SIZE`` rows).
        """
        n = self.num_envs
        return (
            np.empty((n, self.sim.observation_size), dtype=np.float32),
            np.empty((env_kernel.OUT_SIZE, n)),
            np.empty((_FLAG_AND_MASK_ROWS, n), dtype=bool),
        )

    def _info(
        self, out: FloatArray, flags: BoolArray, mask: BoolArray | None = None
    ) -> dict[str, Any]:
        """Return the envs' info with Gymnasium's ``_key`` masks (only the envs of ``mask``)."""
        if mask is not None:  # as SyncVectorEnv gathers a subset: zeros elsewhere
            values = [out[row] for row in _OUT_ROWS] + [flags[env_kernel.F_STUCK]]
            info: dict[str, Any] = {}
            for key, value in zip((*INFO_KEYS, "stuck"), values, strict=True):
                info[key], info["_" + key] = np.where(mask, value, value.dtype.type(0)), mask.copy()
            return info
        # Every env reports every key: new masks each call, the rows of `flags` below its
        # flags (written out: this runs every step).
        masks = flags[env_kernel.FLAG_SIZE :]
        masks.fill(True)
        return {
            "position": out[_O_POSITION],
            "_position": masks[0],
            "velocity": out[_O_VELOCITY],
            "_velocity": masks[1],
            "command": out[_O_COMMAND],
            "_command": masks[2],
            "reference": out[_O_REFERENCE],
            "_reference": masks[3],
            "time": out[_O_TIME],
            "_time": masks[4],
            "stuck": flags[env_kernel.F_STUCK],
            "_stuck": masks[5],
        }

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[ObsArray, dict[str, Any]]:
        """Reset every env, or those of ``options["reset_mask"]``; env ``i`` is seeded ``seed + i``.

        ``seed`` may also be a list of one seed (or None) per env. Without a seed an env
        continues its generator, as :class:`~gymnasium.vector.SyncVectorEnv`'s envs do: a run
        seeded once is reproducible through later unseeded resets. ``options`` may hold
        ``reset_mask`` (a boolean array of one entry per env, at least one True: reset only
        those; the others keep their observation and report no info) and the single env's
        reset options (``position``, ``velocity``, ``reference``).
        """
        options = dict(options) if options else {}
        mask = options.pop("reset_mask", None)
        if mask is not None:
            mask = self._reset_mask(mask)
        super().reset(seed=seed if isinstance(seed, int) else None)
        if isinstance(seed, int):
            seed = [seed + i for i in range(self.num_envs)]
        elif seed is None:
            seed = [None] * self.num_envs
        elif len(seed) != self.num_envs:
            raise ValueError(f"seed lists need {self.num_envs} entries, got {len(seed)}")
        targets = np.ones(self.num_envs, dtype=bool) if mask is None else mask
        if mask is not None:  # an N-long position or velocity: the masked envs' entries
            for key in ("position", "velocity"):
                value = np.asarray(options.get(key, 0.0))
                if value.ndim == 1 and value.size == self.num_envs:
                    options[key] = value[mask]
        for i in np.flatnonzero(targets):
            if seed[i] is not None:
                self._seeds[i], self._rngs[i] = seed[i], None
        self.sim.prepare_reset(targets, self._rng, options or None)
        if mask is None:
            obs, out, flags = self._outputs()
            self.sim.run(np.zeros(self.num_envs), targets, obs, out, flags)
            info = self._info(out, flags)
        else:
            obs = self.sim.observations()  # the others' last observation, from their state
            out = np.zeros((env_kernel.OUT_SIZE, self.num_envs))
            flags = np.zeros((env_kernel.FLAG_SIZE, self.num_envs), dtype=bool)
            self.sim.observe(mask, obs, out, flags)
            info = self._info(out, flags, mask)
        self._done[targets] = False
        self._ended = bool(self._done.any())
        self._needs_reset = False
        return obs, info

    def _reset_mask(self, mask: Any) -> BoolArray:
        """Check ``reset_mask`` as SyncVectorEnv does (same rules, messages that say how)."""
        n = self.num_envs
        if not isinstance(mask, np.ndarray):
            raise TypeError(f"options['reset_mask'] must be a numpy array, got {type(mask)}")
        if mask.shape != (n,):
            raise ValueError(f"options['reset_mask'] must have shape ({n},), got {mask.shape}")
        if mask.dtype != np.bool_:
            raise TypeError(f"options['reset_mask'] must have dtype bool, got {mask.dtype}")
        if not mask.any():
            raise ValueError("options['reset_mask'] must select at least one env (one True)")
        if self._needs_reset:
            raise gym.error.ResetNeeded(
                "reset every env once (reset() without reset_mask) before resetting some"
            )
        return mask.copy()

    def step(
        self, actions: ActArray
    ) -> tuple[ObsArray, FloatArray, BoolArray, BoolArray, dict[str, Any]]:
        """Step every env; what happens to an ended env depends on the autoreset mode."""
        if self._needs_reset:
            raise gym.error.ResetNeeded("Cannot call step() before calling reset()")
        if type(actions) is np.ndarray and actions.dtype in _KERNEL_DTYPES:  # the common case
            command = actions.reshape(self._command_shape(actions.shape))
        else:
            command = self._commands(actions)
        mode = self.autoreset_mode
        fresh, autoreset = self._none_fresh, None
        if self._ended:
            if mode is AutoresetMode.DISABLED:
                raise gym.error.ResetNeeded(
                    f"envs {np.flatnonzero(self._done).tolist()} ended on the last step and "
                    "autoreset_mode is DISABLED: reset them first with "
                    "reset(options={'reset_mask': ...})"
                )
            if mode is AutoresetMode.NEXT_STEP:
                # reset by the run, after its check: a refused action resets no env
                fresh, autoreset = self._done, self._rng
        obs, out, flags = self._outputs()
        ended = self.sim.run(command, fresh, obs, out, flags, autoreset)
        # Rows of this step's own output arrays, fresh every step (copied below only where a
        # same-step reset writes them again).
        reward = out[env_kernel.O_REWARD]
        terminated = flags[env_kernel.F_TERMINATED]
        truncated = flags[env_kernel.F_TRUNCATED]
        # the kernel's count: this thread need not read the flags its threads just wrote
        self._done, self._ended = flags[env_kernel.F_DONE], ended > 0
        done = self._done
        if mode is AutoresetMode.SAME_STEP and self._ended:
            reward, terminated, truncated = reward.copy(), terminated.copy(), truncated.copy()
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(done):
                final_obs[i] = obs[i].copy()
            final = {
                "final_obs": final_obs,
                "_final_obs": done.copy(),
                "final_info": self._info(out, flags, done),
                "_final_info": done.copy(),
            }
            reset = final["_final_obs"]  # not `done`: observing writes its row of `flags`
            self.sim.prepare_reset(reset, self._rng)
            self.sim.observe(reset, obs, out, flags)
            info = {**final, **self._info(out, flags)}
            done[:] = False
            self._ended = False
        else:
            info = self._info(out, flags)
        return obs, reward, terminated, truncated, info

    def _command_shape(self, shape: tuple[int, ...]) -> int:
        """Return N for an action array of ``shape`` (N, 1) or (N,), or raise a ValueError."""
        n = self.num_envs
        if shape != (n, 1) and shape != (n,):
            raise ValueError(
                f"actions must hold one command per env, shape ({n}, 1) (or ({n},)); got shape "
                f"{shape}"
            )
        return n

    def _commands(self, actions: ActArray) -> npt.NDArray[np.floating[Any]]:
        """Return one float command per env, or raise a ValueError that says what is wrong."""
        _refuse_masked(actions)
        command = np.asarray(actions)
        if command.dtype not in _KERNEL_DTYPES:  # those two go to the kernel as they are
            if command.dtype.kind not in "iuf":
                raise ValueError(
                    f"actions must be numbers in command units, one per env, got dtype "
                    f"{command.dtype}"
                )
            command = command.astype(np.float64)
        return command.reshape(self._command_shape(command.shape))

    def render(self) -> tuple[npt.NDArray[np.uint8], ...] | None:
        """One RGB frame per env (``render_mode='rgb_array'``)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array'")
            return None
        if self._needs_reset:
            raise gym.error.ResetNeeded("Cannot call render() before calling reset()")
        return tuple(_frame(self.sim, i) for i in range(self.num_envs))

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        """Return what ``SyncVectorEnv.call`` would: one result per env.

        The envs share one simulation, so only these have per-env answers: ``render`` (each
        env's frame), ``np_random`` and ``np_random_seed`` (each env's generator and seed).
        ``action_space`` and ``observation_space`` are the single env's; any other attribute
        that is not a method (``dt``, ``device``, ``spec``, ``render_mode``, one set by
        :meth:`set_attr`...) is the same for every env. Other methods raise AttributeError.
        """
        if name == "render":
            frames = self.render(*args, **kwargs)
            return (None,) * self.num_envs if frames is None else frames
        if name == "np_random":
            return tuple(self._rng(i) for i in range(self.num_envs))
        if name == "np_random_seed":
            return tuple(self._seed_of(i) for i in range(self.num_envs))
        if name == "spec":  # the single env's, as gym.make would register it
            return (self._single_spec(),) * self.num_envs
        single = {
            "action_space": "single_action_space",
            "observation_space": "single_observation_space",
        }
        value = getattr(self, single.get(name, name))
        if callable(value) and not isinstance(value, gym.Space):
            raise AttributeError(
                f"call({name!r}): the native vector env's envs share one simulation and have "
                f"no method {name!r} of their own; per env it answers {', '.join(_PER_ENV)} and "
                "attributes that are not methods (use SyncVectorEnv for other methods)"
            )
        return (value,) * self.num_envs

    def _single_spec(self) -> EnvSpec | None:
        """Return the spec of one of its envs: the vector env's own arguments left out."""
        if self.spec is None:
            return None
        vector_only = ("num_envs", "vectorization_mode", "autoreset_mode", "parallel")
        kwargs = {k: v for k, v in self.spec.kwargs.items() if k not in vector_only}
        steps = kwargs.pop("max_episode_steps", self.spec.max_episode_steps)
        return replace(self.spec, kwargs=kwargs, max_episode_steps=steps)

    def get_attr(self, name: str) -> tuple[Any, ...]:
        """One value per env, as :meth:`call` reads it."""
        return self.call(name)

    def set_attr(self, name: str, values: list[Any] | tuple[Any, ...] | Any) -> None:
        """Set an attribute of the envs, one value for all (a list or tuple: one per env).

        The envs share this object, so a list must hold one value N times. Only new
        attributes (for a wrapper or a callback to read back) can be set: the env's own
        settings are fixed when it is made, so make a new env to change them.
        """
        if not isinstance(values, list | tuple):
            values = [values] * self.num_envs
        if len(values) != self.num_envs:
            raise ValueError(
                f"set_attr needs one value or a list of {self.num_envs}, got {len(values)} values"
            )
        if any(not _same(v, values[0]) for v in values[1:]):
            raise ValueError(
                f"set_attr({name!r}): the native vector env's envs share one value of each "
                "attribute; give one value for all of them"
            )
        if hasattr(self, name) and name not in self._set_by_user:
            raise AttributeError(
                f"set_attr({name!r}): {name} is the env's own setting, fixed when it is made; "
                f"make a new env with the value you want (gym.make_vec(..., {name}=...))"
            )
        self._set_by_user.add(name)
        setattr(self, name, values[0])


def _same(a: Any, b: Any) -> bool:
    """Whether two attribute values are one value (arrays compared by their contents)."""
    if a is b:
        return True
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return bool(np.array_equal(a, b))
    return bool(a == b)
