"""Closed-loop step experiments of the paper, on the simulated plants.

Small, explicit loops (sensor → controller → plant) used by the demo, the Altino model check
and the tests. `frictiongym.controllers.rollout` runs any controller on the envs instead.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from frictiongym.controllers.base import LoopSpec
from frictiongym.controllers.compensation import FrictionCompensator
from frictiongym.controllers.pid import PID, PIDGains
from frictiongym.friction import ALTINO_PAPER, ROTARY_PAPER, FrictionModel
from frictiongym.metrics import StepMetrics, step_metrics
from frictiongym.plants import Plant, PlantParams
from frictiongym.plants.presets import (
    ALTINO_DT,
    ALTINO_PLANT,
    ALTINO_START_CM,
    ALTINO_TARGET_CM,
    ROTARY_DT,
    ROTARY_PAPER_GAINS,
    ROTARY_PLANT,
    ROTARY_VELOCITY_CUTOFF,
)
from frictiongym.plants.sensors import (
    IR_MAX_READOUT,
    QUBE_ENCODER_STEP,
    FilteredDerivative,
    ir_distance,
    ir_readout,
    quantize_angle,
)

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class StepRun:
    """A closed-loop step response: true output, measured output, command and stick flags."""

    t: FloatArray
    y: FloatArray
    measured: FloatArray
    command: FloatArray
    stuck: npt.NDArray[np.bool_]
    reference: float
    y0: float
    #: True when the run ended early because the car reached the wall (:func:`altino_step`).
    collided: bool = False

    def metrics(self) -> StepMetrics:
        """Step metrics of the true output against the reference."""
        return step_metrics(self.t, self.y, self.reference, y0=self.y0)


def rotary_step(
    friction: FrictionModel = ROTARY_PAPER,
    gains: PIDGains | None = None,
    reference: float = 1.0,
    duration: float = 5.0,
    encoder: bool = True,
    plant: PlantParams = ROTARY_PLANT,
    dt: float = ROTARY_DT,
) -> StepRun:
    """Run the paper's servo experiment: a position step under PID, from rest at 0 rad.

    The PID sees what a QUBE user has: the encoder angle (2048 counts/rev when ``encoder``)
    and its filtered derivative ``50 s / (s + 50)`` for the D term.
    """
    gains = gains or PIDGains(**ROTARY_PAPER_GAINS)
    sim = Plant(plant, friction, dt)
    pid = PID(LoopSpec(dt, plant.command_limit), gains)
    tach = FilteredDerivative(ROTARY_VELOCITY_CUTOFF, dt, resolution=QUBE_ENCODER_STEP)
    n = round(duration / dt) + 1
    t = np.arange(n, dtype=np.float64) * dt
    y, measured, command = np.empty(n), np.empty(n), np.empty(n)
    stuck = np.empty(n, dtype=bool)
    for i in range(n):
        y[i] = sim.position[0]
        stuck[i] = sim.stuck[0]
        measured[i] = quantize_angle(y[i]) if encoder else y[i]
        u = pid.update(reference, measured[i], tach.update(measured[i]))
        command[i] = float(u)
        sim.step(u)
    return StepRun(t, y, measured, command, stuck, reference, 0.0)


def altino_step(
    gains: PIDGains,
    friction: FrictionModel = ALTINO_PAPER,
    compensator: FrictionModel | None = None,
    start_cm: float = ALTINO_START_CM,
    target_cm: float = ALTINO_TARGET_CM,
    duration: float = 10.0,
    plant: PlantParams = ALTINO_PLANT,
    dt: float = ALTINO_DT,
    derivative: Literal["measurement", "error"] = "measurement",
) -> StepRun:
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
    friction : FrictionModel, default ALTINO_PAPER
        Friction law of the simulated car.
    compensator : FrictionModel, optional
        Friction model of the compensator; none by default.
    start_cm, target_cm : float
        Initial and target distance to the wall, cm (defaults: ``ALTINO_START_CM``,
        ``ALTINO_TARGET_CM``).
    duration : float, default 10.0
        Simulated time, s.
    plant : PlantParams, default ALTINO_PLANT
        Nominal plant (mass, damping, saturation, lag, dead time).
    dt : float, default ALTINO_DT
        Control period, s.
    derivative : {"measurement", "error"}, default "measurement"
        Where the D term acts. ``measurement``: on the estimated distance, so it starts at
        zero (no kick). ``error``: on the error with the previous error initialised to zero,
        as a textbook ``kd * (e_k - e_(k-1)) / dt`` does, which kicks the first command by
        ``kd * e_0 / dt``; with a constant target the two differ only in that first sample.

    Returns
    -------
    StepRun
        True and estimated distance, commands and stick flags; ``y0`` is ``start_cm``.
        If the car reaches the wall (true distance <= 0 at a sample) the run stops there:
        the arrays end with that sample, whose distance is recorded as 0 (contact), its
        estimate as the IR's nearest reading (readout 800, 1.14 cm), its command as 0 and its
        stick flag as True, and ``collided`` is True. The wall is the plant's end stop (the
        contact located inside the step, as in the env); the run ends with it.
    """
    if derivative not in ("measurement", "error"):
        raise ValueError(f"derivative must be 'measurement' or 'error', got {derivative!r}")
    sim = Plant(dataclasses.replace(plant, end_stop=start_cm), friction, dt)  # the wall
    # Observation layout of the loop: [estimated distance, its rate, target].
    spec = LoopSpec(dt, plant.command_limit, position=0, velocity=1, reference=2, direction=-1.0)
    pid = PID(spec, gains, derivative="difference")
    # The "command" variant with an exact-zero rest band (docs/altino-model.md).
    comp = None if compensator is None else FrictionCompensator(pid, compensator, rest_speed=0.0)
    n = round(duration / dt) + 1
    t = np.arange(n, dtype=np.float64) * dt
    y, measured, command = np.empty(n), np.empty(n), np.empty(n)
    stuck = np.empty(n, dtype=bool)
    previous = None
    for i in range(n):
        y[i] = start_cm - sim.position[0]
        if y[i] <= 0.0:  # touched the wall: record the contact and stop
            y[i], command[i], stuck[i] = 0.0, 0.0, True
            measured[i] = float(ir_distance(IR_MAX_READOUT))
            m = i + 1
            return StepRun(t[:m], y[:m], measured[:m], command[:m], stuck[:m], target_cm,
                           start_cm, collided=True)  # fmt: skip
        stuck[i] = sim.stuck[0]
        measured[i] = float(ir_distance(ir_readout(y[i])))
        # The PID's rate is that of the measurement; a derivative on the error from e_(-1) = 0
        # sees the rate -(e_0 - 0) / dt = (y_0 - r) / dt on the first sample.
        kick = (measured[i] - target_cm) / dt if derivative == "error" and i == 0 else None
        u = float(pid.update(target_cm, measured[i], kick))
        if comp is not None:
            rate = 0.0 if previous is None else (measured[i] - previous) / dt
            u += float(comp.compensation(np.array([measured[i], rate, target_cm]), u))
        previous = measured[i]
        command[i] = u
        sim.step(u)
    return StepRun(t, y, measured, command, stuck, target_cm, start_cm)
