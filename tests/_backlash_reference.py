"""Event-located reference solver for the two-body plant with backlash: the test oracle.

An independent, pure-Python/SciPy solution of the motor/load pair joined through a dead band
of total width ``W`` (half gap ``g = W / 2``), following the contract of the backlash spec
(FREE / impact / ENGAGED modes). Like :mod:`_reference` it shares no code with the plant
kernel; it reads the friction laws through :class:`_reference.Law` only.

State: load position ``x`` and velocity ``v``, gap ``d = x_m - x_L`` in ``[-g, g]`` and motor
velocity ``v_m``. The load carries the share ``phi`` of every friction level, of the law's
viscous slope and of the damping ``B``; the motor carries ``1 - phi``. The load's inertia is
``psi J``, the motor's ``(1 - psi) J``; the command acts on the motor only.

Each control period is integrated with :func:`scipy.integrate.solve_ivp` (DOP853) one smooth
piece at a time, restarting at terminal events:

* FREE (state ``x_L, v_L``, gap change ``e = d - d_start``, relative speed ``w = v_m - v_L``):
  each sliding body's stop (``v = 0``) and decay edge (``|v| = v0``), and the contacts
  ``d = +g`` (rising) and ``d = -g`` (falling). A body at rest stays at rest for the whole
  piece, since its input is constant (the load's is 0). A piece that starts on the face the
  bodies just left watches that face through ``e / (t - t_start)^3``, which has no root at the
  start, so a return to the face within the integrator's first step is still located.
* ENGAGED ``sigma`` (state ``x_L, v``, ``d = sigma g``): the pair as one body with the total
  law; events stop, edge and the contact force ``sigma F`` falling through 0 (separation).

At a contact the impact is perfectly inelastic (momentum average). A pair at rest obeys the
rest rules of the spec (pair break-away, motor-alone break-away, or held). ``backlash = 0`` is
a rigid pair: always ENGAGED, never separating, the one-body band at rest.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from _reference import Law
from scipy.integrate import solve_ivp

Controller = Callable[[float, float, float], float]

#: Shapes the reference supports: with these the sliding friction is affine in ``v`` on each
#: branch, so the contact force is monotone along an ENGAGED piece.
SHAPES = ("step", "linear")
MAX_EVENTS = 100  #: events in one control period before the solver gives up


@dataclass
class BacklashResult:
    """Trajectory at the control instants ``t_k = k dt`` (``n + 1`` samples).

    Attributes
    ----------
    t, x, v, gap, motor_v : numpy.ndarray
        Time, load position and velocity, gap ``d = x_m - x_L`` and motor velocity (``n + 1``).
    command : numpy.ndarray
        Held input of each step after saturation and dead zone (``n``).
    friction : numpy.ndarray
        Step-average friction of both bodies (laws' viscous parts included, plant ``B`` not),
        from the momentum balance (``n``).
    contacts : list of float
        Times of impacts and engagements (FREE -> ENGAGED).
    separations : list of float
        Times the engaged pair separated (ENGAGED -> FREE), motor-alone break-aways included.
    engaged : numpy.ndarray
        Whether the pair is ENGAGED at each control instant (``n + 1``).
    """

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    gap: np.ndarray
    motor_v: np.ndarray
    command: np.ndarray
    friction: np.ndarray
    contacts: list[float] = field(default_factory=list)
    separations: list[float] = field(default_factory=list)
    engaged: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))


@dataclass(frozen=True)
class _Body:
    """One side of the pair (or the whole pair): inertia, law and total linear damping."""

    mass: float
    law: Law
    bt: float  #: plant damping share + the law's viscous slope (already scaled)

    def branch(self, v: float, force: float) -> tuple[float, bool] | None:
        """Smooth branch ``(s, inner)`` to integrate on, or ``None`` for at rest all piece.

        At rest the closed band ``[-us_neg, us_pos]`` holds the body; otherwise it breaks away
        toward the force. On the decay edge the outer curve's acceleration decides the side.
        """
        law = self.law
        if v == 0.0:
            if -law.us_neg <= force <= law.us_pos:
                return None
            s = 1.0 if force > 0.0 else -1.0
            return s, law.decays(s)
        s = 1.0 if v > 0.0 else -1.0
        _, uc, v0 = law.side(s)
        if law.decays(s) and s * v == v0:
            return s, s * (force - s * uc - self.bt * v) < 0.0
        return s, law.decays(s) and s * v < v0

    def resist(self, v: float, s: float, inner: bool) -> float:
        """Signed friction + damping ``h(v) = s level(|v|) + bt v`` on the branch."""
        us, uc, v0 = self.law.side(s)
        level = uc + (us - uc) * (1.0 - s * v / v0) if inner else uc
        return s * level + self.bt * v

    def slope(self, s: float, inner: bool) -> float:
        """``dh/dv`` on the branch (constant: the shapes are affine in ``v``)."""
        us, uc, v0 = self.law.side(s)
        return self.bt - ((us - uc) / v0 if inner else 0.0)

    def events(
        self, vel: Callable[[np.ndarray], float], s: float, inner: bool
    ) -> list[tuple[Callable, str]]:
        """Stop and decay-edge events of the velocity ``vel(y)`` on the branch."""
        out: list[tuple[Callable, str]] = []
        law = self.law
        if inner or not law.decays(s):

            def stop(t: float, y: np.ndarray) -> float:
                return vel(y)

            stop.terminal = True  # type: ignore[attr-defined]
            stop.direction = -s  # type: ignore[attr-defined]
            out.append((stop, "stop"))
        if law.decays(s):
            v0 = law.side(s)[2]

            def edge(t: float, y: np.ndarray) -> float:
                return s * vel(y) - v0

            edge.terminal = True  # type: ignore[attr-defined]
            edge.direction = 1.0 if inner else -1.0  # type: ignore[attr-defined]
            out.append((edge, "edge"))
        return out


def _second(y: np.ndarray) -> float:
    """The velocity of a one-body state and the load's of a FREE state."""
    return y[1]


def _motor_v(y: np.ndarray) -> float:
    """The motor's velocity ``v_L + w`` of a FREE state."""
    return y[1] + y[3]


def _scaled(law: Law, share: float) -> Law:
    """The law carried by one body: every level and the viscous slope times ``share``."""
    return Law(
        law.us_pos * share,
        law.us_neg * share,
        law.uc_pos * share,
        law.uc_neg * share,
        law.v0_pos,
        law.v0_neg,
        law.viscous * share,
        law.shape,
    )


@dataclass
class _State:
    """Hybrid state between pieces."""

    x: float  #: load position
    v: float  #: load velocity
    d: float  #: gap x_m - x_L
    vm: float  #: motor velocity
    engaged: bool
    sigma: float  #: face of the contact (+1: d = +g, -1: d = -g); meaningful when engaged


class BacklashReference:
    """Event-located ZOH solution of the motor/load pair with backlash.

    Parameters
    ----------
    inertia, damping : float
        Total ``J`` and plant ``B`` (the law's viscous slope adds to it).
    law : Law or frictiongym friction model
        Total static friction law (shape ``"step"`` or ``"linear"``).
    dt : float
        Control period.
    backlash : float
        Total free play ``W >= 0``; the half gap is ``g = W / 2``. ``0`` is a rigid pair.
    inertia_share : float
        ``psi`` in ``(0, 1)``: the load's inertia is ``psi J``, the motor's ``(1 - psi) J``.
    friction_share : float
        ``phi`` in ``[0, 1]``: the load carries ``phi`` times every level, the viscous slope
        and ``B``; the motor ``1 - phi``.
    command_limit : float
        Symmetric saturation of the command.
    dead_zone : float
        Half-width of the actuator's dead zone, applied after the saturation.
    rtol, atol, max_step : float
        Integrator settings (``max_step`` defaults to ``dt / 4``).

    Attributes
    ----------
    Jm, JL : float
        Motor and load inertias.
    events : list of (float, str)
        Terminal events of the last :meth:`run`, in order: ``"stop"``/``"edge"``/``"sep"``
        (ENGAGED), ``"load-stop"``, ``"motor-edge"``, ... and ``"contact+"``/``"contact-"``
        (FREE).
    """

    def __init__(
        self,
        inertia: float,
        damping: float,
        law: Any,
        dt: float,
        backlash: float,
        inertia_share: float,
        friction_share: float,
        command_limit: float = math.inf,
        dead_zone: float = 0.0,
        rtol: float = 1e-12,
        atol: float = 1e-15,
        max_step: float | None = None,
    ) -> None:
        self.J = float(inertia)
        self.B = float(damping)
        if type(law).__name__ == "Law":  # also a Law imported under another module name
            law = Law(*(getattr(law, f.name) for f in dataclasses.fields(Law)))
        self.law = Law.of(law) if not isinstance(law, Law) else law
        if self.law.shape not in SHAPES:
            raise ValueError(
                f"the backlash reference supports the shapes {SHAPES}, not {self.law.shape!r}"
            )
        self.dt = float(dt)
        self.g = float(backlash) / 2.0
        self.psi = float(inertia_share)
        self.phi = float(friction_share)
        if not self.J > 0.0 or not self.dt > 0.0:
            raise ValueError("inertia and dt must be > 0")
        if not self.g >= 0.0:
            raise ValueError(f"backlash must be >= 0, got {backlash!r}")
        if not 0.0 < self.psi < 1.0:
            raise ValueError(f"inertia_share must lie in (0, 1), got {inertia_share!r}")
        if not 0.0 <= self.phi <= 1.0:
            raise ValueError(f"friction_share must lie in [0, 1], got {friction_share!r}")
        self.umax = float(command_limit)
        self.dead_zone = float(dead_zone)
        self.rtol = rtol
        self.atol = atol
        self.max_step = self.dt / 4 if max_step is None else max_step
        self.Jm = (1.0 - self.psi) * self.J
        self.JL = self.psi * self.J
        law_m, law_l = _scaled(self.law, 1.0 - self.phi), _scaled(self.law, self.phi)
        self.motor = _Body(self.Jm, law_m, (1.0 - self.phi) * self.B + law_m.viscous)
        self.load = _Body(self.JL, law_l, self.phi * self.B + law_l.viscous)
        self.pair = _Body(self.J, self.law, self.B + self.law.viscous)

    # -- helpers ----------------------------------------------------------------------------
    def _solve(
        self, rhs: Callable, t0: float, t1: float, y0: list[float], events: list[Callable]
    ) -> Any:
        sol = solve_ivp(
            rhs,
            (t0, t1),
            y0,
            method="DOP853",
            rtol=self.rtol,
            atol=self.atol,
            max_step=self.max_step,
            events=events or None,
        )
        if sol.status < 0:
            raise RuntimeError(sol.message)
        return sol

    @staticmethod
    def _first_event(sol: Any) -> tuple[int, float, np.ndarray] | None:
        """Index, time and state of the earliest terminal event, or ``None``."""
        if sol.status != 1:
            return None
        te, i = min((te[0], i) for i, te in enumerate(sol.t_events) if len(te))
        return i, te, sol.y_events[i][0]

    def contact_force(self, u: float, v: float, s: float, inner: bool) -> float:
        """``F = psi u + (phi - psi) h(v)``: the motor's push on the load while engaged."""
        return self.psi * u + (self.phi - self.psi) * self.pair.resist(v, s, inner)

    def _engage(self, t: float, st: _State, sigma: float) -> None:
        """Contact at ``d = sigma g``: perfectly inelastic impact, then ENGAGED ``sigma``."""
        if st.vm != st.v:  # no impact when the velocities are already equal
            st.v = (self.Jm * st.vm + self.JL * st.v) / self.J
        st.vm = st.v
        st.d = sigma * self.g
        st.engaged, st.sigma = True, sigma
        self._log_contacts.append(t)

    def _separate(self, t: float, st: _State) -> None:
        st.engaged = False
        st.vm = st.v
        self._log_separations.append(t)

    # -- one ENGAGED piece ------------------------------------------------------------------
    def _engaged_piece(self, t: float, t1: float, st: _State, u: float) -> float:
        """Advance an ENGAGED state to ``t1`` or its first event; return the new time."""
        pair, sigma, rigid = self.pair, st.sigma, self.g == 0.0
        if st.v == 0.0:
            if rigid:
                br = pair.branch(0.0, u)
                if br is None:  # the one-body closed band
                    return t1
            else:
                us_sigma = self.law.side(sigma)[0]
                us_motor_back = self.motor.law.side(-sigma)[0]
                if sigma * u > us_sigma:  # the pair breaks away together toward sigma
                    br = (sigma, self.law.decays(sigma))
                elif -sigma * u > us_motor_back:  # the motor alone leaves the face
                    self._separate(t, st)
                    return t
                else:  # held at rest
                    return t1
        else:
            br = pair.branch(st.v, u)
            assert br is not None
        s, inner = br
        if not rigid and sigma * self.contact_force(u, st.v, s, inner) < 0.0:
            self._separate(t, st)
            return t

        def rhs(_t: float, y: np.ndarray) -> list[float]:
            return [y[1], (u - pair.resist(y[1], s, inner)) / pair.mass]

        evs = pair.events(_second, s, inner)
        acc0 = (u - pair.resist(st.v, s, inner)) / pair.mass
        # F is affine in v on a branch and v is monotone there: the force can only cross 0 if
        # both its slope and the acceleration are nonzero (skip an identically zero F).
        if not rigid and (self.phi - self.psi) * pair.slope(s, inner) != 0.0 and acc0 != 0.0:

            def sep(_t: float, y: np.ndarray) -> float:
                return sigma * self.contact_force(u, y[1], s, inner)

            sep.terminal = True  # type: ignore[attr-defined]
            sep.direction = -1.0  # type: ignore[attr-defined]
            evs.append((sep, "sep"))
        sol = self._solve(rhs, t, t1, [st.x, st.v], [e for e, _ in evs])
        first = self._first_event(sol)
        if first is None:
            st.x, st.v = float(sol.y[0, -1]), float(sol.y[1, -1])
            st.vm = st.v
            return t1
        i, te, ye = first
        st.x, st.v = float(ye[0]), float(ye[1])
        kind = evs[i][1]
        if kind == "stop":
            st.v = 0.0
        elif kind == "edge":
            st.v = s * pair.law.side(s)[2]
        st.vm = st.v
        if kind == "sep":
            self._separate(te, st)
        self.events.append((te, kind))
        return te

    # -- one FREE piece ---------------------------------------------------------------------
    def _free_piece(self, t: float, t1: float, st: _State, u: float) -> float:
        """Advance a FREE state to ``t1`` or its first event; return the new time."""
        g = self.g
        if abs(st.d) == g:
            sigma = 1.0 if st.d > 0.0 else -1.0
            if sigma * (st.vm - st.v) > 0.0:  # at a face and closing: impact now
                self._engage(t, st, sigma)
                return t
        br_m = self.motor.branch(st.vm, u)
        br_l = self.load.branch(st.v, 0.0)
        if br_m is None and br_l is None:  # both held for the rest of the period
            return t1
        motor, load = self.motor, self.load
        # y = [x_L, v_L, e, w]: the gap as e = d - d_ref from its start and the relative speed
        # w = v_m - v_L, both starting at 0.0 so that a piece leaving a face resolves the
        # first tiny separation exactly (on d itself it would round back onto the face and
        # re-trigger the contact).
        d_ref = st.d

        def rhs(_t: float, y: np.ndarray) -> list[float]:
            # a body at rest has zero velocity and acceleration all piece
            a_l = 0.0 if br_l is None else -load.resist(y[1], *br_l) / load.mass
            a_m = 0.0 if br_m is None else (u - motor.resist(y[1] + y[3], *br_m)) / motor.mass
            return [y[1], a_l, y[3], a_m - a_l]

        evs: list[tuple[Callable, str]] = []
        if br_l is not None:
            evs += [(e, f"load-{k}") for e, k in load.events(_second, *br_l)]
        if br_m is not None:
            evs += [(e, f"motor-{k}") for e, k in motor.events(_motor_v, *br_m)]

        # Contacts only from inside (the event directions). A piece that starts on a face (the
        # bodies just separated) has e = 0 there: its contact function is e / (t - t_start)^3,
        # negative from the start whether the gap opens at first, second or third order, so
        # that the start is no root and a quick return to the face is still located (e
        # itself would have a root at the start and hide the return in the same step).
        t_start = t

        def on_face(tt: float, e: float) -> float:
            return -1.0 if tt == t_start else e / (tt - t_start) ** 3

        def hit_pos(tt: float, y: np.ndarray) -> float:
            return on_face(tt, y[2]) if d_ref == g else y[2] - (g - d_ref)

        def hit_neg(tt: float, y: np.ndarray) -> float:
            return -on_face(tt, -y[2]) if d_ref == -g else y[2] + (g + d_ref)

        hit_pos.terminal = hit_neg.terminal = True  # type: ignore[attr-defined]
        hit_pos.direction, hit_neg.direction = 1.0, -1.0  # type: ignore[attr-defined]
        evs += [(hit_pos, "contact+"), (hit_neg, "contact-")]
        y0 = [st.x, st.v, 0.0, st.vm - st.v]
        sol = self._solve(rhs, t, t1, y0, [e for e, _ in evs])
        first = self._first_event(sol)
        if first is None:
            t_end, y, kind = t1, sol.y[:, -1], "end"
        else:
            t_end, y, kind = first[1], first[2], evs[first[0]][1]
        st.x, st.v = float(y[0]), float(y[1])
        st.d, st.vm = d_ref + float(y[2]), float(y[1] + y[3])
        st.d = min(max(st.d, -g), g)  # rounding of d_ref + e only: events keep it inside
        if br_l is None:
            st.v = 0.0
        if br_m is None:
            st.vm = 0.0
        if kind == "end":
            return t1
        if kind == "load-stop":
            st.v = 0.0
        elif kind == "load-edge":
            assert br_l is not None
            st.v = br_l[0] * load.law.side(br_l[0])[2]
        elif kind == "motor-stop":
            st.vm = 0.0
        elif kind == "motor-edge":
            assert br_m is not None
            st.vm = br_m[0] * motor.law.side(br_m[0])[2]
        else:
            self._engage(t_end, st, 1.0 if kind == "contact+" else -1.0)
        self.events.append((t_end, kind))
        return t_end

    # -- one control period -----------------------------------------------------------------
    def period(self, t0: float, st: _State, u: float) -> None:
        """Advance ``st`` in place over ``[t0, t0 + dt]`` with ``u`` held."""
        t1 = t0 + self.dt
        t = t0
        for _ in range(MAX_EVENTS):
            if not t1 - t > 4e-16 * max(1.0, abs(t1)):
                return
            if st.engaged:
                t = self._engaged_piece(t, t1, st, u)
            else:
                t = self._free_piece(t, t1, st, u)
        raise RuntimeError(f"more than {MAX_EVENTS} events in the period starting at t={t0}")

    def _initial(self, x0: float, v0: float, gap0: float, vm0: float) -> _State:
        g = self.g
        st = _State(float(x0), float(v0), float(gap0), float(vm0), False, 1.0)
        if g == 0.0:
            if gap0 != 0.0:
                raise ValueError("a rigid pair (backlash 0) starts with gap0 = 0")
            st.engaged = True
            if st.vm != st.v:  # the rigid pair starts with an impact
                self._engage(0.0, st, 1.0)
            return st
        if not abs(st.d) <= g:
            raise ValueError(f"gap0={gap0!r} lies outside the play [-{g}, {g}]")
        if abs(st.d) == g:
            sigma = 1.0 if st.d > 0.0 else -1.0
            closing = sigma * (st.vm - st.v)
            if closing > 0.0:
                self._engage(0.0, st, sigma)
            elif closing == 0.0:  # on a face with equal velocities: in contact
                st.engaged, st.sigma = True, sigma
        return st

    def _input(self, c: float) -> float:
        """Saturation, then the dead zone."""
        u = min(max(c, -self.umax), self.umax)
        if abs(u) <= self.dead_zone:
            return 0.0
        return u - self.dead_zone if u > 0.0 else u + self.dead_zone

    def run(
        self,
        n_steps: int,
        x0: float = 0.0,
        v0: float = 0.0,
        gap0: float = 0.0,
        motor_v0: float | None = None,
        commands: Sequence[float] | np.ndarray | None = None,
        controller: Controller | None = None,
    ) -> BacklashResult:
        """Simulate ``n_steps`` control periods, open loop (``commands``) or closed loop.

        Parameters
        ----------
        n_steps : int
            Number of control periods.
        x0, v0 : float
            Initial load position and velocity.
        gap0 : float
            Initial gap ``x_m - x_L`` in ``[-g, g]`` (0: the middle of the play).
        motor_v0 : float, optional
            Initial motor velocity (default: ``v0``).
        commands : sequence of float, optional
            Open-loop commands, one per step.
        controller : callable, optional
            ``controller(t, x, v) -> command`` on the load's position and velocity.

        Returns
        -------
        BacklashResult
        """
        if (commands is None) == (controller is None):
            raise ValueError("give exactly one of commands and controller")
        self._log_contacts: list[float] = []
        self._log_separations: list[float] = []
        self.events: list[tuple[float, str]] = []
        st = self._initial(x0, v0, gap0, v0 if motor_v0 is None else motor_v0)
        xs, vs, ds, vms = (np.empty(n_steps + 1) for _ in range(4))
        engaged = np.empty(n_steps + 1, dtype=bool)
        us, fr = np.empty(n_steps), np.empty(n_steps)
        xs[0], vs[0], ds[0], vms[0], engaged[0] = st.x, st.v, st.d, st.vm, st.engaged
        w = self.phi
        for k in range(n_steps):
            t = k * self.dt
            c = float(commands[k]) if controller is None else float(controller(t, st.x, st.v))
            u = self._input(c)
            x, v, xm, vm = st.x, st.v, st.x + st.d, st.vm
            self.period(t, st, u)
            # momentum balance (impacts conserve momentum): friction impulse of both bodies
            dxm, dx = st.x + st.d - xm, st.x - x
            fr[k] = (
                u
                - (
                    self.B * ((1.0 - w) * dxm + w * dx)
                    + self.Jm * (st.vm - vm)
                    + self.JL * (st.v - v)
                )
                / self.dt
            )
            us[k] = u
            xs[k + 1], vs[k + 1], ds[k + 1], vms[k + 1] = st.x, st.v, st.d, st.vm
            engaged[k + 1] = st.engaged
        return BacklashResult(
            np.arange(n_steps + 1) * self.dt,
            xs,
            vs,
            ds,
            vms,
            us,
            fr,
            self._log_contacts,
            self._log_separations,
            engaged,
        )
