"""The Altino's distance guard: brake before the wall, whatever the host commands.

Refusing forward commands at a distance limit is not enough: a car at speed coasts on (the
emulated Altino at 600 units stops about 8 cm after its motor is cut, and its dead time adds a
period of travel). The guard therefore predicts where the car would stop if it braked after its
reaction time, from the IR distance *d*, its change per tick (the approach speed *v*) and the
command *u* the motor is about to hold, and trips when that point reaches the limit. With the
reaction time ``T = reaction_periods * dt``, a forward command ``u > 0`` taken to accelerate
the car at ``a = max(u - FRICTION, 0) / MASS`` (the least friction the car has: a car driven
from rest gets no faster) and ``v+ = max(v, 0)``::

    stop = d - (v+ * T + a * T**2 / 2) - (v+ + a * T)**2 / (2 * BRAKE_DECELERATION)

(``stop = d`` when ``v+ = 0`` and ``u <= 0``). Each sample is judged with ``u = 0``
(:meth:`DistanceGuard.update`: braking now); every forward command is judged before the motor
holds it (:meth:`DistanceGuard.command`, with the latest sample): a car at rest near the wall
cannot be launched into it before the guard sees it move. Backing away (``u <= 0``) is never
checked. A trip brakes at full reverse while the car still approaches, holds
``min(request, 0)`` after, and stays latched (``Status.LIMIT``) until the host re-arms. The
firmware (``firmware/common/fg_device.c``), the emulator and the stock-firmware backend run
this same rule.
"""

from __future__ import annotations

import math

from frictiongym.plants.sensors import ir_estimate

#: Closest the car may come to the wall, cm. Assumed (docs/hardware.md): above the IR sensor's
#: nearest reading (966 / (800 + 45) = 1.14 cm) and below the closest approach of the paper's
#: gains in our model (the Ki = 20 PID overshoots to 1.9 cm), so the guard never acts on them.
LIMIT_CM = 1.5
#: Deceleration assumed when predicting the stop, cm/s². Assumed, conservative: full reverse
#: gives (1000 + 150) / 2.2 = 523 cm/s² in our model (docs/altino-model.md); 300 is 0.3 g.
BRAKE_DECELERATION = 300.0
#: Effective mass of the car, command units·s²/cm: ``presets.ALTINO_PLANT.inertia``, assumed
#: in docs/altino-model.md (plausible range 1.1-5.5).
MASS = 2.2
#: Friction a forward command must overcome, units: the paper's forward Coulomb level
#: (``ALTINO_PAPER.uc_pos``, Fig. 10(b)), the least friction of a moving car in our model, so
#: ``max(u - FRICTION, 0) / MASS`` bounds the acceleration from above. Taking no friction at all
#: would trip the guard on the paper's Ki = 20 PID, which creeps to 1.9 cm pushing about +200
#: (just under break-away); on a surface with less friction than the paper's, lower it.
FRICTION = 150.4
#: Periods of travel before a brake acts: one to see the car move, one of dead time.
REACTION_PERIODS = 2
#: Approach speed above which the tripped guard keeps braking, cm/s (one IR count at 5 cm per
#: 50 ms period is 0.5 cm/s: below that the car is taken as stopped).
STOPPED_SPEED = 0.5


def readout_distance(readout: float) -> float | None:
    """Distance (cm) an IR readout stands for (paper Eq. (1)); None when out of range (0)."""
    return float(ir_estimate(readout)) if readout > 0 else None


def stopping_point(
    distance: float,
    speed: float,
    dt: float,
    reaction_periods: int = REACTION_PERIODS,
    command: float = 0.0,
) -> float:
    """Where a car stops if it holds ``command`` over the reaction time, then brakes.

    Parameters
    ----------
    distance : float
        Distance to the wall now, cm.
    speed : float
        Approach speed, cm/s (toward the wall > 0; a receding car counts as at rest).
    dt : float
        Sample period, s.
    reaction_periods : int, default REACTION_PERIODS
        Periods the command is held before a brake acts.
    command : float, default 0.0
        Command held until then, units; only a forward one counts, as
        ``max(command - FRICTION, 0) / MASS`` of acceleration.

    Returns
    -------
    float
        The predicted stopping distance from the wall, cm (``distance`` for a car at rest or
        receding that is not driven forward).
    """
    accel = max(command - FRICTION, 0.0) / MASS
    if speed <= 0.0 and accel == 0.0:
        return distance
    v = max(speed, 0.0)
    reaction = reaction_periods * dt
    travel = v * reaction + 0.5 * accel * reaction * reaction
    v_end = v + accel * reaction
    return distance - travel - v_end * v_end / (2.0 * BRAKE_DECELERATION)


class DistanceGuard:
    """The guard's state for one car sampled every ``dt`` seconds.

    ``reaction_periods``: periods of travel before a brake acts (one more on a link whose
    replies lag a period, as the stock firmware's).

    Call :meth:`update` with every IR readout, then :meth:`command` with the command the motor
    is to hold next (the newest request): it checks a forward one and returns what the motor
    may get.
    """

    def __init__(
        self,
        dt: float,
        command_limit: float = 1000.0,
        limit_cm: float = LIMIT_CM,
        reaction_periods: int = REACTION_PERIODS,
    ) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        self.dt = dt
        self.brake = -abs(command_limit)
        self.limit_cm = limit_cm
        self.reaction_periods = reaction_periods
        self.tripped = False
        self.speed = 0.0  #: approach speed, cm/s (positive toward the wall)
        self._distance: float | None = None

    def rearm(self) -> bool:
        """Clear the trip (the host re-armed the device); return whether it trips again at once.

        The latest sample is judged again: a car still within the limit, or approaching too fast
        to stop short of it, stays tripped.
        """
        self.tripped = self._distance is not None and self._trips(self._distance)
        return self.tripped

    def _trips(self, distance: float, command: float = 0.0) -> bool:
        stop = stopping_point(distance, self.speed, self.dt, self.reaction_periods, command)
        return stop <= self.limit_cm

    def update(self, readout: float) -> bool:
        """Take one readout; return whether the guard is tripped."""
        distance = readout_distance(readout)
        if distance is None or self._distance is None:
            self.speed = 0.0
        else:
            self.speed = (self._distance - distance) / self.dt
        self._distance = distance
        if distance is not None:
            self.tripped |= self._trips(distance)
        return self.tripped

    def command(self, requested: float) -> float:
        """Return what the motor may hold next: the request, or a brake and then zero once tripped.

        A forward request (> 0) is judged first, held over the reaction time from the latest
        sample: if the car would then not stop short of the limit, the guard trips (latched)
        and the request is refused at once. Without a sample (none yet, or out of range) it
        passes.
        """
        if not self.tripped and requested > 0.0 and self._distance is not None:
            self.tripped = self._trips(self._distance, requested)
        if not self.tripped:
            return requested
        return self.brake if self.speed > STOPPED_SPEED else min(requested, 0.0)
