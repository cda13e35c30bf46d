"""``frictiongym/Axis-v0``: any single-axis device, from its description file (docs/devices.md).

``gym.make("frictiongym/Axis-v0", device="my_stage.toml")`` gives the env of the device the
file describes, with every argument of the built-in envs (the servo's, in the device's units);
``gym.make_vec(..., vectorization_mode="vector_entry_point")`` its native vector env.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from frictiongym import devices
from frictiongym.devices import Device
from frictiongym.envs.base import ActArray, FrictionEnv, ObsArray
from frictiongym.envs.references import PRESET_CLASSES
from frictiongym.envs.vector import FrictionVectorEnv


def axis_device(device: str | os.PathLike[str] | Device | None) -> Device:
    """Return the device of an Axis env: a :class:`Device` or its description file, checked.

    Raises
    ------
    TypeError
        If ``device`` is missing or neither a path nor a device.
    DeviceFileError
        If the file cannot be used (a ``ValueError``); the message names the file and field.
    """
    if device is None:
        raise TypeError(
            "frictiongym/Axis-v0 needs device=: the path of a device description file "
            "(gym.make('frictiongym/Axis-v0', device='my_stage.toml'); docs/devices.md)"
        )
    if not isinstance(device, Device | str | os.PathLike):
        raise TypeError(f"device must be a description file's path or a Device, got {device!r}")
    described = devices.get(device)
    if described not in devices.DEVICES:
        devices.register(described)  # a Device built in code, or one from another process
    for kind, arguments in described.references.items():  # the file's tables, built once here
        if kind not in PRESET_CLASSES:
            raise devices.DeviceFileError(
                f"{described.source or described.name}: references.{kind}: unknown kind; use "
                f"{', '.join(PRESET_CLASSES)}"
            )
        try:
            PRESET_CLASSES[kind](**arguments)
        except (TypeError, ValueError) as error:
            raise devices.DeviceFileError(
                f"{described.source or described.name}: references.{kind}: {error}"
            ) from None
    return described


class AxisEnv(FrictionEnv):
    """Position control of the single-axis device that ``device`` describes.

    Takes ``device`` (the path of its description file, TOML or JSON, or a
    :class:`~frictiongym.devices.Device`) and the arguments of
    :class:`~frictiongym.envs.RotaryServoEnv`, in the device's units. An episode is truncated
    after the file's ``episode_steps`` (``episode_steps=`` sets another length: Gymnasium's
    ``max_episode_steps`` can only shorten it, as this id registers none).
    """

    def __init__(
        self,
        device: str | os.PathLike[str] | Device | None = None,
        *,
        episode_steps: int | None = None,
        **kwargs: Any,
    ) -> None:
        self.device = axis_device(device)
        steps = self.device.episode_steps if episode_steps is None else episode_steps
        if not isinstance(steps, int | np.integer) or isinstance(steps, bool) or steps < 1:
            raise ValueError(f"episode_steps must be a positive whole number, got {steps!r}")
        self.episode_steps = int(steps)
        kwargs.setdefault("horizon", self.episode_steps)
        super().__init__(**kwargs)
        self._elapsed = 0

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickle, and make the device known to this process (its tools look it up)."""
        super().__setstate__(state)
        devices.register(self.device)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsArray, dict[str, Any]]:
        """Start an episode (see :class:`~frictiongym.envs.RotaryServoEnv`)."""
        self._elapsed = 0
        return super().reset(seed=seed, options=options)

    def step(self, action: ActArray) -> tuple[ObsArray, float, bool, bool, dict[str, Any]]:
        """Hold ``action`` over one period; truncated after ``episode_steps``."""
        obs, reward, terminated, _, info = super().step(action)
        self._elapsed += 1
        return obs, reward, terminated, self._elapsed >= self.episode_steps, info


class AxisVectorEnv(FrictionVectorEnv):
    """``num_envs`` envs of the device that ``device`` describes, stepped by one compiled call.

    Takes :class:`AxisEnv`'s ``device`` and the built-in vector envs' arguments;
    ``max_episode_steps`` defaults to the file's ``episode_steps``.
    """

    def __init__(
        self,
        num_envs: int = 1,
        *,
        device: str | os.PathLike[str] | Device | None = None,
        max_episode_steps: int | None = None,
        **kwargs: Any,
    ) -> None:
        self.device = axis_device(device)
        steps = self.device.episode_steps if max_episode_steps is None else max_episode_steps
        super().__init__(num_envs, max_episode_steps=steps, **kwargs)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickle, and make the device known to this process (its tools look it up)."""
        self.__dict__.update(state)
        devices.register(self.device)


__all__ = ["AxisEnv", "AxisVectorEnv", "axis_device"]
