"""Model-based friction compensation in the velocity loop (the paper's compensator).

The paper adds the modelled nonlinear friction, stiction and Coulomb, at the measured
velocity to the command of the PID: if the model is right, the plant seen by the PID is the
nominal linear one. The sign of friction is undefined at rest, and what the compensator does
there decides whether it removes the steady-state error or drives a limit cycle; the
variants below are the usual answers (docs/controllers.md compares them).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from frictiongym._validation import real_number
from frictiongym.controllers.base import Controller, FloatArray
from frictiongym.controllers.pid import PID, PIDGains
from frictiongym.devices import device_of
from frictiongym.friction import FrictionModel
from frictiongym.params import DeviceParams, resolve_params

#: What the compensator does at (near) zero velocity.
Mode = Literal["command", "error", "deadband", "smooth"]
MODES: tuple[Mode, ...] = ("command", "error", "deadband", "smooth")


class FrictionCompensator(Controller):
    """Any controller plus the modelled stiction/Coulomb friction at the measured velocity.

    Above the rest speed ``|v| > v_rest`` it adds ``F_nl(v)``, the model's friction without its
    viscous part (the paper's velocity-loop compensator; the viscous part is the nominal
    plant's damping, which the base controller was tuned for). At rest, by ``mode``:

    ``"command"``
        the break-away level ``u_s`` in the direction of the base controller's command: it
        helps the command break the body free as soon as it asks to move (chatters between
        ``±u_s`` when that command hovers around zero);
    ``"error"``
        the break-away level in the direction that reduces the tracking error: it pushes
        toward the reference until the body moves (overshoots if the model is too strong);
    ``"deadband"``
        nothing: only sliding friction is compensated, the integral of the base controller
        breaks the body free (no chatter, but a slower final approach);
    ``"smooth"``
        no rest band: ``|F_nl(v)| tanh(v / v_smooth)``, a continuous compensation that fades
        out at rest.

    Parameters
    ----------
    base : Controller
        The controller to compensate (its :class:`LoopSpec` is shared).
    model : FrictionModel, DeviceParams, str or PathLike, optional
        The compensator's friction model: a law, identified parameters (their ``friction``), or
        the path of a ``friction.json`` (or of its directory). By default the spec's: the env's
        ``params`` file if it was made with one, else the device's paper preset. Only the
        stiction/Coulomb part is used (:meth:`FrictionModel.nonlinear_force`), so a fitted
        viscous slope is never compensated twice. A model different from the plant's is a
        structural mismatch.
    mode : {"command", "error", "deadband", "smooth"}, default "command"
    rest_speed : float, optional
        ``v_rest``, output units per s; the spec's (the device's) by default.
    smoothing : float, optional
        ``v_smooth`` of ``mode="smooth"``; ``rest_speed`` by default.
    scale : float, default 1.0
        Model mismatch in level: every break-away and Coulomb level of ``model`` is
        multiplied by it (1.2: friction over-estimated by 20 %).
    dead_zone : float, optional
        The modelled half-width ``d`` of an actuator dead zone, command units (the env's
        ``deadzone=``): the compensated command ``u`` is sent as ``u + d sign(u)``, the dead
        zone's inverse (Tao and Kokotovic 1996), so that the plant is driven by ``u``. By
        default the model file's ``dead_zone`` (a file from ``frictiongym identify
        --dead-zone``; with no ``model``, the env's file, :attr:`LoopSpec.dead_zone`), else 0.
    """

    def __init__(
        self,
        base: Controller,
        model: FrictionModel | DeviceParams | str | os.PathLike[str] | None = None,
        *,
        mode: Mode = "command",
        rest_speed: float | None = None,
        smoothing: float | None = None,
        scale: float = 1.0,
        dead_zone: float | None = None,
    ) -> None:
        spec = base.spec
        if spec.velocity is None:
            raise ValueError(
                "friction compensation needs a velocity entry in the observation; the "
                "controller's LoopSpec has none"
            )
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
        zone = 0.0  # the model's dead zone: its levels are the friction's own below it
        if model is None:
            model, zone = spec.friction, spec.dead_zone
        elif not isinstance(model, FrictionModel):
            params = resolve_params(model)
            if None not in (params.device, spec.device) and params.device != spec.device:
                raise ValueError(
                    f"model {model!r} was identified on {params.device}, but the loop runs on "
                    f"{spec.device}: give the friction.json of this device"
                )
            model, zone = params.friction, params.dead_zone or 0.0
        if model is None:
            raise ValueError(
                "no friction model: pass model=..., or build the base controller for a "
                "frictiongym env (LoopSpec.friction)"
            )
        rest = (
            spec.rest_speed if rest_speed is None else real_number("rest_speed", rest_speed, ">= 0")
        )
        smooth = rest if smoothing is None else real_number("smoothing", smoothing)
        if mode == "smooth" and not smooth > 0.0:
            raise ValueError(f"mode='smooth' needs smoothing > 0, got {smooth!r}")
        self.spec = spec
        self.base = base
        self.model = model.scaled(scale) if scale != 1.0 else model
        self.mode: Mode = mode
        self.rest_speed = rest
        self.smoothing = smooth
        self.scale = float(scale)
        self.dead_zone = zone if dead_zone is None else real_number("dead_zone", dead_zone, ">= 0")
        if self.dead_zone >= spec.limit:
            raise ValueError(
                f"dead_zone={self.dead_zone!r} reaches the command limit {spec.limit:g}: no "
                "command would drive the plant; check the value (or the model file's) and units"
            )

    @classmethod
    def for_env(  # its base, not a LoopSpec, follows the env
        cls,
        env: Any,
        base: Controller | PIDGains | Mapping[str, float] | None = None,
        model: FrictionModel | DeviceParams | str | os.PathLike[str] | None = None,
        **kwargs: Any,
    ) -> FrictionCompensator:
        """Build the compensator for ``env`` (its friction model by default) around ``base``.

        ``base`` is a controller, or the gains (``kp``, ``ki``, ``kd``) of a PID built for
        ``env``; by default the paper's compensated PID of the env's device. ``model`` and
        ``kwargs`` are the class's.
        """
        if not isinstance(base, Controller):
            gains = device_of(env).paper_gains["compensated"] if base is None else base
            base = PID.for_env(env, gains if isinstance(gains, PIDGains) else PIDGains(**gains))
        return cls(base, model, **kwargs)

    def reset(self, mask: npt.ArrayLike | None = None) -> None:  # noqa: D102
        self.base.reset(mask)

    def compensation(self, observation: npt.ArrayLike, base_command: npt.ArrayLike) -> FloatArray:
        """Return the command added to ``base_command`` for ``observation`` (command units)."""
        reference, output, rate = self.spec.split(observation)
        direction = self.spec.direction
        v = direction * rate  # the plant's velocity: positive where a positive command drives
        if self.mode == "smooth":
            # |F_nl(v)| is 0 at v = 0 exactly, where tanh is 0 too: continuous and odd.
            magnitude = np.abs(self.model.nonlinear_force(v))
            return np.asarray(magnitude * np.tanh(v / self.smoothing), dtype=np.float64)
        sliding = np.where(np.abs(v) > self.rest_speed, self.model.nonlinear_force(v), 0.0)
        if self.mode == "deadband":
            return np.asarray(sliding, dtype=np.float64)
        toward = base_command if self.mode == "command" else direction * (reference - output)
        push = np.sign(toward)
        us_pos, us_neg = self.model.breakaway
        at_rest = np.where(push > 0.0, us_pos, np.where(push < 0.0, -us_neg, 0.0))
        return np.asarray(np.where(np.abs(v) > self.rest_speed, sliding, at_rest), dtype=np.float64)

    def command(self, observation: FloatArray) -> FloatArray:  # noqa: D102
        u = self.base.command(observation)
        compensated = np.asarray(u + self.compensation(observation, u), dtype=np.float64)
        if self.dead_zone:  # the zone's inverse: the plant is then driven by `compensated`
            compensated = compensated + self.dead_zone * np.sign(compensated)
        return compensated

    def __repr__(self) -> str:
        mismatch = f", scale={self.scale:g}" if self.scale != 1.0 else ""
        zone = f", dead_zone={self.dead_zone:g}" if self.dead_zone else ""
        return f"FrictionCompensator({self.base!r}, mode={self.mode!r}{mismatch}{zone})"
