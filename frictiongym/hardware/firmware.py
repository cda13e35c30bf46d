"""Our device firmware's state machine around the simulated plant, without I/O or clocks.

:class:`Firmware` is what ``firmware/common/`` does on the microcontroller, in Python: it
answers ``HelloRequest`` at once, queues ``Command`` and ``Place`` frames, and at every tick of
the device clock applies them (the newest command wins), runs the watchdog, holds the motor
command over the period (the Altino's distance guard checks a forward command against the
latest sample first), samples the sensor, feeds the sample to the guard
(:class:`~frictiongym.hardware.guard.DistanceGuard`, whose output the motor holds over the
next period) and builds one ``State``. The plant is a :class:`~frictiongym.plants.Plant` of one
read through :func:`~frictiongym.plants.sensors.measure`, with the env's settings, draws and
noise, so the physics exists once and the sensor numbers are the env's own measurements
(bit-identical to the simulated env fed the same applied commands). The emulator
(:class:`frictiongym.hardware.emulator.Emulator`) drives it from a real-time or lock-step clock
behind a pty or a TCP socket; ``tests/test_firmware.py`` checks it against the C firmware's
scenario table.

Timing idealisation: a command is held over the *whole* period in which it arrived, and the
``State`` that ends that period echoes it; the emulator has no transport or computation delay
of its own (the plant's ``dead_time`` is part of the plant). Use ``Faults(delay=...)`` of the
emulator for link latency.
"""

from __future__ import annotations

import math
import os
from collections import deque
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from frictiongym import devices
from frictiongym.friction import FrictionModel
from frictiongym.hardware import protocol
from frictiongym.hardware.base import kind_code
from frictiongym.hardware.guard import CarBounds, DistanceGuard
from frictiongym.params import DeviceParams, device_physics
from frictiongym.plants.plant import Plant, default_substeps
from frictiongym.plants.randomization import DomainRandomization, apply_factors
from frictiongym.plants.sensors import SENSOR_ENCODER, measure, noise_std, normal_draw

#: Build number the firmware reports in its ``Hello``, the same as ``FG_FIRMWARE_BUILD`` in
#: firmware/common/fg_device.h: 3 = the guard bounds the speed and the car (2: the predictive
#: distance guard of one nominal car; 1: a fixed readout limit).
FIRMWARE_BUILD = 3
#: Default watchdog: three periods, at least 100 ms (servo 100 ms, Altino 150 ms). The floor is
#: the host's margin: a general-purpose host under load stalls for tens of ms now and then
#: (docs/hardware.md, "Timing and the watchdog"), and a stall is not a dead host.
WATCHDOG_PERIODS = 3
WATCHDOG_MIN_MS = 100
#: Farthest start of an emulated device, position units (a ``Place`` beyond is refused).
PLACE_RANGE = 1e9
#: Per-tick records kept in :attr:`Firmware.history` (200 s at 500 Hz; older ones are dropped).
HISTORY_TICKS = 100_000
#: One :attr:`Firmware.history` record: a plain tuple of numbers, which the garbage collector
#: stops tracking (a full history of :class:`Tick` objects made each collection 8 ms longer).
TickRecord = tuple[int, int, int, int, int, float, float]


class Tick(NamedTuple):
    """One tick of the emulated device, as its ``State`` reported it, plus the truth."""

    tick: int  #: device tick number (1 is the first)
    seq_applied: int  #: ``seq`` of the command held over the period
    applied: int  #: motor command held over the period, counts
    status: protocol.Status  #: status bits sent
    sensor: int  #: encoder counts or IR readout sent
    position: float  #: true position at the tick: rad, or cm from the wall
    velocity: float  #: its true rate


def default_watchdog_ms(dt: float) -> int:
    """Return the default watchdog time of a device of period ``dt``: max(3 periods, 100 ms)."""
    return max(math.ceil(WATCHDOG_PERIODS * dt * 1000.0 - 1e-9), WATCHDOG_MIN_MS)


def _wrap_i32(value: int) -> int:
    """Wrap an integer into int32, as a 32-bit encoder counter does."""
    return ((value + 2**31) % 2**32) - 2**31


class Firmware:
    """The device firmware's state machine around one simulated plant (see the module).

    Parameters
    ----------
    kind : str
        The device to emulate, one of :data:`~frictiongym.hardware.base.KINDS`: what it is and
        does is its :class:`~frictiongym.devices.Device` (sensor, sign, command scale, limits;
        the distance guard with the IR sensor).
    params : str, PathLike or DeviceParams, optional
        The plant's "true" identified parameters (a ``friction.json``); default: the nominal
        model with ``friction``.
    friction : str or FrictionModel, default "paper"
        The true friction law (ignored with ``params``, whose law it is).
    sensor_noise : bool or float, default False
        Sensor noise, as the env's ``sensor_noise``.
    randomize : mapping or DomainRandomization, optional
        Factors drawn at boot and at every ``Place`` (a device unlike the nominal model).
    watchdog_ms : int, optional
        Watchdog time, ms (default: max(3 periods, 100 ms)); 0 turns it off.
    start : float, optional
        Position at boot: rad, or cm from the wall (default: the env's start).
    seed : int, default 0
        Seed of the plant's draws (noise, randomisation): ``numpy.random.default_rng(seed)``,
        as ``env.reset(seed=seed)`` seeds the env.
    car_bounds : CarBounds, optional
        What the Altino's distance guard assumes of the car (default: the documented mass
        range and the least friction of the plant's own law,
        :meth:`~frictiongym.hardware.guard.CarBounds.from_law`).
    """

    def __init__(
        self,
        kind: str,
        *,
        params: str | os.PathLike[str] | DeviceParams | None = None,
        friction: str | FrictionModel = "paper",
        sensor_noise: bool | float = False,
        randomize: Mapping[str, Any] | None = None,
        watchdog_ms: int | None = None,
        start: float | None = None,
        seed: int = 0,
        car_bounds: CarBounds | None = None,
    ) -> None:
        self.device = devices.get(kind)  # a ValueError naming the devices
        self.kind = kind = self.device.kind
        self.dt = self.device.dt
        self.scale = self.device.command_scale  #: command counts per unit
        self.encoder = self.device.sensor == SENSOR_ENCODER
        guarded = not self.encoder  # the distance guard reads the IR sensor (hardware/guard.py)
        _, self.friction, _, self.plant_params = device_physics(
            self.device, self.dt, friction, params=params
        )
        spread = self.randomize = DomainRandomization.from_spec(randomize)
        lightest = self.plant_params if spread is None else spread.lightest(self.plant_params)
        substeps = default_substeps([lightest], [self.friction], self.dt)
        # One plant: the single-threaded kernel, whatever the envs' policy for batches.
        self.plant = Plant(
            self.plant_params, self.friction, self.dt, substeps=substeps, parallel=False
        )
        self._nominal_row = self.plant.rows[0].copy()
        self.noise_std = noise_std(sensor_noise, self.device.noise_std)
        self._noise = np.zeros(1, dtype=np.uint64)  # the sensor noise's generator state
        self._gain = 1.0  # the sensor's drawn gain
        if watchdog_ms is None:
            watchdog_ms = default_watchdog_ms(self.dt)
        if not (isinstance(watchdog_ms, int) and 0 <= watchdog_ms <= 0xFFFF):
            raise ValueError(
                "watchdog_ms must be a whole number of ms in 0..65535 (0: off), "
                f"got {watchdog_ms!r}"
            )
        self.watchdog_s = watchdog_ms / 1000.0
        caps = protocol.Capability.PLACE | (protocol.Capability.WATCHDOG if watchdog_ms else 0)
        if guarded:
            caps |= protocol.Capability.DISTANCE_LIMIT
        self.hello = protocol.Hello(
            version=protocol.PROTOCOL_VERSION,
            kind=protocol.DeviceKind(kind_code(kind)),
            capabilities=protocol.Capability(caps),
            rate_hz=round(1.0 / self.dt),
            counts_per_rev=self.device.counts_per_rev,
            command_scale=self.scale,
            command_limit=round(self.plant_params.command_limit * self.scale),
            watchdog_ms=watchdog_ms,
            firmware=FIRMWARE_BUILD,
        )
        self._period_us = round(self.dt * 1e6)
        self._rng = np.random.default_rng(seed)
        self.decoder = protocol.FrameDecoder()
        self._pending: list[protocol.Command | protocol.Place] = []
        self.ticks = 0  #: device ticks so far
        self.commands = 0  #: valid ``Command`` frames received
        self.late = 0  #: ticks that held an old command while armed and enabled
        self.rejected = 0  #: ``Place`` frames refused (position out of range) and host frames
        self.armed = False
        self.enabled = False
        self.held = 0  #: counts of the newest command (clipped to the limit)
        self.motor_counts = 0  #: counts the motor holds now (negative while the guard brakes)
        self.seq_applied = 0
        self.latched = protocol.Status(0)  #: latched WATCHDOG / LIMIT bits
        self.status = protocol.Status.DISABLED  #: status bits of the last state
        self.last_command = -math.inf  #: arrival time of the newest command, s
        #: Per-tick records, as :meth:`ticks_history` returns them (:data:`TickRecord`).
        self.history: deque[TickRecord] = deque(maxlen=HISTORY_TICKS)
        self._errors_seen = 0
        #: The distance guard of a device with the IR sensor (None else): brakes before the wall.
        self.guard: DistanceGuard | None = None
        self.set_car_bounds(self._car_bounds() if car_bounds is None else car_bounds)
        if guarded:
            self.guard = self._new_guard()
        self.sensor = 0
        self.plant.step(0.0)  # compiled now: a first tick must not stall past the watchdog
        self._place(self.device.start if start is None else float(start))

    # -- plant ------------------------------------------------------------------------------

    @property
    def position(self) -> float:
        """True position, env units (rad, or cm from the wall)."""
        return self.device.direction * float(self.plant.position[0])

    @property
    def velocity(self) -> float:
        """True velocity, env units (rad/s, or cm/s away from the wall)."""
        return self.device.direction * float(self.plant.velocity[0])

    @property
    def motor(self) -> float:
        """The command the motor holds now, physical units.

        0.0 when disabled, except while the Altino's distance guard brakes (full reverse).
        """
        return self.motor_counts / self.scale

    def _place(self, position: float) -> None:
        """Reset the plant at rest at ``position`` and sample it (the env's reset and draws).

        Raises ValueError if ``position`` is not within ±:data:`PLACE_RANGE` and short of the
        device's end stop (ahead of the Altino's wall).
        The distance guard starts afresh there (the car did not drive there: no speed), keeping
        its trip, and judges the new sample at once.
        """
        device = self.device
        x = device.direction * position
        if not (abs(position) <= PLACE_RANGE and x < device.end_stop):
            raise ValueError(
                f"{device.title} must start within ±{PLACE_RANGE:g} {device.position_unit} and "
                f"short of its end stop, got {position!r}"
            )
        if self.randomize is not None:
            factors = self.randomize.draw(self._rng)
            self.plant.rows[0], self._gain = apply_factors(self._nominal_row, factors)
        if self.noise_std > 0.0:
            self._noise[0] = self._rng.integers(2**64, dtype=np.uint64)
        self.plant.reset(x)
        self.sensor = self._sensor()
        if self.guard is not None:
            tripped = self.guard.tripped
            self.guard = self._new_guard()
            self.guard.tripped = tripped
            self._watch(0)
        self.motor_counts = self._output()

    def _car_bounds(self) -> CarBounds:
        """Return the guard's bounds from the plant's own law, mass and randomisation ranges."""
        plant, spread = self.plant_params, self.randomize
        bounds = CarBounds.from_law(
            self.friction, plant.damping, plant.inertia, self.hello.command_limit
        )
        if spread is None:
            return bounds
        masses = [plant.inertia * f for f in spread.inertia or (1.0, 1.0)]
        return CarBounds(
            min(bounds.mass_min, masses[0]),
            max(bounds.mass_max, masses[1]),
            bounds.friction * (spread.friction or (1.0,))[0],
            bounds.viscous * (spread.damping or (1.0,))[0],
            bounds.command_limit,
            bounds.noise_counts,
        )

    def set_car_bounds(self, car_bounds: CarBounds) -> None:
        """Change what the distance guard assumes of the car; its state is kept.

        The C firmware's ``fg_device_set_car``.
        """
        if not isinstance(car_bounds, CarBounds):
            raise TypeError(f"car_bounds must be a CarBounds(...), got {car_bounds!r}")
        #: What the distance guard assumes of the car (its mass range and least friction).
        self.car_bounds = car_bounds
        if self.guard is not None:
            self.guard.car = car_bounds

    def _new_guard(self) -> DistanceGuard:
        return DistanceGuard(self.dt, self.hello.command_limit, car=self.car_bounds)

    def _sensor(self) -> int:
        """Sample the sensor, as the env does: encoder counts or IR readout."""
        noise = self.noise_std * normal_draw(self._noise, 0) if self.noise_std > 0.0 else 0.0
        x, step = float(self.plant.position[0]), self.device.encoder_step
        measured = measure(x, self.encoder, self._gain, 0.0, noise, True, step)
        return _wrap_i32(round(measured / step)) if self.encoder else int(measured)

    # -- messages ---------------------------------------------------------------------------

    def feed(self, data: bytes) -> list[protocol.Message]:
        """Decode the bytes the host sent (bad frames are counted for ``CRC_ERROR``)."""
        return self.decoder.feed(data)

    def receive(self, message: protocol.Message, now: float) -> protocol.Hello | None:
        """Take one message that arrived at ``now`` (s); return the reply to send at once.

        ``HelloRequest`` (of any version: the host decides) is answered with the ``Hello``;
        ``Command`` and ``Place`` wait for the next tick; a device's own messages are ignored.
        """
        if isinstance(message, protocol.HelloRequest):
            return self.hello
        if isinstance(message, protocol.Command):
            self.commands += 1
            self.last_command = now
            self._pending.append(message)
        elif isinstance(message, protocol.Place):
            self._pending.append(message)
        else:
            self.rejected += 1
        return None

    def apply_pending(self) -> bool:
        """Apply the queued messages in order; return whether a command was among them."""
        got = False
        for message in self._pending:
            if isinstance(message, protocol.Place):
                try:
                    self._place(float(message.position))
                except ValueError:  # out of range or not finite: a device ignores it
                    self.rejected += 1
                continue
            got = True
            flags = message.flags
            if flags & protocol.Flag.REARM:
                self.latched = protocol.Status(0)
                self.armed = True
                if self.guard is not None and self.guard.rearm():
                    self.latched |= protocol.Status.LIMIT  # still too close or too fast: at once
            if flags & protocol.Flag.ESTOP:
                self.armed = False
            if flags & protocol.Flag.ZERO_POSITION and self.encoder:
                self.plant.place(0.0)  # the encoder reset (Plant.place)
                self.sensor = 0
            self.enabled = bool(flags & protocol.Flag.ENABLE)
            limit = self.hello.command_limit
            self.held = min(max(int(message.command), -limit), limit)
            self.seq_applied = message.seq
        self._pending.clear()
        return got

    def watchdog_deadline(self) -> float | None:
        """When the watchdog trips if no command comes (s, the clock of ``now``); None: never."""
        if not (self.armed and self.watchdog_s):
            return None
        return self.last_command + self.watchdog_s

    def excuse(self, seconds: float) -> None:
        """Do not count ``seconds`` of host silence against the watchdog.

        The emulator calls this when its own thread ran late and sent no state for that long:
        a host cannot answer states it never got (a microcontroller never runs late).
        """
        self.last_command += max(0.0, seconds)

    def ticks_history(self) -> list[Tick]:
        """Return :attr:`history` as :class:`Tick` records (newest last)."""
        return [
            Tick(t, seq, applied, protocol.Status(status), sensor, x, v)
            for t, seq, applied, status, sensor, x, v in self.history
        ]

    # -- tick -------------------------------------------------------------------------------

    def _watch(self, held: int) -> None:
        """Feed the latest sample and the counts held before it to the guard; latch on a trip."""
        if self.guard is not None and self.guard.update(self.sensor, held / self.scale):
            self.latched |= protocol.Status.LIMIT

    def _output(self) -> int:
        """Return the counts the motor holds: the request if armed and enabled, via the guard.

        The guard acts whether or not the device is armed: once tripped it brakes while the
        car still approaches, after an e-stop or a watchdog trip too. A forward request is
        judged first, from the latest sample (``DistanceGuard.command``); if it trips the
        guard, ``LIMIT`` latches here.
        """
        requested = self.held if self.armed and self.enabled else 0
        if self.guard is None:
            return requested
        counts = round(self.guard.command(requested))
        if self.guard.tripped:
            self.latched |= protocol.Status.LIMIT
        return counts

    def hold(self, counts: int) -> None:
        """Integrate the plant over one period holding ``counts``, then sample its sensor.

        The plant's part of :meth:`tick` alone, for another implementation of the firmware to
        drive the same plant (``scripts/guard_scan.py`` runs the C one around it).
        """
        self.plant.step(counts / self.scale)
        self.sensor = self._sensor()
        end_stop = self.device.end_stop
        if self.plant.position[0] >= end_stop:  # an inelastic wall (the env ends episodes there)
            self.plant.place(end_stop, stop=True)

    def tick(self, now: float) -> protocol.State:
        """Run one device period ending at ``now`` (s); return its ``State``.

        Applies the queued messages, trips the watchdog if it is due, holds the motor output
        over the period (through the distance guard, as it judged the previous sample; a
        forward command, the newest one applied now, is checked against that sample before it
        is held), integrates the plant, samples the sensor and feeds the sample to the guard;
        the guard's answer, the held command checked against the new sample, is the motor
        output of the next period (:attr:`motor`).
        """
        got = self.apply_pending()
        deadline = self.watchdog_deadline()
        if deadline is not None and now >= deadline:
            self.armed = False
            self.latched |= protocol.Status.WATCHDOG
        counts = self._output()  # the newest command, a forward one checked by the guard
        self.motor_counts = counts
        self.hold(counts)
        self._watch(counts)
        self.motor_counts = self._output()  # the guard may brake from now on
        self.ticks += 1
        driving = self.armed and self.enabled
        status = self.latched
        if not driving:
            status |= protocol.Status.DISABLED
        elif not got:
            status |= protocol.Status.COMMAND_LATE
            self.late += 1
        if self.decoder.errors > self._errors_seen:
            status |= protocol.Status.CRC_ERROR
            self._errors_seen = self.decoder.errors
        self.status = status
        self.history.append(
            (
                self.ticks,
                self.seq_applied,
                counts,
                int(status),
                self.sensor,
                self.position,
                self.velocity,
            )
        )
        return protocol.State(
            status=status,
            seq=self.ticks & 0xFFFF,
            tick_us=(self.ticks * self._period_us) & 0xFFFFFFFF,
            seq_applied=self.seq_applied,
            applied=counts,
            sensor=self.sensor,
        )


__all__ = [
    "FIRMWARE_BUILD",
    "Firmware",
    "Tick",
    "default_watchdog_ms",
]
