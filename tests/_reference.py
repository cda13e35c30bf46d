"""Event-located reference solver for the stick/slip plant: the test oracle.

An independent, pure-Python/SciPy solution of ``J x'' + B x' = u - F(x', u)`` with the
command ``u`` held over each control period (ZOH), following the hybrid (Filippov) semantics
of docs/physics.md with event-located ``solve_ivp`` pieces. It shares no code with
:mod:`frictiongym.plants._kernel`; it only reads the public fields of the friction-law
dataclasses.

Modes: SLIDE+ (v > 0), SLIDE- (v < 0), STUCK (v == 0.0 exactly). Each control period is
integrated with :func:`scipy.integrate.solve_ivp` (DOP853, rtol 1e-12) one smooth piece at a
time, restarting at terminal events:

* sliding: ``v = 0`` (stop), and, for the decaying shapes, ``|v| = v0`` (the end of the
  decay range, where the friction curve has a kink);
* stuck with a position- or time-dependent load: the external force reaching ``+us_pos`` or
  ``-us_neg``.

At a stop the velocity is set to 0.0 and the external force decides (§4.2): inside the closed
band ``[-us_neg, us_pos]`` the body sticks, otherwise it reverses at once.

A controller in the loop is any callable ``controller(t, x, v) -> command``, called once at
each control instant.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

Controller = Callable[[float, float, float], float]
Load = Callable[[float, float], float]

_LN100 = math.log(100.0)


def phi(r: float, shape: str) -> float:
    """Decay shape on the decay range, analytic (not clipped at r = 1)."""
    if shape == "linear":
        return 1.0 - r
    if shape == "smooth":
        return 1.0 - 10.0 * r**3 + 15.0 * r**4 - 6.0 * r**5
    if shape == "exponential":
        return (math.exp(-_LN100 * r) - 0.01) / 0.99
    raise ValueError(f"no decay range for shape {shape!r}")


@dataclass(frozen=True)
class Law:
    """Static friction law in command units (levels are magnitudes)."""

    us_pos: float
    us_neg: float
    uc_pos: float
    uc_neg: float
    v0_pos: float = 1.0
    v0_neg: float = 1.0
    viscous: float = 0.0
    shape: str = "step"

    @classmethod
    def of(cls, model: Any) -> Law:
        """Read a frictiongym law through its public fields only."""
        kind = type(model).__name__
        if kind == "NoFriction":
            return cls(0.0, 0.0, 0.0, 0.0)
        if kind == "CoulombViscous":
            uc_pos, uc_neg = model.uc_pos, model.uc_neg
            return cls(uc_pos, uc_neg, uc_pos, uc_neg, viscous=model.viscous)
        if kind == "StictionCoulomb":
            names = ("us_pos", "us_neg", "uc_pos", "uc_neg", "v0_pos", "v0_neg", "viscous", "shape")
            return cls(*(getattr(model, name) for name in names))
        raise TypeError(f"the reference solver has no static law for {kind}")

    def side(self, s: float) -> tuple[float, float, float]:
        """``(us, uc, v0)`` of the direction ``s``."""
        if s > 0:
            return self.us_pos, self.uc_pos, self.v0_pos
        return self.us_neg, self.uc_neg, self.v0_neg

    def decays(self, s: float) -> bool:
        """Whether the level falls over a speed range (a kink at ``|v| = v0``)."""
        us, uc, _ = self.side(s)
        return self.shape != "step" and us > uc

    def level(self, speed: float, s: float) -> float:
        """Sliding level magnitude at ``speed > 0`` (for checking the reference itself)."""
        us, uc, v0 = self.side(s)
        if not self.decays(s) or speed >= v0:
            return uc
        return uc + (us - uc) * phi(speed / v0, self.shape)


@dataclass
class Result:
    """Trajectory at the control instants ``t_k = k dt`` (``n + 1`` samples)."""

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    command: np.ndarray  #: held command of step k (length n)
    friction: np.ndarray  #: step-average friction of step k, law's viscous part included
    stops: list[float] = field(default_factory=list)  #: times of stop events (v -> 0)
    breakaways: list[float] = field(default_factory=list)  #: times of leaving rest

    @property
    def stuck(self) -> np.ndarray:
        """Stuck flag at each control instant."""
        return self.v == 0.0


class ReferencePlant:
    """Event-located ZOH solution of ``J x'' + B x' = u + load(t, x) - F``.

    Parameters
    ----------
    inertia, damping : float
        ``J`` and the plant's ``B`` (the law's viscous slope adds to it).
    law : Law or frictiongym friction model
    dt : float
        Control period.
    command_limit : float
        Symmetric saturation of the command.
    dead_zone : float
        Half-width of the actuator's dead zone (applied after the saturation): the drive is
        zero inside it and the command less the half-width, toward zero, outside.
    load : callable, optional
        Extra external force ``load(t, x)`` (e.g. a spring); it makes the stuck mode end
        on an event inside the period.
    rtol, atol, max_step : float
        Integrator settings (``max_step`` defaults to ``dt / 4``).
    """

    def __init__(
        self,
        inertia: float,
        damping: float,
        law: Any,
        dt: float,
        command_limit: float = math.inf,
        dead_zone: float = 0.0,
        load: Load | None = None,
        rtol: float = 1e-12,
        atol: float = 1e-15,
        max_step: float | None = None,
    ) -> None:
        self.J = float(inertia)
        self.B = float(damping)
        self.law = law if isinstance(law, Law) else Law.of(law)
        self.dt = float(dt)
        self.umax = float(command_limit)
        self.dead_zone = float(dead_zone)
        self.load = load
        self.rtol = rtol
        self.atol = atol
        self.max_step = self.dt / 4 if max_step is None else max_step
        self.b_total = self.B + self.law.viscous

    # -- one smooth piece -------------------------------------------------------------------
    def _external(self, t: float, x: float, u: float) -> float:
        return u if self.load is None else u + self.load(t, x)

    def _slide(
        self, t0: float, t1: float, x: float, v: float, s: float, inner: bool, u: float
    ) -> tuple[float, float, float, str]:
        """Slide in direction ``s`` on one smooth branch until ``t1`` or the first event."""
        us, uc, v0 = self.law.side(s)
        shape, J, bt = self.law.shape, self.J, self.b_total

        def rhs(t: float, y: np.ndarray) -> list[float]:
            vv = y[1]
            lev = uc + (us - uc) * phi(s * vv / v0, shape) if inner else uc
            return [vv, (self._external(t, y[0], u) - s * lev - bt * vv) / J]

        events = []
        kinds = []
        if inner or not self.law.decays(s):

            def stop(t: float, y: np.ndarray) -> float:
                return y[1]

            stop.terminal = True
            stop.direction = -s
            events.append(stop)
            kinds.append("stop")
        if self.law.decays(s):

            def edge(t: float, y: np.ndarray) -> float:
                return s * y[1] - v0

            edge.terminal = True
            edge.direction = 1.0 if inner else -1.0
            events.append(edge)
            kinds.append("edge")
        sol = solve_ivp(
            rhs,
            (t0, t1),
            [x, v],
            method="DOP853",
            rtol=self.rtol,
            atol=self.atol,
            max_step=self.max_step,
            events=events,
        )
        if sol.status < 0:
            raise RuntimeError(sol.message)
        if sol.status == 1:
            first = min((te[0], i) for i, te in enumerate(sol.t_events) if len(te))
            i = first[1]
            te, ye = sol.t_events[i][0], sol.y_events[i][0]
            if kinds[i] == "stop":
                return te, ye[0], 0.0, "stop"
            return te, ye[0], s * v0, "edge"
        return t1, sol.y[0, -1], sol.y[1, -1], "end"

    def _stuck(self, t0: float, t1: float, x: float, u: float) -> tuple[float, str]:
        """Stay at rest until ``t1`` or the external force leaves the band."""
        us_pos, us_neg = self.law.us_pos, self.law.us_neg
        if self.load is None:
            return t1, "end"

        def up(t: float, y: np.ndarray) -> float:
            return self._external(t, x, u) - us_pos

        def down(t: float, y: np.ndarray) -> float:
            return self._external(t, x, u) + us_neg

        up.terminal = down.terminal = True
        up.direction, down.direction = 1.0, -1.0
        sol = solve_ivp(
            lambda t, y: [0.0],
            (t0, t1),
            [x],
            rtol=self.rtol,
            atol=self.atol,
            max_step=self.max_step,
            events=[up, down],
        )
        if sol.status == 1:
            te = min(t[0] for t in sol.t_events if len(t))
            return te, "break"
        return t1, "end"

    # -- one control period -----------------------------------------------------------------
    def period(self, t0: float, x: float, v: float, u: float) -> tuple[float, float]:
        """Advance the state over ``[t0, t0 + dt]`` with ``u`` held; log events."""
        t1 = t0 + self.dt
        t = t0
        law = self.law
        guard = 0
        while t1 - t > 4e-16 * max(1.0, abs(t1)):
            guard += 1
            if guard > 50:
                raise RuntimeError(f"too many events in one period at t={t0}")
            if v == 0.0:
                f_ext = self._external(t, x, u)
                if -law.us_neg <= f_ext <= law.us_pos:  # STUCK (§4.2: closed band)
                    t, how = self._stuck(t, t1, x, u)
                    if how == "end":
                        break
                    f_ext = self._external(t, x, u)
                s = 1.0 if f_ext > 0.0 else -1.0
                self._log_breakaways.append(t)
                inner = law.decays(s)
            else:
                s = 1.0 if v > 0.0 else -1.0
                _, _, v0 = law.side(s)
                inner = law.decays(s) and s * v < v0
                if law.decays(s) and s * v == v0:  # on the kink: go where the curve sends it
                    _us, uc, _ = law.side(s)
                    acc = self._external(t, x, u) - s * uc - self.b_total * v
                    inner = s * acc < 0.0
            t, x, v, how = self._slide(t, t1, x, v, s, inner, u)
            if how == "stop":
                self._log_stops.append(t)
        return x, v

    def run(
        self,
        n_steps: int,
        x0: float = 0.0,
        v0: float = 0.0,
        commands: Sequence[float] | np.ndarray | None = None,
        controller: Controller | None = None,
    ) -> Result:
        """Simulate ``n_steps`` control periods, open loop (``commands``) or closed loop."""
        if (commands is None) == (controller is None):
            raise ValueError("give exactly one of commands and controller")
        xs = np.empty(n_steps + 1)
        vs = np.empty(n_steps + 1)
        us = np.empty(n_steps)
        fr = np.empty(n_steps)
        self._log_stops: list[float] = []
        self._log_breakaways: list[float] = []
        x, v = float(x0), float(v0)
        xs[0], vs[0] = x, v
        for k in range(n_steps):
            t = k * self.dt
            c = float(commands[k]) if controller is None else float(controller(t, x, v))
            u = min(max(c, -self.umax), self.umax)
            if abs(u) <= self.dead_zone:
                u = 0.0
            else:
                u -= self.dead_zone if u > 0.0 else -self.dead_zone
            x1, v1 = self.period(t, x, v, u)
            # momentum balance: integral of friction (law incl. its viscous part) over the step
            fr[k] = u - (self.B * (x1 - x) + self.J * (v1 - v)) / self.dt
            x, v = x1, v1
            xs[k + 1], vs[k + 1], us[k] = x, v, u
        return Result(
            np.arange(n_steps + 1) * self.dt, xs, vs, us, fr, self._log_stops, self._log_breakaways
        )


# -- controllers shared by the reference and the kernel runs ---------------------------------
@dataclass
class PID:
    """Discrete PID on the position error ``e = r(t) - x``, derivative on measured velocity.

    ``u_k = Kp e_k + Ki I_k - Kd v_k`` with ``I_{k+1} = I_k + e_k dt`` (forward Euler); the
    reference ``r`` is a constant or a function of time.
    """

    kp: float
    ki: float = 0.0
    kd: float = 0.0
    reference: float | Callable[[float], float] = 0.0
    dt: float = 1e-3
    integral: float = 0.0

    def __call__(self, t: float, x: float, v: float) -> float:
        r = self.reference(t) if callable(self.reference) else self.reference
        e = r - x
        u = self.kp * e + self.ki * self.integral - self.kd * v
        self.integral += e * self.dt
        return u
