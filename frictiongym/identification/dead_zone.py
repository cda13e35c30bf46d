"""An actuator dead zone, estimated from the reversal test.

**Why the other experiments cannot see it.** A dead zone of half-width ``d`` sends
``u - d sign(u)`` to the plant (docs/physics.md, "Dead zone"). While the command drives the
body in the direction it moves, which every ramp, level and step of the identification does,
that is friction levels raised by ``d``: the rigid identification reports ``u_s + d`` and
``u_c + d`` in each direction, with ``J``, ``B`` and the decay speeds unchanged.

**What the reversal test adds.** After a reversal the command brakes the body: the zone
weakens the braking command by ``d`` while friction brakes by its own level, so the body runs
on by more than raised levels would let it, a difference of ``2 d`` in the braking force. So
the recorded reversal run (:meth:`~frictiongym.identification.experiments.Runner.reversals`)
is replayed on plants with candidate zones ``d``, each with the rigid levels lowered by ``d``
(which leaves every driven experiment as it was), and ``d`` is fitted as the play's width is
(:func:`~frictiongym.identification.backlash.fit_scalar`): grids, a bounded minimisation, the
reversals' scatter for the standard error, and a resolution bound of one sensor step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.optimize import minimize

from frictiongym import devices
from frictiongym.controllers.rollout import Rollout
from frictiongym.friction import StictionCoulomb
from frictiongym.identification.backlash import (
    NO_WINDOWS,
    FloatArray,
    ReversalData,
    ReversalEstimate,
    ReversalPlan,
    fit_scalar,
    replay,
)
from frictiongym.identification.refine import LinearReading, Reading
from frictiongym.params import DeviceParams, device_physics
from frictiongym.plants.plant import PlantParams

LEVELS = ("us_pos", "us_neg", "uc_pos", "uc_neg")


@dataclass(frozen=True, kw_only=True)
class DeadZoneEstimate(ReversalEstimate):
    """The dead zone fitted to a reversal run: its half-width ``d``, command units."""

    play: float  #: the play held during the fit (0: none)

    def describe(self) -> str:
        """One line: the half-width and its standard error, or the bound."""
        held = (
            f", with the play of {self.play:.4g} held (a play and a zone trade off: wide plays "
            "bias the zone, and its bound holds for this play only; docs/identification.md)"
            if self.play
            else ""
        )
        detail = (
            "(half-width; 1 s.e. of the noise, not of the rigid model's errors), the friction "
            "levels lowered by it"
        )
        return self._describe("dead zone", "d", detail, held)

    def record(self) -> dict[str, Any]:
        """Metadata of the estimate for the parameter file."""
        return {**super().record(), "play_held": self.play}

    def apply(self, params: DeviceParams) -> DeviceParams:
        """Return ``params`` (the rigid identification) with this zone, if it is resolved.

        The levels become the friction's own (each lowered by ``d``) and the file gains
        ``dead_zone``: every driven experiment behaves as before, braking as measured.
        """
        if not self.resolved:
            return params
        if params.dead_zone:
            raise ValueError(
                "these parameters already hold a dead zone: apply it to the ones without"
            )
        if params.law != "paper" or not params.friction.exact:
            raise ValueError(
                "the zone was fitted with the paper law of a linear or step decay, not "
                f"{params.friction!r}"
            )
        return replace(
            params,
            friction=without_zone(params.friction, self.width),
            dead_zone=self.width,
            uncertainty={
                **params.uncertainty,
                **({"dead_zone": self.stderr} if math.isfinite(self.stderr) else {}),
            },
        )


def without_zone(law: Any, width: float) -> StictionCoulomb:
    """Return the paper law ``law`` with each break-away and Coulomb level lowered by ``width``."""
    if not isinstance(law, StictionCoulomb):
        raise ValueError(f"the dead-zone fit lowers the paper law's levels, got {law!r}")
    return law.replace(**{k: getattr(law, k) - width for k in LEVELS})  # type: ignore[return-value]


def estimate_dead_zone(
    trace: Rollout,
    rigid: DeviceParams,
    plan: ReversalPlan,
    *,
    dt: float,
    reading: Reading | None = None,
    dead_time: float | None = None,
) -> DeadZoneEstimate:
    """Fit a dead zone's half-width to a reversal run (the module's description).

    Parameters
    ----------
    trace : Rollout
        The reversal run (:meth:`Runner.reversals`).
    rigid : DeviceParams
        The identification without a zone (the paper law; a ``backlash`` in it is held).
    plan : ReversalPlan
        Grid and sensor step; the search runs from 0 to the lower Coulomb level.
    dt, reading, dead_time
        As :func:`~frictiongym.identification.backlash.estimate_backlash`.

    Raises
    ------
    ValueError
        If the run holds no reversal, the law is not the paper's with the event-exact step,
        or ``rigid`` names no device.
    """
    if rigid.dead_zone:
        raise ValueError("the identification already holds a dead zone: give the one without")
    device, law, base = _replayed(rigid, dt, dead_time)
    data = ReversalData(trace, reading or LinearReading())
    if not data.windows:
        raise ValueError(NO_WINDOWS)
    # A zone at least the lower Coulomb level would leave a level negative.
    high = 0.999 * min(law.uc_pos, law.uc_neg)

    def simulate(widths: FloatArray) -> FloatArray:
        params = [replace(base, dead_zone=float(d)) for d in widths]
        laws = [without_zone(law, float(d)) for d in widths]
        return replay(data.command, params, laws, dt)

    fit = fit_scalar(
        data,
        simulate,
        plan,
        high,
        "the zone would reach the lower Coulomb level",
        device.command_unit,
    )
    return DeadZoneEstimate(
        **fit.fields(search=(0.0, high), unit=device.command_unit, trace=trace),
        play=base.backlash,
    )


def joint_start(
    trace: Rollout,
    rigid: DeviceParams,
    plan: ReversalPlan,
    shares: tuple[float, float],
    *,
    dt: float,
    reading: Reading | None = None,
    dead_time: float | None = None,
) -> tuple[float, float]:
    """Return the play's width and the zone's half-width that best fit the run together.

    Both weaken the braking after a reversal (the zone its force, the play its start), so a
    fit of one with the other absent takes up both, and alternating one-dimensional fits
    creep along the valley between them. A coarse grid over both (``plan.grid`` squared,
    capped at 21 a side), a fine grid around its best point and a simplex polish find the
    valley's minimum; the one-dimensional fits start from it.
    ``rigid`` is the identification without either, ``shares`` the play's.
    """
    if rigid.dead_zone:
        raise ValueError("the identification already holds a dead zone: give the one without")
    _, law, base = _replayed(rigid, dt, dead_time)
    base = replace(base, load_inertia=shares[0], load_friction=shares[1])
    data = ReversalData(trace, reading or LinearReading())
    if not data.windows:
        raise ValueError(NO_WINDOWS)
    side = min(plan.grid, 21)
    high = np.array([plan.max_width, 0.999 * min(law.uc_pos, law.uc_neg)])

    def costs(points: FloatArray) -> FloatArray:
        params = [replace(base, backlash=float(w), dead_zone=float(d)) for w, d in points]
        laws = [without_zone(law, float(d)) for _, d in points]
        return data.costs(replay(data.command, params, laws, dt)).sum(axis=0)

    # A coarse grid over both, a fine one around its best point, then a simplex polish.
    low, top = np.zeros(2), high
    for _ in range(2):
        axes = [np.linspace(a, b, side) for a, b in zip(low, top, strict=True)]
        grid = np.array([(w, d) for w in axes[0] for d in axes[1]])
        best = grid[int(np.argmin(costs(grid)))]
        steps = (top - low) / (side - 1)
        low, top = np.maximum(best - steps, 0.0), np.minimum(best + steps, high)
    result = minimize(
        lambda x: float(costs(x[None, :])[0]),
        best,
        method="Nelder-Mead",
        bounds=list(zip(np.zeros(2), high, strict=True)),
        options={"initial_simplex": np.vstack([best, best + np.diag(steps)])},
    )
    start = result.x if result.fun <= float(costs(best[None, :])[0]) else best
    return float(start[0]), float(start[1])


def _replayed(
    rigid: DeviceParams, dt: float, dead_time: float | None
) -> tuple[devices.Device, StictionCoulomb, PlantParams]:
    """Return the device, the paper law and the plant a reversal run is replayed on."""
    if rigid.device is None:
        raise ValueError("the rigid identification names no device: set DeviceParams.device")
    device = devices.get(rigid.device)
    _, law, _, base = device_physics(device, dt, params=rigid)
    if not (isinstance(law, StictionCoulomb) and law.exact):
        raise ValueError(
            f"the dead-zone fit replays the paper law with the event-exact step (linear or "
            f"step decay), got {law!r}"
        )
    base = replace(
        base,
        end_stop=math.inf,  # the run stays inside its band; offsets place it
        dead_time=base.dead_time if dead_time is None else round(dead_time / dt) * dt,
    )
    return device, law, base
