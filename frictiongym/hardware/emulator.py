"""The device emulator: our firmware around the simulated plant, behind the wire protocol.

An :class:`Emulator` runs a :class:`~frictiongym.hardware.firmware.Firmware` (the firmware's
state machine around the env's own simulated plant, with its own "true" parameters) in a
thread, on a pseudo-terminal (:meth:`Emulator.serve_pty`, for pyserial in this or another
process) or a TCP server (:meth:`Emulator.serve_tcp`, pyserial's ``socket://``)::

    from frictiongym.hardware.emulator import Emulator
    with Emulator("rotary") as emu:
        port = emu.serve_pty()                 # "/dev/pts/7"
        env = gym.make("frictiongym/RotaryServo-v1", backend=f"serial://{port}")

Two clocks:

* real time (default): the device thread ticks at absolute deadlines ``t0 + k dt`` (never
  ``sleep(dt)``), reading input without blocking in between; a ``HelloRequest`` is answered at
  once. A tick the thread could not make in time is still integrated (the plant does not wait)
  but its ``State`` is not sent: ``seq`` jumps and :attr:`EmulatorStats.missed` counts it. The
  watchdog does not count such a stall of the emulator against the host
  (:meth:`~frictiongym.hardware.firmware.Firmware.excuse`). The thread runs under
  ``SCHED_FIFO`` where the system permits it (:mod:`frictiongym.hardware.realtime`;
  :attr:`Emulator.priority` says what it got), and the objects alive when it starts are kept
  out of the garbage collector's scans, so a collection does not stall the device either.
* lock-step (``lockstep=True``, for exact tests): every ``Command`` received is one tick, so
  device time is exactly ``ticks dt`` whatever the host's speed; while armed and silent for
  ``watchdog_ms`` of wall time the watchdog trips and a ``State`` is sent anyway.

:class:`Faults` injects link faults on the device's output: dropped bytes, flipped bits, delays
and jitter, unplugging (the link closes; the host's reads fail) and freezing (the device stops
sending; the host times out). After either the device keeps running, and its watchdog zeroes
the motor when commands stop.
"""

from __future__ import annotations

import math
import os
import select
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from frictiongym.hardware import protocol
from frictiongym.hardware.firmware import Firmware, Tick
from frictiongym.hardware.guard import CarBounds
from frictiongym.hardware.realtime import (
    REALTIME_PRIORITY,
    describe_priority,
    freeze_heap,
    raise_priority,
    thaw_heap,
)
from frictiongym.hardware.transport import Faults, Link, PtyLink, TcpLink

#: Longest wait of the lock-step thread between checks, s (a pty without a host is retried).
LOCKSTEP_POLL = 0.02
#: Timing samples kept for :meth:`Emulator.stats` (the last 20 s at 500 Hz).
TIMING_SAMPLES = 10_000
#: Longest wait for the device thread to act on unplug/close, s.
JOIN_TIMEOUT = 5.0


@dataclass(frozen=True)
class EmulatorStats:
    """Counters and timing of a running emulator."""

    ticks: int  #: device ticks so far
    missed: int  #: ticks whose state was not sent because the thread woke too late
    commands: int  #: valid commands received
    crc_errors: int  #: bad frames received
    late: int  #: ticks that held an old command while armed and enabled
    frames_sent: int  #: frames written (states and hellos; before byte drops)
    bytes_dropped: int  #: bytes dropped by fault injection or because nobody read them
    tick_time_mean: float  #: time to run one tick and send its state, s (every tick so far)
    tick_time_p99: float  #: over the last ``TIMING_SAMPLES`` ticks
    tick_time_max: float  #: over every tick
    wake_late_p50: float  #: how late the thread woke for a tick, s (real time only; the last
    wake_late_p99: float  #: ``TIMING_SAMPLES`` ticks)
    wake_late_max: float  #: over every tick


class Emulator:
    """A device of ``kind`` behind the protocol, served on a pty or on TCP (module docstring).

    Parameters
    ----------
    kind : {"rotary", "altino"}
        The device.
    seed : int, default 0
        Seed of the plant's draws (as :class:`~frictiongym.hardware.firmware.Firmware`'s) and,
        through a spawned child, of the link faults.
    lockstep : bool, default False
        One tick per command received instead of the real-time clock.
    faults : Faults, optional
        Link faults to inject (default: none).
    realtime : bool, default True
        Run the device thread under ``SCHED_FIFO`` where the system permits it
        (:attr:`priority` says what it got); False leaves it an ordinary thread.
    **firmware
        The plant's "true" parameters and the firmware's settings: ``params``, ``friction``,
        ``sensor_noise``, ``randomize``, ``watchdog_ms``, ``start``, ``car_bounds``
        (:class:`~frictiongym.hardware.firmware.Firmware`).
    """

    def __init__(
        self,
        kind: str,
        *,
        lockstep: bool = False,
        faults: Faults | None = None,
        seed: int = 0,
        realtime: bool = True,
        **firmware: Any,
    ) -> None:
        if faults is None:
            faults = Faults()
        if not isinstance(faults, Faults):
            raise TypeError(f"faults must be a Faults(...), got {faults!r}")
        self.firmware = Firmware(kind, seed=seed, **firmware)
        self.kind = kind
        self.dt = self.firmware.dt
        self.lockstep = bool(lockstep)
        self.faults = faults
        self.url: str | None = None
        self.error: BaseException | None = None  #: what stopped the device thread, if anything
        #: The device thread's scheduling: ``"SCHED_FIFO N"``, or why it is an ordinary one.
        self.priority = "not started"
        self.realtime = bool(realtime)
        self._rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        self._link: Link | None = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._stop = False
        self._closed = False
        self._started = threading.Event()
        self._unplug_requested = threading.Event()
        self._unplugged = threading.Event()
        self._frozen = False
        self._delayed: deque[tuple[float, bytes]] = deque()
        self._last_release = 0.0
        self._frames_sent = 0
        self._bytes_dropped = 0
        self._missed = 0
        self._tick_times: deque[float] = deque(maxlen=TIMING_SAMPLES)
        self._tick_time_total = 0.0  # over every tick, for the mean
        self._tick_time_max = 0.0
        self._ticks_timed = 0
        self._wake_late_max = 0.0
        self._wake_late: deque[float] = deque(maxlen=TIMING_SAMPLES)

    # -- public state -------------------------------------------------------------------------

    @property
    def motor(self) -> float:
        """The command the motor holds now, physical units (0.0 when disabled)."""
        return self.firmware.motor

    @property
    def status(self) -> protocol.Status:
        """Status bits of the latest state (``DISABLED`` at boot)."""
        return self.firmware.status

    @property
    def history(self) -> list[Tick]:
        """Per-tick records (newest last; the last ``HISTORY_TICKS`` of them)."""
        with self._lock:
            return self.firmware.ticks_history()

    @property
    def position(self) -> float:
        """True plant position: rad, or cm from the wall."""
        return self.firmware.position

    @property
    def velocity(self) -> float:
        """True plant velocity: rad/s, or cm/s away from the wall."""
        return self.firmware.velocity

    @property
    def running(self) -> bool:
        """Whether the device thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def set_car_bounds(self, car_bounds: CarBounds) -> None:
        """Change what the Altino's distance guard assumes of the car (``Firmware``'s)."""
        with self._lock:
            self.firmware.set_car_bounds(car_bounds)

    def stats(self, timing: bool = True) -> EmulatorStats:
        """Counters and timing so far.

        The device thread waits for nothing here: the samples are copied under its lock and
        summarised outside it. ``timing=False`` skips the percentiles (they read as NaN; the
        mean and the maxima stay), cheap enough for a status line every second.
        """
        with self._lock:
            fw = self.firmware
            link_dropped = self._link.dropped if self._link is not None else 0
            counts = (
                fw.ticks,
                self._missed,
                fw.commands,
                fw.decoder.errors,
                fw.late,
                self._frames_sent,
                self._bytes_dropped + link_dropped,
            )
            times = list(self._tick_times) if timing else []
            late = list(self._wake_late) if timing else []
            tick_mean = self._tick_time_total / max(self._ticks_timed, 1)
            tick_max, late_max = self._tick_time_max, self._wake_late_max
        p = np.quantile(times, 0.99) if times else (0.0 if timing else math.nan)
        q = np.quantile(late, [0.5, 0.99]) if late else np.full(2, 0.0 if timing else math.nan)
        return EmulatorStats(
            *counts,
            tick_time_mean=tick_mean,
            tick_time_p99=float(p),
            tick_time_max=tick_max,
            wake_late_p50=float(q[0]),
            wake_late_p99=float(q[1]),
            wake_late_max=late_max,
        )

    # -- serving ------------------------------------------------------------------------------

    def serve_pty(self) -> str:
        """Start the device on a new pseudo-terminal; return the path the host opens."""
        return self._serve(PtyLink())

    def serve_tcp(self, host: str = "127.0.0.1", port: int = 0) -> str:
        """Start the device on a TCP server (port 0: any free one); return its pyserial URL."""
        return self._serve(TcpLink(host, port))

    def _serve(self, link: Link) -> str:
        if self._closed:
            link.close()
            raise RuntimeError("this emulator is closed; make a new one")
        if self._link is not None:
            link.close()
            raise RuntimeError(f"this emulator already serves {self.url}; make another one")
        self._link = link
        self.url = link.url
        freeze_heap(self)
        loop = self._loop_lockstep if self.lockstep else self._loop_realtime
        self._thread = threading.Thread(
            target=self._run, args=(loop,), name=f"frictiongym-emulator-{self.kind}", daemon=True
        )
        self._thread.start()
        self._started.wait(JOIN_TIMEOUT)  # its priority is set: :attr:`priority` is final
        return link.url

    def unplug(self) -> None:
        """Close the link now (the host's reads fail); the device keeps running unlinked."""
        self._unplug_requested.set()
        if self.running and threading.current_thread() is not self._thread:
            self._wake()
            self._unplugged.wait(JOIN_TIMEOUT)
        else:
            self._do_unplug()

    def freeze(self) -> None:
        """Stop sending anything, keeping the link open (the host times out).

        The device still reads commands and runs; its watchdog zeroes the motor.
        """
        self._frozen = True

    def close(self) -> None:
        """Stop the device thread and close the link (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop = True
        if self._thread is not None:
            self._wake()
            self._thread.join(JOIN_TIMEOUT)
        if self._link is not None:
            self._link.close()
        for fd in (self._wake_r, self._wake_w):
            os.close(fd)
        thaw_heap(self)

    def __enter__(self) -> Emulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        if not getattr(self, "_closed", True):
            self.close()

    # -- device thread ------------------------------------------------------------------------

    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b"\x01")
        except (BlockingIOError, OSError):
            pass

    def _run(self, loop: Any) -> None:
        why_not = raise_priority(REALTIME_PRIORITY) if self.realtime else "not asked for"
        self.priority = describe_priority(why_not)
        self._started.set()
        try:
            loop()
        except BaseException as exc:  # reported through .error
            self.error = exc
        finally:
            self._do_unplug()

    def _do_unplug(self) -> None:
        if self._link is not None:
            self._link.close()
        self._delayed.clear()
        self._unplugged.set()

    def _wait(self, timeout: float) -> list[int]:
        """Wait up to ``timeout`` s for input; return the link's ready descriptors."""
        link = None if self._unplugged.is_set() else self._link
        fds = [] if link is None else link.fds()
        pending = link is not None and link.pending
        ready, _, _ = select.select(
            [*fds, self._wake_r], [], [], 0.0 if pending else max(timeout, 0.0)
        )
        if self._wake_r in ready:
            try:
                os.read(self._wake_r, 64)
            except BlockingIOError:
                pass
            ready.remove(self._wake_r)
        if pending and not ready:
            ready = [-1]  # input already waits inside the link
        if self._unplug_requested.is_set() and not self._unplugged.is_set():
            self._do_unplug()
        return ready

    def _read(self, ready: list[int]) -> list[protocol.Message]:
        if not ready or self._link is None or self._unplugged.is_set():
            return []
        return self.firmware.feed(self._link.read(ready))

    def _send(self, message: protocol.Message) -> None:
        """Write a frame through the fault injection (or queue it for its delay)."""
        if self._frozen or self._unplugged.is_set() or self._link is None:
            return
        faults, rng = self.faults, self._rng
        encoded = protocol.encode(message)
        frame = faults.mangle(encoded, rng)
        self._bytes_dropped += len(encoded) - len(frame)
        self._frames_sent += 1
        if faults.delayed:
            due = time.perf_counter() + faults.delay + faults.jitter * rng.random()
            self._last_release = max(due, self._last_release)  # a link keeps the order
            self._delayed.append((self._last_release, frame))
        else:
            self._link.write(frame)

    def _release(self) -> float:
        """Write the delayed frames that are due; return the time until the next (or inf)."""
        if self._frozen:
            self._delayed.clear()
        now = time.perf_counter()
        while self._delayed and self._delayed[0][0] <= now:
            frame = self._delayed.popleft()[1]
            if self._link is not None and not self._unplugged.is_set():
                self._link.write(frame)
        if self._link is not None and not self._unplugged.is_set():
            self._link.flush()
        return self._delayed[0][0] - now if self._delayed else math.inf

    def _after_tick(self, state: protocol.State, started: float) -> None:
        self._send(state)
        took = time.perf_counter() - started
        self._tick_times.append(took)
        self._tick_time_total += took
        self._tick_time_max = max(self._tick_time_max, took)
        self._ticks_timed += 1
        device_time = self.firmware.ticks * self.dt
        faults = self.faults
        if faults.freeze_after is not None and device_time >= faults.freeze_after:
            self._frozen = True
        if faults.unplug_after is not None and device_time >= faults.unplug_after:
            self._unplug_requested.set()
            self._do_unplug()

    def _answer(self, message: protocol.Message, now: float) -> bool:
        """Hand ``message`` to the firmware, answer a ``HelloRequest``; True for a command."""
        reply = self.firmware.receive(message, now)
        if reply is not None:
            self._send(reply)
        return isinstance(message, protocol.Command)

    def _loop_realtime(self) -> None:
        fw, dt = self.firmware, self.dt
        t0 = time.perf_counter()
        while not self._stop:
            now = time.perf_counter()
            deadline = t0 + (fw.ticks + 1) * dt
            if now >= deadline:
                for message in self._read(self._wait(0.0)):  # what arrived up to the tick
                    self._answer(message, now - t0)
                missed = max(int((now - t0) / dt) - fw.ticks, 1) - 1
                with self._lock:
                    fw.excuse(missed * dt)  # the host never got the states of these ticks
                    for _ in range(missed + 1):
                        state = fw.tick((fw.ticks + 1) * dt)
                    self._missed += missed
                    self._wake_late.append(now - deadline)
                    self._wake_late_max = max(self._wake_late_max, now - deadline)
                    self._after_tick(state, now)
                self._release()
                continue
            ready = self._wait(min(deadline - now, self._release()))
            arrived = time.perf_counter() - t0
            for message in self._read(ready):
                self._answer(message, arrived)
            self._release()

    def _loop_lockstep(self) -> None:
        fw = self.firmware
        t0 = time.perf_counter()
        while not self._stop:
            timeout = min(LOCKSTEP_POLL, self._release())
            watchdog = fw.watchdog_deadline()
            if watchdog is not None:
                timeout = min(timeout, max(0.0, watchdog - (time.perf_counter() - t0)))
            ready = self._wait(timeout)
            now = time.perf_counter() - t0
            commanded = self._step_lockstep(ready, now)
            watchdog = fw.watchdog_deadline()
            if not commanded and watchdog is not None and now >= watchdog:
                # One more look first: this thread may have been held up (a garbage collection,
                # the scheduler) since it last looked, and a command that came is not silence.
                now = time.perf_counter() - t0
                if not self._step_lockstep(self._wait(0.0), now):
                    with self._lock:
                        self._after_tick(fw.tick(now), time.perf_counter())
            self._release()

    def _step_lockstep(self, ready: list[int], now: float) -> bool:
        """Take the input that arrived: one tick per command; return whether one came."""
        commanded = False
        for message in self._read(ready):
            if self._answer(message, now):
                commanded = True
                with self._lock:
                    self._after_tick(self.firmware.tick(now), time.perf_counter())
            elif isinstance(message, protocol.Place):
                self.firmware.apply_pending()
        return commanded


__all__ = ["Emulator", "EmulatorStats", "Faults"]
