"""The Altino's distance guard: brake before the wall, whatever the host commands.

Refusing forward commands at a distance limit is not enough: a car at speed coasts on, and its
dead time adds a period of travel. The guard therefore predicts where the car would stop if it
braked after its reaction time and trips when that point reaches the limit. What it cannot
measure it bounds (:class:`CarBounds`): the mass lies anywhere in the documented plausible
range, the friction is at least the least the device's law allows. With ``T =
reaction_periods * dt``, the approach speed *v* and the command *u* the motor may hold until
the brake acts::

    a(u, v) = (u - FRICTION - VISCOUS v) / M
    travel  = min(v T + a(u, v) T^2 / 2, max(v, v_top(u)) T),  v_T = min(v + a T, v_top(u))
    stop    = d - travel - M v_T^2 / (2 K + VISCOUS v_T),  K = limit + FRICTION

the nearer for ``M = MASS_MIN`` and ``M = MASS_MAX`` (both terms are convex in the mass: an
end of the range is the worst). A car that does not accelerate travels at most ``v T``; the
last term bounds the distance full reverse needs to stop the car, the viscous force taken at
the mean speed of the stop (it overestimates). The speed *v*:

* two readings in the IR range: their difference over ``dt`` (the mean speed over the
  period), plus half a count of each reading's quantization and the half period of
  acceleration the car may have had since the mean (at most the bound below); whether a
  tripped guard brakes is decided on the difference alone;
* the first reading in range, or none (out of range): :attr:`DistanceGuard.bound`, an upper
  bound on the speed the car can have, integrated every period from the commands the motor
  held (the largest of the last ``reaction_periods``, for the dead time) with the same bounds.
  Out of range the distance is unknown but at least :data:`EDGE_CM`, and the car may enter the
  range just after a sample and be seen a period later: it is judged at ``EDGE_CM`` with one
  period more of reaction. So a forward command that could take the car faster than it can
  stop from the edge of the range is refused before the car is seen at all.

Each sample is judged with the command already on its way (:meth:`DistanceGuard.update`);
every forward command before the motor holds it (:meth:`DistanceGuard.command`). A trip brakes
at full reverse while the car still approaches (two readings in range say it moves, or the
first reading's bound does; blind, out of range, it does not brake), holds ``min(request, 0)``
after, and stays latched (``Status.LIMIT``) until the host re-arms. Until the first sample
forward commands are refused (nothing is known of the distance yet). The firmware
(``firmware/common/fg_device.c``), the emulator and the stock-firmware backend run this same
rule.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from frictiongym._validation import check_nonnegative, check_positive, real_number
from frictiongym.plants.sensors import IR_NUMERATOR, IR_OFFSET, ir_estimate

#: Closest the car may come to the wall, cm. Assumed (docs/hardware.md): above the IR sensor's
#: nearest reading (966 / (800 + 45) = 1.14 cm) and below the closest approach of the paper's
#: gains in our model (the Ki = 20 PID overshoots to 1.9 cm), so the guard never acts on them.
LIMIT_CM = 1.5
#: Plausible range of the car's effective mass, command units·s²/cm (docs/altino-model.md: the
#: assumed 2.2 of ``presets.ALTINO_PLANT.inertia``, plausible 1.1-5.5, a mechanical time
#: constant of 0.1-0.5 s). Not measured on any car: the guard takes the worst of the range.
MASS_MIN = 1.1
MASS_MAX = 5.5
#: Least friction resisting a forward-moving car, units: the paper's forward Coulomb level
#: (``ALTINO_PAPER.uc_pos``, Fig. 10(b)); stiction only adds to it. The default of a car whose
#: law is unknown (the stock backend); the emulator takes it from its own law
#: (:meth:`CarBounds.from_law`).
FRICTION = 150.4
#: Least viscous slope, units/(cm/s): the paper's (``ALTINO_PAPER.viscous``, Fig. 10(b); the
#: model's plant damping ``ALTINO_PLANT.damping`` is 0).
VISCOUS = 10.93
#: Periods of travel before a brake acts: one to see the car move, one of dead time.
REACTION_PERIODS = 2
#: Approach speed above which the tripped guard keeps braking, cm/s (one IR count at 5 cm per
#: 50 ms period is 0.5 cm/s: below that the car is taken as stopped).
STOPPED_SPEED = 0.5
#: Largest IR readout noise assumed, counts: 4 standard deviations of the model's 2 counts
#: (``AltinoEnv``'s ``sensor_noise``; docs/altino-model.md gives none for the car).
IR_NOISE_COUNTS = 8.0
#: Nearest distance a car out of the IR range (readout 0) can be at, cm: the readout is
#: ``round(966 / d - 45)`` (paper Eq. (1)), 0 only for ``d >= 966 / 45.5``.
EDGE_CM = IR_NUMERATOR / (IR_OFFSET + 0.5)


def readout_jump_possible(
    previous: float, readout: float, travel_cm: float, noise_counts: float = 0.0
) -> bool:
    """Whether the IR readout can go from ``previous`` to ``readout``, the car moving ``travel_cm``.

    One count of quantization is allowed on top, that of the farther (coarser) reading, and
    ``noise_counts`` of sensor noise at each reading; a readout of 0 (out of range) stands for
    "at least :data:`EDGE_CM`".
    """
    far_readout, near_readout = sorted((previous, readout))  # the larger readout is nearer
    nearest_far = float(ir_estimate(max(far_readout, 0.0) + 1.0 + noise_counts))
    if near_readout - noise_counts < 1.0:
        return True  # the nearer reading may stand for any distance out to the range's edge
    farthest_near = float(ir_estimate(near_readout - noise_counts))
    return nearest_far - farthest_near <= travel_cm


def _count(distance: float) -> float:
    """Distance one IR count spans at ``distance`` cm (Eq. (1): d² / (966 + d))."""
    return distance * distance / (IR_NUMERATOR + distance)


@dataclass(frozen=True)
class CarBounds:
    """What the guard assumes of a car it cannot weigh: bounds that hold for every plausible car.

    Parameters
    ----------
    mass_min, mass_max : float, default MASS_MIN, MASS_MAX
        Range of the effective mass, units·s²/cm: the lightest accelerates fastest, the
        heaviest brakes slowest.
    friction : float, default FRICTION
        Least Coulomb friction against a forward-moving car, units (0: none).
    viscous : float, default VISCOUS
        Least viscous slope, units/(cm/s) (0: none; then the car has no top speed).
    command_limit : float, default 1000.0
        Full command, units: the brake is full reverse.
    noise_counts : float, default IR_NOISE_COUNTS
        Largest IR readout noise the checks of a readout allow, counts.
    """

    mass_min: float = MASS_MIN
    mass_max: float = MASS_MAX
    friction: float = FRICTION
    viscous: float = VISCOUS
    command_limit: float = 1000.0
    noise_counts: float = IR_NOISE_COUNTS

    def __post_init__(self) -> None:
        check_positive(self, "mass_min", "mass_max", "command_limit")
        check_nonnegative(self, "friction", "viscous", "noise_counts", hint=lambda *_: " (0: none)")
        if self.mass_min > self.mass_max:
            raise ValueError(
                f"mass_min ({self.mass_min}) must not exceed mass_max ({self.mass_max})"
            )

    @classmethod
    def from_law(
        cls,
        law: object,
        damping: float = 0.0,
        inertia: float | None = None,
        command_limit: float = 1000.0,
    ) -> CarBounds:
        """Bounds of a car with friction ``law`` (a FrictionModel) and plant ``damping``.

        Least friction: the forward Coulomb level (``uc_pos``) of a static law, 0 for no
        friction and for LuGre (its bristles can pull forward for a moment); least viscous
        slope: the law's ``viscous`` plus ``damping``. The mass range is the documented one,
        widened to hold ``inertia`` (an identified or emulated mass outside it).
        """
        lugre = type(law).__name__ == "LuGre"
        friction = 0.0 if lugre else float(getattr(law, "uc_pos", 0.0))
        viscous = float(getattr(law, "viscous", 0.0)) + float(damping)
        low, high = MASS_MIN, MASS_MAX
        if inertia is not None:
            low, high = min(low, inertia), max(high, inertia)
        return cls(low, high, friction, viscous, command_limit)

    def accel(self, command: float, speed: float, mass: float | None = None) -> float:
        """Acceleration toward the wall at ``speed`` (>= 0) holding ``command``.

        Of a car of ``mass``; by default the largest of any plausible car.
        """
        net = command - self.friction - self.viscous * speed
        if mass is None:
            mass = self.mass_min if net > 0.0 else self.mass_max
        return net / mass

    def top_speed(self, command: float) -> float:
        """Speed at which ``command`` no longer accelerates the car (inf without viscous)."""
        net = command - self.friction
        if net <= 0.0:
            return 0.0
        return net / self.viscous if self.viscous > 0.0 else math.inf

    def advance(self, speed: float, command: float, seconds: float) -> float:
        """Upper bound of the approach speed after holding ``command`` for ``seconds``.

        Accelerating: a forward Euler step capped at the top speed (the acceleration only
        falls as the car speeds up). Slowing: an implicit Euler step (the exact decay is
        faster). Never below 0: a car that stops is taken as at rest.
        """
        speed = max(speed, 0.0)
        a = self.accel(command, speed)
        if a > 0.0:
            return min(speed + a * seconds, max(self.top_speed(command), speed))
        net = command - self.friction
        slowed = (speed + net * seconds / self.mass_max) / (
            1.0 + self.viscous * seconds / self.mass_max
        )
        return max(slowed, 0.0)

    def braking_distance(self, speed: float, mass: float | None = None) -> float:
        """Upper bound of the distance full reverse needs to stop a car of ``mass``, cm.

        From ``speed``, the viscous force taken at the mean speed of the stop (the force only
        falls as the car slows, so this overestimates). Default: the heaviest car.
        """
        if speed <= 0.0:
            return 0.0
        force = self.command_limit + self.friction
        mass = self.mass_max if mass is None else mass
        return mass * speed * speed / (2.0 * force + self.viscous * speed)


#: The bounds of the Altino model with the paper's friction law (the defaults above).
PAPER_CAR = CarBounds()


def stopping_point(
    distance: float,
    speed: float,
    dt: float,
    reaction_periods: int = REACTION_PERIODS,
    command: float = 0.0,
    car: CarBounds = PAPER_CAR,
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
        Command held until then, units.
    car : CarBounds, default PAPER_CAR
        The bounds of mass and friction the prediction must hold for.

    Returns
    -------
    float
        The predicted stopping distance from the wall, cm (``distance`` for a car at rest or
        receding that is not driven forward): the nearer of the lightest car's and the
        heaviest's (travel and braking distance are convex in the mass, so one of the two
        ends of its range is the worst).
    """
    t = reaction_periods * dt
    stops = []
    for mass in (car.mass_min, car.mass_max):
        v = max(speed, 0.0)
        a = car.accel(command, v, mass)
        if a > 0.0:
            top = max(car.top_speed(command), v)
            travel = min(v * t + 0.5 * a * t * t, top * t)
            v = min(v + a * t, top)
        else:
            travel = v * t
        stops.append(distance - travel - car.braking_distance(v, mass))
    return min(stops)


class DistanceGuard:
    """The guard's state for one car sampled every ``dt`` seconds.

    ``reaction_periods``: periods of travel before a brake acts (one more on a link whose
    replies lag a period, as the stock firmware's); ``car``: the bounds it assumes
    (default: :data:`PAPER_CAR` with ``command_limit``).

    Call :meth:`update` with every IR readout and the command the motor held over the period
    that ended, then :meth:`command` with the command the motor is to hold next (the newest
    request): it checks a forward one and returns what the motor may get.
    """

    def __init__(
        self,
        dt: float,
        command_limit: float = 1000.0,
        limit_cm: float = LIMIT_CM,
        reaction_periods: int = REACTION_PERIODS,
        car: CarBounds | None = None,
    ) -> None:
        self.dt = real_number("dt", dt, "> 0", unit=" s")
        self.car = CarBounds(command_limit=abs(command_limit)) if car is None else car
        self.brake = -abs(command_limit)
        self.limit_cm = limit_cm
        self.reaction_periods = reaction_periods
        self.tripped = False
        self.speed = 0.0  #: approach speed judged, cm/s (positive toward the wall)
        self.measured = 0.0  #: approach speed the readings show (the bound before two), cm/s
        self.bound = 0.0  #: upper bound of the approach speed, cm/s (the car starts at rest)
        self.sampled = False  #: a readout has come (before it, forward is refused)
        #: Commands held over the last periods: those a car with dead time may still feel.
        self._held: deque[float] = deque([0.0], maxlen=max(reaction_periods, 1))
        self._distance: float | None = None

    def rearm(self) -> bool:
        """Clear the trip (the host re-armed the device); return whether it trips again at once.

        The latest sample is judged again: a car still within the limit, or approaching too fast
        to stop short of it, stays tripped.
        """
        self.tripped = self.sampled and self._trips(0.0)
        return self.tripped

    def predicted_stop(self, command: float = 0.0) -> float:
        """Where the guard predicts the car stops if the motor holds ``command``, cm.

        From the latest sample (out of range: from :data:`EDGE_CM`, a period later), with the
        larger of ``command`` and the commands already on their way (the dead time).
        """
        command = max(command, *self._held)
        if self._distance is None:  # out of range: at the edge at worst, seen a period late
            distance, speed, periods = EDGE_CM, self.bound, self.reaction_periods + 1
        else:
            distance, speed, periods = self._distance, self.speed, self.reaction_periods
        return stopping_point(distance, speed, self.dt, periods, command, self.car)

    def _trips(self, command: float) -> bool:
        return self.predicted_stop(command) <= self.limit_cm

    def update(self, readout: float, held: float = 0.0) -> bool:
        """Take one readout and the command held over the period it ends; return whether tripped."""
        self._held.append(held)
        self.bound = self.car.advance(self.bound, max(self._held), self.dt)
        distance = float(ir_estimate(readout)) if readout > 0 else None  # None: out of range
        if distance is None or self._distance is None:
            self.speed = self.measured = self.bound  # no two readings: the fastest it can be
        else:
            self.measured = (self._distance - distance) / self.dt
            self.speed = self._now_at_most(self._distance, distance)
        self._distance = distance
        self.sampled = True
        self.tripped |= self._trips(0.0)
        return self.tripped

    def _now_at_most(self, before: float, now: float) -> float:
        """Return the fastest the car can be now, from two readings ``before`` and ``now`` (cm).

        Their difference is the mean speed over the period, off by up to half a count at each
        reading; the car may have gained half a period of acceleration since the mean. Never
        above the bound, unless the readings themselves are.
        """
        half_counts = (0.5 + self.car.noise_counts) * (_count(before) + _count(now)) / self.dt
        gain = max(self.car.accel(max(self._held), max(self.measured, 0.0)), 0.0) * self.dt / 2
        return max(self.measured, min(self.bound, self.measured + half_counts + gain))

    def may_approach(self) -> bool:
        """Whether the car may still approach the wall.

        Out of range: by the speed bound. In range: the readings say it moves, or a command
        that can move it (beyond the least friction) is still on its way (the dead time).
        """
        if self._distance is None:
            return self.bound > STOPPED_SPEED
        pushed = max(self._held) > self.car.friction
        return self.measured > STOPPED_SPEED or pushed

    def command(self, requested: float) -> float:
        """Return what the motor may hold next: the request, or a brake and then zero once tripped.

        A forward request (> 0) is judged first, held over the reaction time from the latest
        sample: if the car would then not stop short of the limit, the guard trips (latched)
        and the request is refused at once. Before any sample it is refused (not latched).
        """
        if not self.sampled:
            return min(requested, 0.0)
        if not self.tripped and requested > 0.0:
            self.tripped = self._trips(requested)
        if not self.tripped:
            return requested
        approaching = self._distance is not None and self.measured > STOPPED_SPEED
        return self.brake if approaching else min(requested, 0.0)
