"""Nominal plant + friction: parameters and the batched, event-exact ZOH plant.

The plant is ``J x'' + B x' = u - F(x', u)`` with ``u`` the command after saturation,
dead time and an optional first-order actuator lag. :class:`Plant` holds N such plants
(N = 1 for a single env) and steps them all with one call of the compiled kernel.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym._validation import check_finite, check_nonnegative, check_positive
from frictiongym.friction.laws import FrictionModel, LuGre
from frictiongym.plants import _batch as plant_batch
from frictiongym.plants import _kernel as plant_kernel
from frictiongym.plants.threads import PARALLEL_MIN_PLANTS, AdaptiveKernel, Kernel, select_kernel

FloatArray = npt.NDArray[np.float64]

__all__ = ["PARALLEL_MIN_PLANTS", "Plant", "PlantParams", "default_substeps", "plant_row"]


@dataclass(frozen=True)
class PlantParams:
    """Linear part and actuator of a 1-DOF motion-control plant.

    Parameters
    ----------
    inertia : float
        ``J``: inertia (or mass) in command units per acceleration unit (the paper's servo:
        V·s²/rad).
    damping : float
        ``B``: linear damping in command units per velocity unit, not counting the viscous slope
        of the friction law (which adds to it).
    command_limit : float
        Symmetric saturation of the command, command units.
    lag : float, default 0.0
        Time constant of a first-order actuator lag, s (0: none).
    dead_time : float, default 0.0
        Transport delay of the command, s; must be a whole number of control periods.
    end_stop : float, default inf
        Position of a rigid end stop ahead (position units): the body cannot pass it, and
        hitting it stops it dead (inelastic contact, located inside the step). ``inf``: none.
        The Altino env sets it to the wall.
    dead_zone : float, default 0.0
        Half-width of the actuator's dead zone, command units: a command (after saturation
        and dead time) of magnitude up to it drives nothing, a larger one drives
        ``u - dead_zone * sign(u)`` (:func:`~frictiongym.plants._kernel.dead_zone`). 0: none.
    backlash : float, default 0.0
        Free play between the motor and the load, position units (the full width: the motor
        turns this far between the faces without moving the load). 0: a rigid drivetrain.
        With play the plant is two bodies (:mod:`frictiongym.plants._backlash`, docs/physics.md);
        the load is what the position and velocity report. It needs a law with the exact step
        (a static law with a ``step`` or ``linear`` decay).
    load_inertia : float, default 0.5
        The load's share of ``inertia`` (the motor has the rest), in (0, 1). Used only with
        backlash; 0.5 has no source: take it from the drivetrain (the envs set their devices').
    load_friction : float, default 0.5
        The load's share of the friction law's levels and viscous slope and of ``damping``
        (the motor has the rest), in [0, 1]. Used only with backlash; 0.5 has no source either.
    jitter : float, default 0.0
        Varying latency of the drive, s, on top of ``dead_time``: each step's new drive takes
        effect at a uniformly random instant up to ``jitter`` after the step starts, the last
        drive holding until then (a wireless link's loop timing). Below the control period;
        0: none. The draws come from a generator per plant (:meth:`Plant.seed_jitter`).
    """

    inertia: float
    damping: float
    command_limit: float
    lag: float = 0.0
    dead_time: float = 0.0
    end_stop: float = math.inf
    dead_zone: float = 0.0
    backlash: float = 0.0
    load_inertia: float = 0.5
    load_friction: float = 0.5
    jitter: float = 0.0

    def __post_init__(self) -> None:
        check_finite(
            self,
            "inertia",
            "damping",
            "command_limit",
            "lag",
            "dead_time",
            "dead_zone",
            "backlash",
            "load_inertia",
            "load_friction",
            "jitter",
        )
        check_positive(self, "inertia", "command_limit")
        check_nonnegative(self, "damping", "lag", "dead_time", "dead_zone", "backlash", "jitter")
        if not 0.0 < self.load_inertia < 1.0:
            raise ValueError(
                f"PlantParams.load_inertia={self.load_inertia!r} is the load's share of the "
                "inertia: give a fraction strictly between 0 and 1 (both bodies have mass)"
            )
        if not 0.0 <= self.load_friction <= 1.0:
            raise ValueError(
                f"PlantParams.load_friction={self.load_friction!r} is the load's share of the "
                "friction and damping: give a fraction from 0 to 1"
            )
        if not (isinstance(self.end_stop, numbers.Real) and not math.isnan(self.end_stop)):
            raise ValueError(
                f"PlantParams.end_stop must be a position or inf (no stop), got {self.end_stop!r}"
            )
        if self.dead_zone >= self.command_limit:
            raise ValueError(
                f"PlantParams.dead_zone={self.dead_zone!r} leaves no command that drives the "
                f"plant (command_limit={self.command_limit!r}); use a dead zone narrower than "
                "the command limit"
            )

    def delay_steps(self, dt: float) -> int:
        """Dead time in whole control periods of length ``dt``; raises if it is not whole."""
        steps = round(self.dead_time / dt)
        if abs(steps * dt - self.dead_time) > 1e-9 * max(1.0, self.dead_time):
            raise ValueError(
                f"PlantParams.dead_time={self.dead_time!r} s is not a whole number of control "
                f"periods dt={dt!r} s; use a multiple of dt (e.g. {max(steps, 1) * dt!r})"
            )
        return int(steps)


def plant_row(params: PlantParams, friction: FrictionModel) -> FloatArray:
    """Pack plant and friction parameters into one kernel row."""
    plant = (
        params.inertia,
        params.damping,
        params.command_limit,
        params.lag,
        params.end_stop,
        params.dead_zone,
    )
    if params.backlash > 0.0 and not friction.exact:
        raise ValueError(
            f"backlash={params.backlash!r} needs a friction law with the event-exact step (a "
            f"static law with a 'step' or 'linear' decay, or none), got {friction!r}; use such a "
            "law or no backlash"
        )
    drivetrain = (params.backlash / 2.0, params.load_inertia, params.load_friction)
    return plant_kernel.pack_row(plant, friction.row(), drivetrain, params.jitter)


def default_substeps(
    params: Sequence[PlantParams], frictions: Sequence[FrictionModel], dt: float
) -> int:
    """Substeps per control period that the laws and the actuator need.

    One for the exact laws without actuator lag; otherwise enough for the split scheme's
    first-order error, for a lag sampled well inside its time constant, and for a stable
    LuGre bristle mode (``h_sub * omega_n <= 0.2``, ``h_sub * sigma1 / J <= 0.2``).
    """
    n = 1
    for pp in params:
        if pp.lag > 0.0:
            n = max(n, math.ceil(4.0 * dt / pp.lag))
    for fr in frictions:
        if not fr.exact and not fr.is_dynamic:
            n = max(n, 10)
        if isinstance(fr, LuGre):
            j_min = min(pp.inertia for pp in params)
            omega = math.sqrt(float(fr.sigma0) / j_min)
            n = max(n, math.ceil(dt * omega / 0.2), math.ceil(dt * float(fr.sigma1) / j_min / 0.2))
    return n


def _entry_point(kernel: Kernel, args: tuple[Any, ...]) -> Kernel:
    """Return the compiled code of a numba kernel for the types of ``args``, or the kernel.

    For a plain numba kernel that has been compiled for these types (an
    :class:`~frictiongym.plants.threads.AdaptiveKernel` calls its twins through their
    dispatchers); anything unexpected keeps the dispatcher.
    """
    overloads = getattr(kernel, "overloads", None)
    if not isinstance(overloads, dict):
        return kernel
    import numba  # the kernels are numba's: imported already

    try:
        entry: Kernel = overloads[tuple(numba.typeof(a) for a in args)].entry_point
    except (AttributeError, KeyError, ValueError):  # no such code, or a type numba lacks
        return kernel
    return entry


class Plant:
    """N plants stepped together by a compiled batch kernel: the package's one plant core.

    Parameters
    ----------
    params : PlantParams or sequence of PlantParams
        One set for all plants, or one per plant.
    friction : FrictionModel or sequence of FrictionModel
        One law for all plants, or one per plant.
    dt : float
        Control period, s: the command is held over it.
    num_plants : int, default 1
        Batch size N.
    substeps : int, optional
        Substeps per control period; by default :func:`default_substeps`.
    parallel : bool, optional
        ``True`` steps the batch on numba's threads, ``False`` on one; results are bit-identical
        either way. By default (``None``) batches of ``PARALLEL_MIN_PLANTS`` plants or more time
        their calls and use whichever is faster at the moment
        (:class:`~frictiongym.plants.threads.AdaptiveKernel`), so threads help on an idle
        machine and step aside beside a learner; smaller batches run on one thread.
    task_columns : int, default 0
        Further state columns per plant for a task kernel (the env kernel keeps its step count,
        estimates and reference there).
    kernels : (Kernel, Kernel), optional
        The serial and threaded batch kernels: by default the plant kernel's
        (:func:`~frictiongym.plants._batch.step_batch`); a task kernel such as
        :func:`~frictiongym.envs._kernel.step_envs` takes the same first seven arguments and
        steps the plant inside its own loop.

    Notes
    -----
    The state lives in one ``(11 + task_columns, N)`` float64 array (:attr:`state`, one row per
    quantity, its index in :mod:`frictiongym.plants._kernel`); the properties below are views
    into it.
    """

    dt: float
    num_plants: int
    substeps: int
    delay_steps: int
    parallel: bool
    #: Slot of :attr:`delay_buffer` holding the command due now.
    head: int
    _step_kernel: Kernel
    _serial: Kernel

    def __init__(
        self,
        params: PlantParams | Sequence[PlantParams],
        friction: FrictionModel | Sequence[FrictionModel],
        dt: float,
        num_plants: int = 1,
        substeps: int | None = None,
        parallel: bool | None = None,
        *,
        task_columns: int = 0,
        kernels: tuple[Kernel, Kernel] = (
            plant_batch.step_batch,
            plant_batch.step_batch_parallel,
        ),
    ) -> None:
        if not (isinstance(dt, numbers.Real) and math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be a finite positive number of seconds, got {dt!r}")
        if not isinstance(num_plants, numbers.Integral) or num_plants < 1:
            raise ValueError(f"num_plants must be a positive integer, got {num_plants!r}")
        self.dt = float(dt)
        self.num_plants = int(num_plants)
        self._params: list[PlantParams] = self._per_plant(params, "params", PlantParams)
        frictions: list[FrictionModel] = self._per_plant(friction, "friction", FrictionModel)
        late = max(p.jitter for p in self._params)
        if late >= self.dt:
            raise ValueError(
                f"PlantParams.jitter={late!r} s reaches the control period dt={self.dt!r} s: a "
                "drive would take effect after the next one is due; use a jitter below dt (a "
                "whole period more latency is dead_time)"
            )
        delays = {p.delay_steps(self.dt) for p in self._params}
        if len(delays) > 1:
            raise ValueError("all plants of a batch must share one dead time")
        self.delay_steps = delays.pop()
        if substeps is None:
            substeps = default_substeps(self._params, frictions, self.dt)
        if not isinstance(substeps, numbers.Integral) or substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
        self.substeps = int(substeps)
        count = max(len(self._params), len(frictions))
        pairs = zip(
            self._params * (count // len(self._params)),
            frictions * (count // len(frictions)),
            strict=True,
        )
        self.rows: FloatArray = np.ascontiguousarray(np.stack([plant_row(p, f) for p, f in pairs]))
        self.prime_rows()
        self._serial = kernels[0]
        self._step_kernel = select_kernel(*kernels, self.num_plants, parallel)
        #: whether the threaded kernel may run (always, or when the adaptive choice picks it)
        self.parallel = self._step_kernel is not self._serial
        #: One row per state column, one entry per plant: the kernel reads each column as a
        #: contiguous vector (a plant per entry), which lets its common path run in SIMD lanes.
        self.state: FloatArray = np.zeros((plant_kernel.STATE_SIZE + task_columns, self.num_plants))
        #: Commands in flight over the dead time, ``(delay_steps, N)``.
        self.delay_buffer: FloatArray = np.zeros((self.delay_steps, self.num_plants))
        self.head = 0
        self.reset()

    def _per_plant(self, value: Any, name: str, kind: type) -> list[Any]:
        values = [value]
        if isinstance(value, Sequence) and not isinstance(value, str):
            if len(value) != self.num_plants:
                raise ValueError(
                    f"{name} has {len(value)} entries for {self.num_plants} plants; give one "
                    "for all or one per plant"
                )
            values = list(value)
        for item in values:
            if not isinstance(item, kind):
                hint = (
                    " (build one by name with frictiongym.friction.friction_from_name, or use a "
                    "preset such as ROTARY_PAPER)"
                    if kind is FrictionModel
                    else ""
                )
                raise TypeError(f"{name} must be a {kind.__name__}, got {item!r}{hint}")
        return values

    @property
    def params(self) -> list[PlantParams]:
        """Plant parameters (one entry when shared by the whole batch)."""
        return list(self._params)

    def own_rows(self) -> None:
        """Give every plant its own parameter row (to change them one by one), if they share one."""
        if self.rows.shape[0] == 1 < self.num_plants:
            self.rows = np.repeat(self.rows, self.num_plants, axis=0)

    def prime_rows(self, mask: npt.ArrayLike | None = None) -> None:
        """Refill the coefficient cache of the parameter rows (all, or those of ``mask``).

        Call it after writing :attr:`rows`: a row whose cache no longer matches its parameters
        steps slower (never differently) until it is primed.
        """
        if mask is None or self.rows.shape[0] == 1:
            plant_kernel.prime_rows(self.rows, self.dt / self.substeps)
            return
        idx = np.flatnonzero(self._selection(mask))
        rows = self.rows[idx]
        plant_kernel.prime_rows(rows, self.dt / self.substeps)
        self.rows[idx] = rows

    def keep(self, mask: npt.ArrayLike) -> None:
        """Drop the plants where ``mask`` is false; the others go on exactly as before.

        The kept plants keep their state, parameters and commands in flight. A batch that
        shrinks below ``PARALLEL_MIN_PLANTS`` steps serially from then on; otherwise it keeps its
        kernel and, if adaptive, what the kernel's timings have learnt (scaled to the new size).
        """
        keep = np.asarray(mask, dtype=bool)
        if keep.shape != (self.num_plants,):
            raise ValueError(f"mask must have shape ({self.num_plants},), got {keep.shape}")
        idx = np.flatnonzero(keep)
        if idx.size == 0:
            raise ValueError("keep() must keep at least one plant")
        if len(self._params) > 1:
            self._params = [self._params[i] for i in idx]
        if self.rows.shape[0] > 1:
            self.rows = np.ascontiguousarray(self.rows[idx])
        self.state = np.ascontiguousarray(self.state[:, idx])
        self.delay_buffer = np.ascontiguousarray(self.delay_buffer[:, idx])
        size, self.num_plants = self.num_plants, int(idx.size)
        kernel = self._step_kernel
        if isinstance(kernel, AdaptiveKernel) and self.num_plants < PARALLEL_MIN_PLANTS:
            self._step_kernel, self.parallel = self._serial, False
        elif isinstance(kernel, AdaptiveKernel):
            kernel.rescale(self.num_plants / size)

    def _selection(self, mask: npt.ArrayLike | None) -> npt.NDArray[np.bool_]:
        if mask is None:
            return np.ones(self.num_plants, dtype=bool)
        selection = np.ascontiguousarray(mask, dtype=bool)
        if selection.shape != (self.num_plants,):
            raise ValueError(f"mask must have shape ({self.num_plants},), got {selection.shape}")
        return selection

    def reset(
        self,
        position: float | npt.ArrayLike = 0.0,
        velocity: float | npt.ArrayLike = 0.0,
        mask: npt.ArrayLike | None = None,
    ) -> None:
        """Reset plants (all, or those where ``mask`` is true) to a state at ``position``.

        A velocity of exactly 0.0 starts the plant stuck; the actuator lag, dead-time buffer
        and LuGre bristles start relaxed (zero).
        """
        selected = self._selection(mask)
        count = int(np.count_nonzero(selected))
        pos = np.broadcast_to(np.asarray(position, dtype=np.float64), count)
        vel = np.broadcast_to(np.asarray(velocity, dtype=np.float64), count)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
            raise ValueError("reset position and velocity must be finite")
        beyond = pos > np.broadcast_to(plant_kernel.end_stops(self.rows), self.num_plants)[selected]
        if np.any(beyond):
            raise ValueError(
                f"reset position {pos[beyond][0]!r} lies beyond the plant's end stop; "
                "start at or before it"
            )
        start = (np.ascontiguousarray(pos), np.ascontiguousarray(vel))
        plant_kernel.reset_plants(selected, self.state, self.delay_buffer, *start)
        jittery = np.broadcast_to(self.rows[:, plant_kernel.I_JITTER] > 0.0, self.num_plants)
        seeded = selected & jittery  # a stream per plant with a jitter; 0 elsewhere
        self._column("jitter_rng")[seeded] = np.flatnonzero(seeded)

    def seed_jitter(self, seeds: npt.ArrayLike, mask: npt.ArrayLike | None = None) -> None:
        """Set the jitter generators of plants (all, or those of ``mask``) to ``seeds``.

        ``seeds`` holds integers from 0 to 2**52 - 1, one per selected plant or one for all.
        :meth:`reset` reseeds plant ``i`` (if it has a jitter) with ``i``, so call this after
        it; the envs draw their seeds from their own generators at each reset.
        """
        selected = self._selection(mask)
        count = int(np.count_nonzero(selected))
        try:
            values = np.broadcast_to(np.asarray(seeds, dtype=np.float64), count)
        except (TypeError, ValueError):
            raise ValueError(
                f"jitter seeds must be one integer or {count} (one per selected plant), "
                f"got {seeds!r}"
            ) from None
        if not np.all((values >= 0) & (values < 2**52) & (values == np.floor(values))):
            raise ValueError("jitter seeds must be integers from 0 to 2**52 - 1")
        self._column("jitter_rng")[selected] = values

    def place(
        self, position: float, *, stop: bool = False, mask: npt.ArrayLike | None = None
    ) -> None:
        """Move plants to ``position``, the rest of their state kept; ``stop`` also halts them.

        An encoder reset moves the origin (the disk's dynamics do not depend on its angle); an
        inelastic stop (``stop=True``) leaves the body stuck there at rest.
        """
        selected = self._selection(mask)
        self._column("position")[selected] = position
        if stop:
            self._column("velocity")[selected] = 0.0
            self._column("motor_velocity")[selected] = 0.0  # with backlash: both bodies
            self._column("stuck")[selected] = 1.0

    def step(self, command: float | npt.ArrayLike) -> None:
        """Hold ``command`` over one control period for every plant.

        Parameters
        ----------
        command : float or array_like, shape (N,)
            Commands in command units; saturated at ``command_limit``.

        Raises
        ------
        ValueError
            If a command is NaN or infinite (no plant is changed).
        """
        u = np.asarray(command, dtype=np.float64).reshape(-1)
        if u.shape[0] not in (1, self.num_plants):
            raise ValueError(f"expected 1 or {self.num_plants} commands, got {u.shape[0]}")
        bad = self.run(u)
        if bad >= 0:
            raise ValueError(
                f"command {bad} is {float(u[bad])!r}: commands must be finite numbers "
                "(command units)"
            )

    def run(self, command: npt.NDArray[np.floating[Any]], *task: Any) -> int:
        """Call the batch kernel once, then advance the dead time by one period.

        ``task`` follows the plant's arguments for a task kernel (see ``kernels``). Returns -1,
        or the index of the first non-finite command, in which case nothing changed.
        """
        args = (self.state, self.delay_buffer, self.head, command, self.dt, self.substeps)
        bad: int = self._step_kernel(*args, self.rows, *task)
        if bad < 0 and self.delay_steps:
            self.head = (self.head + 1) % self.delay_steps
        return bad

    def bind(
        self,
        command: npt.NDArray[np.floating[Any]],
        *task: Any,
        refuse: Callable[[int], object] | None = None,
    ) -> Callable[[], int]:
        """Return a function that does :meth:`run` with these very arrays, in less time.

        A call through numba's dispatcher types every argument first: about 0.35 µs for the
        env kernel's 14 arguments as they were when measured (16 now), a third of a single
        env's kernel call. The arrays bound here (and the plant's own, which keep their types)
        have the same types at every call, so after a first call through the dispatcher, which
        compiles or loads the code, the function calls the compiled entry point for those types
        directly, with the arguments built once (again only when the kernel, the state, the
        rows or the dead time's head changed). The caller writes each command into ``command``
        in place. ``refuse`` is called with the index of a non-finite command (it should
        raise); without it the function returns that index, as :meth:`run` does.
        """
        # the kernel, the state and rows the call was built for, its entry point and arguments
        bound: list[Any] = [None, None, None, None, ()]

        def run() -> int:
            kernel, state, rows, head = self._step_kernel, self.state, self.rows, self.head
            if kernel is bound[0] and state is bound[1] and rows is bound[2]:
                args = bound[4]
                if head != args[2]:  # a dead time of several periods moves its head each step
                    args = bound[4] = (*args[:2], head, *args[3:])
                bad: int = bound[3](*args)
            else:
                args = (
                    state,
                    self.delay_buffer,
                    head,
                    command,
                    self.dt,
                    self.substeps,
                    rows,
                    *task,
                )
                bad = kernel(*args)
                bound[:] = [kernel, state, rows, _entry_point(kernel, args), args]
            if bad >= 0:
                if refuse is not None:
                    refuse(bad)
                return bad
            if self.delay_steps:
                self.head = (head + 1) % self.delay_steps
            return bad

        return run

    def _column(self, name: str) -> FloatArray:
        return self.state[plant_kernel.COLUMNS[name]]

    @property
    def position(self) -> FloatArray:
        """Positions, shape (N,); the load's, with backlash."""
        return self._column("position")

    @property
    def velocity(self) -> FloatArray:
        """Velocities, shape (N,); exactly 0.0 while stuck; the load's, with backlash."""
        return self._column("velocity")

    @property
    def gap(self) -> FloatArray:
        """With backlash, the motor's offset from the middle of the play, in ``±backlash / 2``."""
        return self._column("gap")

    @property
    def motor_velocity(self) -> FloatArray:
        """With backlash, the motor's velocity (the load's while the pair is engaged).

        A plant without play does not keep it up to date (it holds the reset's velocity): read
        :attr:`velocity` there.
        """
        return self._column("motor_velocity")

    @property
    def stuck(self) -> npt.NDArray[np.bool_]:
        """Whether each plant ended the last step stuck (with backlash: both bodies at rest)."""
        return self._column("stuck") != 0.0

    @property
    def command(self) -> FloatArray:
        """Last commands after saturation."""
        return self._column("command")

    @property
    def friction_force(self) -> FloatArray:
        """Friction force averaged over the last step (nonlinear + the law's viscous part)."""
        return self._column("friction_force")
