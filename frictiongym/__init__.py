"""frictiongym: friction as a first-class part of motion-control simulation and control.

Importing the package registers its Gymnasium ids (``frictiongym/RotaryServo-v1``,
``frictiongym/AltinoDistance-v1``): at once if gymnasium is already imported, otherwise the
moment it is, so ``import frictiongym`` and ``import gymnasium`` work in either order while
``import frictiongym`` alone stays light (no gymnasium, no numba: ``frictiongym --help`` starts
fast). ``load_params``, ``save_params``, ``DeviceParams`` (:mod:`frictiongym.params`) and
``register_envs`` are imported on first use for the same reason.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
from collections.abc import Sequence
from types import ModuleType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from frictiongym.envs import register_envs
    from frictiongym.params import DeviceParams, load_params, save_params

__version__ = "0.1.0"

__all__ = ["DeviceParams", "load_params", "register_envs", "save_params"]

#: Names imported on first use -> their module.
_LAZY = {
    "DeviceParams": "frictiongym.params",
    "load_params": "frictiongym.params",
    "save_params": "frictiongym.params",
    "register_envs": "frictiongym.envs",
}


def _register() -> None:
    # Importing frictiongym.envs registers the ids (at its end, so also when gymnasium was
    # first imported by frictiongym.envs itself); it imports gymnasium: called once it is.
    importlib.import_module("frictiongym.envs")


class _RegisterWhenGymnasiumLoads(importlib.abc.MetaPathFinder):
    """Import hook: registers the ids right after gymnasium's own module has run."""

    def find_spec(
        self, name: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)  # once; and find the real module through the other finders
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.loader is not None:
            run_module = spec.loader.exec_module

            def run_then_register(module: ModuleType) -> None:
                run_module(module)
                _register()

            spec.loader.exec_module = run_then_register  # type: ignore[method-assign]
        return spec


if "gymnasium" in sys.modules:
    _register()
else:
    sys.meta_path.insert(0, _RegisterWhenGymnasiumLoads())


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'frictiongym' has no attribute {name!r}")
