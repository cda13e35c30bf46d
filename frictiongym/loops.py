"""Closed-loop step experiments of the paper: the servo step and the Altino run to the wall.

Each builds the paper's controller for the simulated env and records one episode with
:func:`frictiongym.controllers.rollout`, so an experiment here is exactly what the benchmark
and ``rollout`` run on the same env (``tests/test_loops.py`` checks it bit for bit).
"""

from __future__ import annotations

from typing import Any, Literal

import numpy.typing as npt

from frictiongym.controllers.base import FloatArray
from frictiongym.controllers.compensation import FrictionCompensator
from frictiongym.controllers.pid import PID, PIDGains
from frictiongym.controllers.rollout import Rollout, rollout
from frictiongym.devices import ALTINO, ROTARY
from frictiongym.envs import AltinoDistanceEnv, RotaryServoEnv
from frictiongym.friction import FrictionModel
from frictiongym.plants import PlantParams


def rotary_step(
    friction: FrictionModel = ROTARY.paper_friction,
    gains: PIDGains | None = None,
    reference: float = 1.0,
    duration: float = 5.0,
    encoder: bool = True,
    plant: PlantParams = ROTARY.plant,
    dt: float = ROTARY.dt,
) -> Rollout:
    """Run the paper's servo experiment: a position step under PID, from rest at 0 rad.

    The PID sees what a QUBE user has: the encoder angle (2048 counts/rev when ``encoder``)
    and its filtered derivative ``50 s / (s + 50)`` for the D term, as the env observes them.
    Returns ``round(duration / dt) + 1`` samples.
    """
    env = RotaryServoEnv(
        friction=friction, reference=reference, quantize=encoder, plant=plant, dt=dt
    )
    pid = PID.for_env(env, gains or PIDGains(**ROTARY.paper_gains["pid"]))
    return _run(env, pid, duration, dt)


class _ErrorKickPID(PID):
    """PID whose first D term acts on the error from ``e_(-1) = 0``, as a textbook one does."""

    def reset(self, mask: npt.ArrayLike | None = None) -> None:
        super().reset(mask)
        self._kick = True

    def command(self, observation: FloatArray) -> FloatArray:
        if not self._kick:
            return super().command(observation)
        self._kick = False
        reference, output, _ = self.spec.split(observation)
        # The rate of the measurement that the error's first difference implies.
        return self.update(reference, output, (output - reference) / self.spec.dt)


def altino_step(
    gains: PIDGains,
    friction: FrictionModel = ALTINO.paper_friction,
    compensator: FrictionModel | None = None,
    start_cm: float = ALTINO.start,
    target_cm: float = ALTINO.references["step"]["value"],
    duration: float = 10.0,
    plant: PlantParams = ALTINO.plant,
    dt: float = ALTINO.dt,
    derivative: Literal["measurement", "error"] = "measurement",
    seed: int | None = 0,
) -> Rollout:
    """Run the paper's Altino experiment: drive from ``start_cm`` to ``target_cm`` from a wall.

    The PID acts on the distance error, with the distance estimated from the integer IR
    readout (paper Eq. (1)); a positive command drives toward the wall. With ``compensator``,
    the modelled stiction and Coulomb friction at the estimated velocity (backward difference
    of the estimated distance) is added to the command; at rest (estimated velocity exactly
    zero) it pushes in the direction of the PID command with the break-away level, which is
    the variant this check uses (docs/results.md compares the others).

    Parameters
    ----------
    gains : PIDGains
        PID gains in per-second form: ``kp`` units/cm, ``ki`` units/(cm·s), ``kd``
        units/(cm/s).
    friction : FrictionModel, default ``ALTINO.paper_friction``
        Friction law of the simulated car.
    compensator : FrictionModel, optional
        Friction model of the compensator; none by default.
    start_cm, target_cm : float
        Initial and target distance to the wall, cm (defaults: the device's start and step,
        30 and 5 cm).
    duration : float, default 10.0
        Simulated time, s.
    plant : PlantParams, default ``ALTINO.plant``
        Nominal plant (mass, damping, saturation, lag, dead time).
    dt : float, default ``ALTINO.dt``
        Control period, s.
    derivative : {"measurement", "error"}, default "measurement"
        Where the D term acts. ``measurement``: on the estimated distance, so it starts at
        zero (no kick). ``error``: on the error with the previous error initialised to zero,
        as a textbook ``kd * (e_k - e_(k-1)) / dt`` does, which kicks the first command by
        ``kd * e_0 / dt``; with a constant target the two differ only in that first sample.
    seed : int or None, default 0
        Seed of the env's reset: it draws only what the plant randomises (a ``jitter``'s
        stream), so it changes nothing else.

    Returns
    -------
    Rollout
        True and estimated distance, commands and stick flags, ``round(duration / dt) + 1``
        samples. If the car reaches the wall the env ends the episode there (the contact
        located inside the step): the last sample's distance is 0, its estimate the IR's
        nearest reading (readout 800, 1.14 cm), it is stuck, and ``terminated[0]`` is True.
    """
    if derivative not in ("measurement", "error"):
        raise ValueError(f"derivative must be 'measurement' or 'error', got {derivative!r}")
    env = AltinoDistanceEnv(friction=friction, reference=target_cm, plant=plant, dt=dt)
    pid = (PID if derivative == "measurement" else _ErrorKickPID).for_env(env, gains)
    # The "command" variant with an exact-zero rest band (docs/altino-model.md).
    controller = (
        pid if compensator is None else FrictionCompensator(pid, compensator, rest_speed=0.0)
    )
    return _run(env, controller, duration, dt, {"position": float(start_cm)}, seed)


def _run(
    env: Any,
    controller: Any,
    duration: float,
    dt: float,
    options: dict[str, float] | None = None,
    seed: int | None = None,
) -> Rollout:
    """Record ``duration`` s of ``controller`` on ``env`` (closed after the run)."""
    try:
        steps = max(1, round(duration / dt))
        return rollout(env, controller, steps, seed=seed, options=options)
    finally:
        env.close()
