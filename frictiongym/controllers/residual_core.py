"""What a residual policy sees and what it may add: one definition for training and control.

:class:`~frictiongym.residual.ResidualEnv` (training) and
:class:`~frictiongym.controllers.residual.ResidualController` (control) both call
:func:`residual_observation` and :func:`bounded_residual`, so a policy is run on exactly the
inputs it was trained on, and its output is bounded the same way in both.

No torch here: this module is imported by ``frictiongym.controllers``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym import devices
from frictiongym._validation import check_positive
from frictiongym.controllers.base import Controller, FloatArray, LoopSpec
from frictiongym.controllers.compensation import FrictionCompensator
from frictiongym.controllers.pid import PID, PIDGains

#: Number of entries of :func:`residual_observation`.
OBSERVATION_SIZE = 6
#: Names of the entries of :func:`residual_observation`.
OBSERVATION_NAMES = ("error", "fine_error", "rate", "reference", "base_action", "at_rest")
#: Bound of every observation entry (the linear ones are clipped to it).
OBSERVATION_BOUND = 10.0


@dataclass(frozen=True)
class ResidualConfig:
    """The observation normalisation and the residual bound of a residual policy.

    Saved with a trained model (``frictiongym train``), so the controller that loads it
    rebuilds the same observation and the same bound.

    Parameters
    ----------
    device : str
        The device it was made for: ``"RotaryServo"`` or ``"AltinoDistance"``.
    limit : float
        The env's action limit (10 V, 1000 motor units); the applied action is saturated at it.
    scale : float
        The residual bound, in action units: the residual is ``scale * clip(a, -1, 1)``.
    error_scale : float
        Error of value 1 in the ``error`` entry (the env's reward unit: 1 rad, 5 cm).
    fine_error : float
        Scale of the ``fine_error`` entry ``tanh(e / fine_error)``: it resolves the small
        errors that friction leaves, which the ``error`` entry shows as about 1e-3.
    velocity_scale : float
        Rate of value 1 in the ``rate`` entry (rad/s, cm/s).
    reference_scale, reference_offset : float
        ``reference`` entry: ``(r - reference_offset) / reference_scale``.
    """

    device: str
    limit: float
    scale: float
    error_scale: float
    fine_error: float
    velocity_scale: float
    reference_scale: float
    reference_offset: float = 0.0

    def __post_init__(self) -> None:
        names = ("limit", "scale", "error_scale", "fine_error", "velocity_scale", "reference_scale")
        check_positive(self, *names)
        if self.scale > self.limit:
            raise ValueError(
                f"ResidualConfig.scale={self.scale!r} exceeds the action limit {self.limit!r}: "
                "a residual bound is a fraction of the limit (give scale <= limit)"
            )

    @classmethod
    def for_device(cls, device: str, scale: float | None = None) -> ResidualConfig:
        """Return the default configuration of ``device``, with the residual bound ``scale``.

        ``device`` is any spelling :func:`frictiongym.devices.get` takes. ``scale`` is in
        action units; by default the device's (``Device.residual``: servo 1 V, Altino 200
        motor units).
        """
        described = devices.get(device)
        limit = described.plant.command_limit
        config = cls(device=described.name, limit=limit, **described.residual)
        return config if scale is None else replace(config, scale=float(scale))

    @classmethod
    def for_env(cls, env: Any, scale: float | None = None) -> ResidualConfig:
        """Return the default configuration of an env's device (see :meth:`for_device`)."""
        config = cls.for_device(devices.device_of(env).name, scale)
        limit = LoopSpec.from_env(env).limit
        if limit != config.limit:  # e.g. a device with another amplifier limit
            fraction = config.scale / config.limit
            config = replace(
                config, limit=limit, scale=fraction * limit if scale is None else float(scale)
            )
        return config

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ResidualConfig:
        """Rebuild a configuration from :meth:`to_dict`'s output."""
        return cls(**dict(data))

    def to_dict(self) -> dict[str, Any]:
        """Return the configuration as a JSON-serialisable dict."""
        return asdict(self)


def residual_observation(
    observation: npt.ArrayLike,
    spec: LoopSpec,
    base_action: npt.ArrayLike,
    config: ResidualConfig,
) -> npt.NDArray[np.float32]:
    """Return the residual policy's observation for an observation ``(k,)`` or ``(N, k)``.

    With ``e = r - y`` and ``s = spec.direction`` (``-1`` for the Altino), the entries are:

    ========== =============================================== =========================
    entry      value                                           range
    ========== =============================================== =========================
    error      ``s e / error_scale``                           clipped to ±10
    fine_error ``tanh(s e / fine_error)``                      ±1
    rate       ``s y' / velocity_scale``                       clipped to ±10
    reference  ``(r - reference_offset) / reference_scale``    clipped to ±10
    base_action base controller's action ``/ limit``           ±1
    at_rest    1 if ``|y'| <= spec.rest_speed`` else 0          0 or 1
    ========== =============================================== =========================

    Multiplying by ``s`` gives the error and rate the sign of the command that increases
    them, so the entries mean the same on both devices. A missing or NaN rate counts as 0.

    Returns
    -------
    numpy.ndarray
        float32, shape ``(6,)`` or ``(N, 6)``.
    """
    reference, output, rate = spec.split(observation)
    rate = np.nan_to_num(rate, nan=0.0)
    s = spec.direction
    error = s * (reference - output)
    u = np.asarray(base_action, dtype=np.float64).reshape(output.shape)
    b = OBSERVATION_BOUND
    features = np.stack(
        [
            np.clip(error / config.error_scale, -b, b),
            np.tanh(error / config.fine_error),
            np.clip(s * rate / config.velocity_scale, -b, b),
            np.clip((reference - config.reference_offset) / config.reference_scale, -b, b),
            np.clip(u / config.limit, -1.0, 1.0),
            (np.abs(rate) <= spec.rest_speed).astype(np.float64),
        ],
        axis=-1,
    )
    return np.nan_to_num(features, nan=0.0).astype(np.float32)


def bounded_residual(action: npt.ArrayLike, scale: float) -> FloatArray:
    """``scale * clip(action, -1, 1)``: the residual, bounded whatever the policy outputs.

    NaN entries count as 0 (no residual) and infinities as ±1, so a broken policy can never
    add more than ``scale`` to the base controller's action.
    """
    a = np.nan_to_num(np.asarray(action, dtype=np.float64), nan=0.0, posinf=1.0, neginf=-1.0)
    return np.asarray(scale * np.clip(a, -1.0, 1.0), dtype=np.float64)


#: Base controllers :func:`make_base` builds by name.
BASES = ("compensated", "pid")


def make_base(
    env: Any, kind: str = "compensated", gains: Mapping[str, float] | None = None
) -> Controller:
    """Build a base controller for ``env``: the paper's PID, friction-compensated by default.

    Parameters
    ----------
    env : gymnasium.Env
        A frictiongym env (simulated or on a device backend).
    kind : {"compensated", "pid"}
        ``FrictionCompensator(PID)`` with the compensator's defaults (the device's paper
        friction model, ``mode="command"``), or the PID alone.
    gains : mapping, optional
        ``kp``, ``ki``, ``kd``; by default the paper's for the device's compensated PID
        (``Device.paper_gains["compensated"]``).
    """
    if kind not in BASES:
        raise ValueError(f"base controller must be one of {BASES}, got {kind!r}")
    pid = PID.for_env(env, PIDGains(**(gains or devices.device_of(env).paper_gains["compensated"])))
    return FrictionCompensator(pid) if kind == "compensated" else pid
