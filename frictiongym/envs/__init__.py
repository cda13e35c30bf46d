"""Gymnasium environments: the QUBE-Servo 2 and the Altino car, each with pluggable friction.

Importing this package (which ``import frictiongym`` does as soon as gymnasium is imported)
registers ``frictiongym/RotaryServo-v0``/``-v1``, ``frictiongym/AltinoDistance-v0``/``-v1`` and
``frictiongym/Axis-v0`` (any device from its description file, docs/devices.md) (single env
through ``gym.make``, native vector env through ``gym.make_vec(...,
vectorization_mode="vector_entry_point")``). The env modules are imported only when an env is
made.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import gymnasium as gym

if TYPE_CHECKING:
    from frictiongym.envs.altino import AltinoDistanceEnv, AltinoDistanceVectorEnv
    from frictiongym.envs.axis import AxisEnv, AxisVectorEnv
    from frictiongym.envs.rotary import RotaryServoEnv, RotaryServoVectorEnv

#: id -> (module, single class, vector class, max_episode_steps, env arguments). The steps
#: repeat the devices' ``episode_steps``: importing :mod:`frictiongym.devices` here would load
#: numba with every ``import gymnasium``; tests/test_devices.py checks that they agree. The
#: classes implement v1; the v0 ids, kept for the results made with them, have v0's reward
#: (``terminal_cost=False``: the env classes' "Rewards").
ENV_IDS: dict[str, tuple[str, str, str, int, dict[str, Any]]] = {
    f"frictiongym/{name}-v{version}": (module, f"{name}Env", f"{name}VectorEnv", steps, kwargs)
    for name, module, steps in (
        ("RotaryServo", "frictiongym.envs.rotary", 2500),
        ("AltinoDistance", "frictiongym.envs.altino", 400),
    )
    for version, kwargs in ((0, {"terminal_cost": False}), (1, {}))
}

#: Any device from its description file: ``gym.make(AXIS_ID, device="my_stage.toml")``. It
#: registers no episode length: the env truncates at the file's ``episode_steps`` itself.
AXIS_ID = "frictiongym/Axis-v0"

#: The env classes, imported on first use: class name -> module.
_LAZY = {name: entry[0] for entry in ENV_IDS.values() for name in entry[1:3]}
_LAZY |= {"AxisEnv": "frictiongym.envs.axis", "AxisVectorEnv": "frictiongym.envs.axis"}

__all__ = [
    "AXIS_ID",
    "ENV_IDS",
    "AltinoDistanceEnv",
    "AltinoDistanceVectorEnv",
    "AxisEnv",
    "AxisVectorEnv",
    "RotaryServoEnv",
    "RotaryServoVectorEnv",
    "checked_device",
    "device_of_id",
    "env_arguments",
    "make",
    "make_vec",
    "register_envs",
]


def register_envs() -> None:
    """Register the frictiongym ids with Gymnasium (idempotent)."""
    for env_id, (module, single, vector, steps, kwargs) in ENV_IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point=f"{module}:{single}",
            vector_entry_point=f"{module}:{vector}",
            max_episode_steps=steps,
            kwargs=kwargs,
        )
    if AXIS_ID not in gym.registry:
        gym.register(
            id=AXIS_ID,
            entry_point="frictiongym.envs.axis:AxisEnv",
            vector_entry_point="frictiongym.envs.axis:AxisVectorEnv",
        )


register_envs()


def env_arguments(device: Any, kwargs: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """Return the id and arguments that make an env of ``device`` through Gymnasium.

    ``device`` is anything :func:`frictiongym.devices.get` takes: an env id, a device's kind or
    name, a description file's path or a ``Device``. A built-in device keeps the id given (a
    v0 id stays v0); any other is made as ``frictiongym/Axis-v0`` with ``device=`` its file (or
    the ``Device``), and a ``max_episode_steps`` becomes its ``episode_steps``.
    """
    from frictiongym import devices

    found = devices.get(device)
    if found.env_id != AXIS_ID:
        given = isinstance(device, str) and device.startswith("frictiongym/")
        return (device if given else found.env_id), kwargs
    kwargs = {**kwargs, "device": found.source or found}
    return AXIS_ID, kwargs


def checked_device(spelling: Any) -> Any:
    """Return the device ``spelling`` names, checked as its env checks it.

    A described device's reference tables are built here (:func:`frictiongym.envs.axis.
    axis_device`), so a tool refuses a bad file before its work starts.

    Raises
    ------
    ValueError
        An unknown device, or a description file that cannot be used (``DeviceFileError``).
    """
    from frictiongym import devices
    from frictiongym.envs.axis import axis_device

    found = devices.get(spelling)
    return found if found in devices.DEVICES else axis_device(found)


def device_of_id(env_id: str, ids: Iterable[str], name: str = "env id") -> Any:
    """Return the device behind ``env_id``, one of ``ids`` or a description file's path.

    What the tools that take an env id accept (``name`` is how their messages call it).

    Raises
    ------
    DeviceFileError
        A description file that cannot be used (its message names the file and the field).
    ValueError
        Neither one of ``ids`` nor a description file: the message lists ``ids``.
    """
    from frictiongym import devices

    try:
        return checked_device(env_id)
    except devices.DeviceFileError:
        raise
    except ValueError:
        raise ValueError(
            f"unknown {name} {env_id!r}; use one of {', '.join(ids)} or a device description "
            "file (.toml or .json, docs/devices.md)"
        ) from None


def make(device: Any, **kwargs: Any) -> Any:
    """``gym.make`` for any device (see :func:`env_arguments`), e.g. ``make("stage.toml")``."""
    env_id, kwargs = env_arguments(device, kwargs)
    if env_id == AXIS_ID and "max_episode_steps" in kwargs:  # gym.make's own would only cut it
        kwargs["episode_steps"] = kwargs.pop("max_episode_steps")
    return gym.make(env_id, **kwargs)


def make_vec(device: Any, num_envs: int = 1, **kwargs: Any) -> Any:
    """``gym.make_vec(..., vectorization_mode="vector_entry_point")`` for any device."""
    env_id, kwargs = env_arguments(device, kwargs)
    kwargs.setdefault("vectorization_mode", "vector_entry_point")
    return gym.make_vec(env_id, num_envs=num_envs, **kwargs)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'frictiongym.envs' has no attribute {name!r}")
