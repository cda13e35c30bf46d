"""A fake Altino on its stock firmware, behind a pseudo-terminal, for the stock backend's tests.

The car's physics is the simulator's (``Simulation(ALTINO, 1)``): the fake parses the
vendor's 28-byte command frames, answers each sensor request with a 31- or 56-byte reply whose
IR[1] is the simulated readout *now* (before the frame's command acts), then steps the
simulation one period under the frame's command. It records every frame it receives, and can
stop answering, corrupt replies or vanish (close the pty).
"""

from __future__ import annotations

import os
import select
import threading
import tty
from typing import Any

import numpy as np

from frictiongym.devices import ALTINO
from frictiongym.envs import _kernel as env_kernel
from frictiongym.envs.core import Device, Simulation
from frictiongym.hardware.altino_frames import (
    COMMAND_LENGTH,
    STX,
    StockCommand,
    StockSensors,
    parse_go_frame,
    sensor_reply,
)
from frictiongym.hardware.errors import ProtocolError


class StepSim:
    """One simulated device stepped by hand (the env core, so the physics is the env's).

    ``measured`` is the first observation (Altino: IR readout; servo: encoder angle, rad),
    ``position`` the true one (Altino: distance to the wall, cm; servo: angle, rad).
    """

    def __init__(self, device: Device, start: float, dt: float, **kwargs: Any) -> None:
        self.sim = Simulation(device, 1, dt=dt, **kwargs)
        self._command = np.zeros(1)
        self._fresh = np.ones(1, dtype=bool)
        self._obs = np.zeros((1, self.sim.observation_size), dtype=np.float32)
        self._out = np.zeros((env_kernel.OUT_SIZE, 1))
        self._flags = np.zeros((env_kernel.FLAG_SIZE, 1), dtype=bool)
        rng = np.random.default_rng(0)
        self.sim.prepare_reset(self._fresh, lambda _: rng, {"position": start})
        self.sim.run(self._command, self._fresh, self._obs, self._out, self._flags)
        self._fresh[:] = False

    @property
    def measured(self) -> float:
        """The sensor: IR readout 0..800, or the encoder angle in rad."""
        return float(self._obs[0, 0])

    @property
    def readout(self) -> int:
        """Altino IR readout, 0..800."""
        return int(self._obs[0, 0])

    @property
    def position(self) -> float:
        """True position: distance to the wall (cm) or angle (rad)."""
        return float(self._out[env_kernel.O_POSITION, 0])

    def step(self, command: float) -> None:
        """Hold ``command`` (physical units) for one period."""
        self._command[0] = command
        self.sim.run(self._command, self._fresh, self._obs, self._out, self._flags)


class FakeStockAltino:
    """A stock Altino on a pty; connect to :attr:`port`.

    Parameters
    ----------
    start_cm : float
        Starting distance to the wall, cm.
    rate_hz : float
        The period the simulation steps per frame (the backend's rate).
    """

    def __init__(self, start_cm: float = 20.0, rate_hz: float = 20.0, **sim_kwargs: Any) -> None:
        self.car = StepSim(ALTINO, start_cm, 1.0 / rate_hz, **sim_kwargs)
        self.commands: list[StockCommand] = []  #: every valid frame received
        self.replies: list[int | None] = []  #: IR[1] answered to each frame (None: no reply)
        self.answering = True  #: False: receive and drive, never reply
        self.corrupt = 0  #: number of next replies sent with a wrong checksum
        #: IR[1] readouts the next replies carry instead of the car's, first first (with a
        #: valid checksum: a corruption the 8-bit sum lets through).
        self.forged: list[int] = []
        self.bad_frames = 0  #: frames that failed parsing
        self._master, self._slave = os.openpty()
        tty.setraw(self._master)
        self.port = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._buffer = bytearray()
        self._thread = threading.Thread(target=self._run, name="fake-altino", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.02)
            if not ready:
                continue
            try:
                data = os.read(self._master, 4096)
            except OSError:
                return
            self._buffer += data
            while self._frame():
                pass

    def _frame(self) -> bool:
        """Handle the first whole frame of the buffer; False when none is complete."""
        start = self._buffer.find(STX)
        if start < 0:
            self._buffer.clear()
            return False
        del self._buffer[:start]
        if len(self._buffer) < COMMAND_LENGTH:
            return False
        try:
            command = parse_go_frame(bytes(self._buffer[:COMMAND_LENGTH]))
        except ProtocolError:
            self.bad_frames += 1
            del self._buffer[0]
            return True
        del self._buffer[:COMMAND_LENGTH]
        self.commands.append(command)
        self.replies.append(None)
        if command.request in (1, 10) and self.answering:
            readout = self.forged.pop(0) if self.forged else self.car.readout
            self.replies[-1] = readout
            ir = (0, readout, 0, 0, 0, 0)
            reply = bytearray(sensor_reply(StockSensors(group=command.request, ir=ir)))
            if self.corrupt > 0:
                self.corrupt -= 1
                reply[2] ^= 0xFF
            os.write(self._master, bytes(reply))
        self.car.step(0.5 * (command.left + command.right))
        return True

    def unplug(self) -> None:
        """Vanish: stop answering and close the pty's master side (the port hangs up)."""
        if not self._stop.is_set():
            self._stop.set()
            self._thread.join(timeout=2.0)
            os.close(self._master)

    def close(self) -> None:
        """Unplug and release the pty."""
        if self._slave >= 0:
            self.unplug()
            os.close(self._slave)
            self._slave = -1

    def __enter__(self) -> FakeStockAltino:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
