"""frictiongym: friction as a first-class part of motion-control simulation and control.

Importing the package registers its Gymnasium ids (``frictiongym/RotaryServo-v0``,
``frictiongym/AltinoDistance-v0``). ``load_params``, ``save_params`` and ``DeviceParams``
(identified parameters, :mod:`frictiongym.params`) are imported on first use, so that
``import frictiongym`` stays light (no numba).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from frictiongym.envs import register_envs

if TYPE_CHECKING:
    from frictiongym.params import DeviceParams, load_params, save_params

__version__ = "0.1.0"

__all__ = ["DeviceParams", "load_params", "register_envs", "save_params"]

_LAZY = {"DeviceParams", "load_params", "save_params"}

register_envs()


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        from frictiongym import params

        return getattr(params, name)
    raise AttributeError(f"module 'frictiongym' has no attribute {name!r}")
