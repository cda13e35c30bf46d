"""The controller interface: what a controller knows about its loop, and how it is called.

Every controller maps an observation to an action (``controller(obs)``) and forgets its
history on ``reset()``. It is built for an env from a :class:`LoopSpec`, which says where the
measured output, its rate and the reference sit in the observation, the control period, the
action limit and the sign of the plant's gain. The spec is read from the env, so the same
controller object runs on the simulator and, unchanged, on a hardware backend of the same
device.

Controllers are batched: an observation of shape ``(k,)`` gives an action of shape ``(1,)``
(a single env), one of shape ``(N, k)`` gives ``(N, 1)`` (a vector env), and
``reset(mask)`` forgets the history of the selected envs only. A controller keeps its per-env
history in numpy arrays with the batch on the last axis (shape ``(..., N)``): that is what
lets :meth:`Controller.advance` step some envs and leave the others.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from frictiongym._validation import real_number
from frictiongym.devices import device_of
from frictiongym.friction import FrictionModel

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class LoopSpec:
    """What a controller needs to know about the loop it closes.

    Parameters
    ----------
    dt : float
        Control period, s.
    limit : float
        Action magnitude limit (volts, or Altino motor units).
    position : int
        Index of the measured output in the observation.
    velocity : int or None
        Index of the measured rate of that output, if the observation carries one.
    reference : int
        Index of the reference.
    direction : float
        ``+1`` if a positive command increases the output, ``-1`` if it decreases it (the
        Altino: driving forward shortens the distance to the wall).
    rest_speed : float
        Speed of the output below which a friction compensator treats the body as at rest.
    friction : FrictionModel or None
        The device's identified friction, the compensator's default model: the env's
        ``params`` file if it was made with one, else the device's paper preset (also when the
        env simulates another law, e.g. ``friction="coulomb"``: a structural mismatch).
    dead_zone : float
        The actuator dead zone's half-width that file identified (command units; 0: none), the
        compensator's default: its levels are then the friction's own, below the zone.
    device : str or None
        The name of the device the loop runs on (``Device.name``; None: not known). A
        compensator refuses a model file identified on another device.
    """

    dt: float
    limit: float
    position: int = 0
    velocity: int | None = 1
    reference: int = 2
    direction: float = 1.0
    rest_speed: float = 0.0
    friction: FrictionModel | None = None
    dead_zone: float = 0.0
    device: str | None = None

    def __post_init__(self) -> None:
        real_number("LoopSpec.dt", self.dt, "> 0", unit=" s")
        if not self.limit > 0.0:
            raise ValueError(f"LoopSpec.limit must be > 0, got {self.limit!r}")
        if self.direction not in (1.0, -1.0):
            raise ValueError(f"LoopSpec.direction must be 1.0 or -1.0, got {self.direction!r}")
        real_number("LoopSpec.rest_speed", self.rest_speed, ">= 0")
        real_number("LoopSpec.dead_zone", self.dead_zone, ">= 0")

    @classmethod
    def from_env(cls, env: Any) -> LoopSpec:
        """Read the spec of a frictiongym env (single or vector, wrapped or not).

        Raises
        ------
        TypeError
            If ``env`` is not a frictiongym env (build a :class:`LoopSpec` by hand then).
        """
        base = getattr(env, "unwrapped", env)
        try:
            device = device_of(base)
        except TypeError:
            raise TypeError(
                f"{type(base).__name__} is not a frictiongym env; build the controller with "
                "an explicit LoopSpec(dt=..., limit=..., position=..., velocity=..., "
                "reference=...) instead of for_env"
            ) from None
        names = device.observation_names
        space = getattr(base, "single_action_space", None) or base.action_space
        params = getattr(base.sim, "params", None)
        return cls(
            dt=float(base.dt),
            limit=float(space.high[0]),
            position=names.index(device.output),
            velocity=names.index("velocity") if "velocity" in names else None,
            reference=names.index("reference"),
            direction=device.direction,
            rest_speed=device.rest_speed,
            friction=base.sim.model_friction,
            dead_zone=(params.dead_zone or 0.0) if params is not None else 0.0,
            device=device.name,
        )

    def split(self, observation: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Split an observation (``(k,)`` or ``(N, k)``) into ``(reference, output, rate)``.

        The rate is NaN when the observation carries none.
        """
        obs = np.asarray(observation, dtype=np.float64)
        if obs.ndim not in (1, 2):
            raise ValueError(
                f"an observation must have shape (k,) or (num_envs, k), got {obs.shape}"
            )
        columns = [self.position, self.reference] + (
            [] if self.velocity is None else [self.velocity]
        )
        if obs.shape[-1] <= max(columns):
            raise ValueError(
                f"the observation has {obs.shape[-1]} entries but the LoopSpec reads entry "
                f"{max(columns)}: is the controller built for this env?"
            )
        y = obs[..., self.position]
        rate = obs[..., self.velocity] if self.velocity is not None else np.full_like(y, np.nan)
        return obs[..., self.reference], y, rate


C = TypeVar("C", bound="Controller")


class Controller(ABC):
    """A feedback controller: ``reset()`` and ``controller(observation) -> action``.

    Subclasses set :attr:`spec` and implement :meth:`command`; :meth:`__call__` shapes the
    result as an action and saturates it at the spec's limit.
    """

    spec: LoopSpec

    @classmethod
    def for_env(cls: type[C], env: Any, *args: Any, **kwargs: Any) -> C:
        """Build the controller for ``env``: ``cls(LoopSpec.from_env(env), *args, **kwargs)``."""
        return cls(LoopSpec.from_env(env), *args, **kwargs)  # type: ignore[call-arg]

    @abstractmethod
    def reset(self, mask: npt.ArrayLike | None = None) -> None:
        """Forget the history, of every env or of those where ``mask`` is True."""

    @abstractmethod
    def command(self, observation: FloatArray) -> FloatArray:
        """Unsaturated command for an observation batch of shape ``(k,)`` or ``(N, k)``.

        Returns an array of the batch shape: ``()`` or ``(N,)``.
        """

    def __call__(self, observation: npt.ArrayLike) -> FloatArray:
        """Return the action: ``(1,)`` for an observation ``(k,)``, ``(N, 1)`` for ``(N, k)``.

        The command is saturated at the spec's limit.
        """
        obs = np.asarray(observation, dtype=np.float64)
        u = np.clip(self.command(obs), -self.spec.limit, self.spec.limit)
        return np.asarray(u, dtype=np.float64)[..., np.newaxis]

    def advance(self, observation: npt.ArrayLike, mask: npt.ArrayLike) -> FloatArray:
        """Return the actions of a batch ``(N, k)`` as a call does; update only ``mask``'s envs.

        The other envs' history is left as it was, so they can be called again on the same
        step: what a vector env needs after resetting some envs within a step (their base
        controller is reset and called on the new episode's first observation). It relies on
        the convention that makes ``reset(mask)`` work: a controller keeps its per-env history
        in numpy arrays whose last axis is the batch (its own, and those of the controllers
        it holds).
        """
        keep = ~np.asarray(mask, dtype=bool)
        saved = [(owner, name, value.copy()) for owner, name, value in _history(self)]
        for owner, name, value in saved:
            if value.ndim and value.shape[-1] != keep.size and keep.size in value.shape:
                raise TypeError(
                    f"{type(owner).__name__}.{name} has shape {value.shape}: keep per-env "
                    f"history with the batch on the last axis (shape (..., {keep.size})), "
                    "so that advance() and reset(mask) can tell the envs apart"
                )
        action = self(observation)
        for owner, name, old in saved:
            new = getattr(owner, name)
            if old.ndim and new.shape == old.shape and old.shape[-1] == keep.size:
                new = np.array(new)
                new[..., keep] = old[..., keep]
                setattr(owner, name, new)
        return action


def _history(controller: Controller) -> list[tuple[Controller, str, FloatArray]]:
    """Return the numpy arrays a controller and the controllers it holds keep as attributes."""
    found = []
    for name, value in vars(controller).items():
        if isinstance(value, np.ndarray):
            found.append((controller, name, value))
        elif isinstance(value, Controller):
            found += _history(value)
    return found


def reset_mask(mask: npt.ArrayLike | None, size: int) -> BoolArray | None:
    """``mask`` as a boolean array of ``size`` (None: every env), with a clear error."""
    if mask is None:
        return None
    m = np.asarray(mask, dtype=bool).reshape(-1)
    if m.size == 1:
        return np.full(size, bool(m[0]))
    if m.size != size:
        raise ValueError(f"reset mask has {m.size} entries for a batch of {size} envs")
    return m
