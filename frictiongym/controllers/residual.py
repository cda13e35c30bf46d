"""A base controller plus a trained residual policy, behind the common controller interface.

Stable-Baselines3 (and torch) are imported only by :meth:`ResidualController.load`, so this
module is as light as the other controllers.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym.controllers.base import Controller, FloatArray
from frictiongym.controllers.policy_file import load_policy, read_data
from frictiongym.controllers.residual_core import (
    OBSERVATION_BOUND,
    OBSERVATION_SIZE,
    ResidualConfig,
    bounded_residual,
    make_base,
    residual_observation,
)
from frictiongym.devices import device_of

#: Attribute of a saved SB3 model holding what :meth:`ResidualController.load` needs (the
#: config, the base controller, the algorithm); SB3 saves it inside the model's zip.
METADATA_ATTRIBUTE = "frictiongym_residual"
#: Stable-Baselines3 classes by ``frictiongym train --algo`` name.
ALGORITHMS = {"ppo": "PPO", "sac": "SAC", "td3": "TD3"}


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read the residual metadata of a model saved by ``frictiongym train``, without SB3.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If ``path`` is not an SB3 model zip or carries no residual metadata.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"no model at {path}: give the model.zip that frictiongym train wrote"
        )
    meta = read_data(path).get(METADATA_ATTRIBUTE)
    if not isinstance(meta, dict) or "config" not in meta:
        raise ValueError(
            f"{path} is an SB3 model without frictiongym residual metadata: train it with "
            "frictiongym train, or give the model and a ResidualConfig to ResidualController"
        )
    return meta


class ResidualController(Controller):
    """A base controller's action plus ``scale * clip(policy(obs'), -1, 1)``, saturated.

    ``obs'`` is :func:`~frictiongym.controllers.residual_core.residual_observation` of the
    observation and of the base action, the same as :class:`~frictiongym.residual.ResidualEnv`
    gives the policy in training; the policy is run deterministically. It reads only
    observations, so it runs on a device backend as on the simulator, on single and vector envs
    alike, through :func:`~frictiongym.controllers.rollout` and
    :class:`~frictiongym.controllers.ControllerPolicy`.

    Parameters
    ----------
    base : Controller
        The base controller (its :class:`LoopSpec` is shared), as in training.
    model : object
        A policy with SB3's ``predict(observation, deterministic=True) -> (action, state)``:
        an SB3 model or its policy.
    config : ResidualConfig, optional
        Observation scales and residual bound; by default the model's own (saved by
        ``frictiongym train``).
    deterministic : bool, default True
        Passed to ``predict``.
    """

    def __init__(
        self,
        base: Controller,
        model: Any,
        config: ResidualConfig | None = None,
        *,
        deterministic: bool = True,
    ) -> None:
        if config is None:
            meta = getattr(model, METADATA_ATTRIBUTE, None)
            if not isinstance(meta, Mapping) or "config" not in meta:
                raise ValueError(
                    "the model carries no residual config: give config=ResidualConfig(...) "
                    "(the one it was trained with)"
                )
            config = ResidualConfig.from_dict(meta["config"])
        if base.spec.limit != config.limit:
            raise ValueError(
                f"the base controller's limit {base.spec.limit} differs from the config's "
                f"{config.limit}: was the policy trained for this device?"
            )
        self.base = base
        self.model = model
        self.config = config
        self.deterministic = bool(deterministic)
        self.spec = base.spec

    @classmethod
    def for_env(  # the policy, not a LoopSpec, follows the env
        cls,
        env: Any,
        model: Any,
        config: ResidualConfig | None = None,
        *,
        base: Controller | None = None,
        deterministic: bool = True,
    ) -> ResidualController:
        """Build the controller for ``env``: ``model`` on ``base``.

        ``base`` defaults to the base of training, the paper's compensated PID of the env's
        device (:func:`~frictiongym.controllers.residual_core.make_base`); ``config`` to the
        model's own. The other arguments are the class's.
        """
        base = make_base(env) if base is None else base
        return cls(base, model, config, deterministic=deterministic)

    @classmethod
    def load(
        cls,
        path: str | os.PathLike[str],
        env: Any = None,
        *,
        base: Controller | None = None,
        device: str = "cpu",
    ) -> ResidualController:
        """Load a model saved by ``frictiongym train`` (``model.zip`` or a checkpoint).

        Nothing in the file is unpickled: the policy is rebuilt from the file's JSON and its
        weights loaded as a plain state dict (:mod:`frictiongym.controllers.policy_file`),
        so a model from a stranger cannot run code here. A file with pickled entries that
        Stable-Baselines3 does not write gets a warning (they are ignored).

        Parameters
        ----------
        path : str or PathLike
            The model zip.
        env : gymnasium.Env, optional
            The env to control (simulated or a device backend); the base controller is built
            for it as in training (the saved kind and gains). Needed unless ``base`` is given.
        base : Controller, optional
            A base controller to use instead.
        device : str, default "cpu"
            Torch device of the policy.

        Raises
        ------
        ValueError
            If the file is not a residual model, or was trained for another device.
        UnsafeModelError
            If the policy could only be built by unpickling (a ``ValueError``).
        ImportError
            If Stable-Baselines3 is not installed (``pip install "frictiongym[rl]"``).
        """
        meta = read_metadata(path)
        config = ResidualConfig.from_dict(meta["config"])
        if env is not None and device_of(env).name != config.device:
            raise ValueError(
                f"{path} was trained for {config.device}, not for this {device_of(env).name} env"
            )
        if base is None:
            if env is None:
                raise ValueError("give the env to control (or a base controller) to load a model")
            spec = meta.get("base", {})
            base = make_base(env, spec.get("kind", "compensated"), spec.get("gains"))
        algorithm = load_algorithm(str(meta.get("algo", "")))
        policy = load_policy(path, algorithm, OBSERVATION_SIZE, OBSERVATION_BOUND, device)
        return cls(base, policy, config)

    def reset(self, mask: npt.ArrayLike | None = None) -> None:
        """Reset the base controller (the policy is stateless)."""
        self.base.reset(mask)

    def residual(self, observation: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Return ``(base_action, residual)`` for an observation, each of the action's shape."""
        obs = np.asarray(observation, dtype=np.float64)
        base = self.base(obs)
        features = residual_observation(obs, self.spec, base, self.config)
        action, _ = self.model.predict(features, deterministic=self.deterministic)
        residual = bounded_residual(np.asarray(action).reshape(base.shape), self.config.scale)
        return base, residual

    def command(self, observation: FloatArray) -> FloatArray:
        """Return the base action plus the bounded residual (saturated by ``__call__``)."""
        base, residual = self.residual(observation)
        return np.asarray((base + residual)[..., 0], dtype=np.float64)

    def __repr__(self) -> str:
        return f"ResidualController({self.base!r}, scale={self.config.scale:g})"


def load_algorithm(algo: str) -> Any:
    """Import and return the Stable-Baselines3 class of ``algo`` (``"ppo"``, ``"sac"``, ``"td3"``).

    Raises
    ------
    ValueError
        For an unknown algorithm.
    ImportError
        If Stable-Baselines3 is not installed, with the command that installs it.
    """
    if algo not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algo!r}; known: {', '.join(ALGORITHMS)}")
    try:
        import stable_baselines3
    except ImportError as exc:
        raise ImportError(
            f'residual policies need Stable-Baselines3 and torch: pip install "frictiongym[rl]" '
            f"({exc})"
        ) from exc
    return getattr(stable_baselines3, ALGORITHMS[algo])
