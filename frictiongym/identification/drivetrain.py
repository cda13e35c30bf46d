"""The drivetrain's elements in an identification, and the refinement they share with it.

:func:`refined_law` is the output-error refinement of the paper's law (``J``, ``B``, the
levels, the dead time) that :func:`~frictiongym.identification.identify.identify` runs on a
plan that refines. :func:`reversal_rounds` runs the reversal test of a play
(:mod:`~frictiongym.identification.backlash`) and :func:`dead_zone_fit` the dead zone's fit
(:mod:`~frictiongym.identification.dead_zone`), each refitting the rigid model with its
element free where the plan refines, because the relay runs brake and reverse too.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from frictiongym import devices
from frictiongym.controllers.rollout import Rollout
from frictiongym.friction import StictionCoulomb
from frictiongym.identification.backlash import (
    BacklashEstimate,
    ReversalPlan,
    estimate_backlash,
    reversal_test,
)
from frictiongym.identification.dead_zone import (
    LEVELS,
    DeadZoneEstimate,
    estimate_dead_zone,
    joint_start,
    without_zone,
)
from frictiongym.identification.experiments import Runner
from frictiongym.identification.fit import LawFit
from frictiongym.identification.refine import Reading, Refinement, refine
from frictiongym.params import Backlash, DeviceParams

#: Rounds of the refinement with the play's width free, each followed by the reversal test's
#: fit again, on a plan that refines (:func:`reversal_rounds`). One is enough: on the Altino
#: with plays of 0.2 and 0.5 cm a second round left the estimate as it was.
PLAY_ROUNDS = 1


def refined_law(
    fit: LawFit,
    traces: list[Rollout],
    inertia: tuple[float, float],
    damping: tuple[float, float],
    runner: Runner,
    reading: Reading | None,
    drivetrain: tuple[float, float, float] | None = None,
    previous: Refinement | None = None,
    zone: float | None = None,
) -> tuple[LawFit, Refinement]:
    """Return the paper's law after the output-error fit, and the refinement itself.

    With a play (``drivetrain``), its width is fitted too, on the reversal runs as well.
    With a dead zone (``zone``, its starting half-width), the zone is fitted instead and a
    play is held; the law's levels are then the friction's own.
    With a ``previous`` refinement, the fit starts from its result alone at its dead time or
    less: a continuation, without the multi-start.
    """
    shape = fit.model.shape if isinstance(fit.model, StictionCoulomb) else "linear"
    start = {"J": inertia[0], "B": damping[0], **fit.values}
    reversals = drivetrain is not None or zone is not None
    kinds = ("constant", "ramp", "relay", *(("reversal",) if reversals else ()))
    runs = [t for t in traces if t.settings["kind"] in kinds]
    options: dict[str, Any] = {}
    if previous is not None:
        steps = round(previous.dead_time / runner.spec.dt)
        options = {"candidates": 1, "local_fits": 1, "polish": 1, "max_delay_steps": steps}
    result = refine(
        runs,
        start,
        runner.spec.dt,
        runner.spec.limit,
        shape,
        reading=reading,
        direction=runner.spec.direction,
        drivetrain=drivetrain,
        fit_play=drivetrain is not None and zone is None,
        dead_zone=zone,
        fit_zone=zone is not None,
        **options,
    )
    v = result.values
    model = result.law(shape)
    values = {**{k: v[k] for k in fit.values if k != "viscous"}, "viscous": v["B"]}
    stderr = {k: result.stderr[k] for k in values if k != "viscous"}
    stderr["viscous"] = result.stderr["B"]
    refined = replace(fit, model=model, values=values, stderr=stderr, rms=math.nan)
    return refined, result


def reversal_rounds(
    runner: Runner,
    reversal: ReversalPlan,
    reading: Reading | None,
    traces: list[Rollout],
    rigid_model: tuple[
        LawFit,
        tuple[float, float],
        tuple[float, float],
        dict[str, tuple[float, float]],
        Refinement | None,
    ],
    note: Callable[[str], None],
) -> tuple[BacklashEstimate, tuple[LawFit, Refinement] | None]:
    """Run the reversal test on the rigid model; where the plan refines, refit both.

    A plan that refines on relay runs fits the rigid model to runs that reverse, so a play
    biases it (on the Altino with a 0.2 cm play: ``u_c-`` 3.6 % low, and the play 24 % low;
    with 0.5 cm, rounds that held the play fixed crept toward it by a few per cent each).
    Then the refinement is run again with the play's width free (the reversal run added),
    and the play estimated again with the rigid model it gives, :data:`PLAY_ROUNDS` times.
    ``rigid_model`` is the paper's fit, ``J`` and ``B`` (each with its standard error), the
    break-away levels and the refinement (or None). Returns the estimate and, if the play is
    resolved in the end, the refitted law and refinement (else the rigid model stands).
    """
    fit, inertia, damping, breakaway, refinement = rigid_model
    device = devices.device_of(runner.env)

    def rigid(law: LawFit, total_inertia: float, total_damping: float) -> DeviceParams:
        return DeviceParams.from_model(
            law.model, inertia=total_inertia, damping=total_damping, device=device.name
        )

    levels = (breakaway["us_pos"][0], breakaway["us_neg"][0])
    dead_time = None if refinement is None else refinement.dead_time
    play = reversal_test(
        runner,
        rigid(fit, inertia[0], damping[0]),
        levels,
        reversal,
        reading=reading,
        dead_time=dead_time,
    )
    if refinement is None or play.width <= 0.0:
        return play, None
    earlier = []
    for round_ in range(PLAY_ROUNDS):
        note(f"refinement with the play {round_ + 1}/{PLAY_ROUNDS}")
        earlier.append(play.width)
        free = (play.width, play.load_inertia, play.load_friction)
        fit, refinement = refined_law(
            fit,
            [*traces, play.trace],
            refinement.estimate("J"),
            refinement.estimate("B"),
            runner,
            reading,
            free,
            refinement,
        )
        play = estimate_backlash(
            play.trace,
            rigid(fit, refinement.values["J"], refinement.values["B"]),
            reversal,
            dt=runner.spec.dt,
            reading=reading,
            dead_time=refinement.dead_time,
        )
    play = replace(play, earlier=tuple(earlier), refinement_width=refinement.values["W"])
    return play, (fit, refinement) if play.resolved else None


def dead_zone_fit(
    runner: Runner,
    reversal: ReversalPlan,
    rigid_model: tuple[LawFit, float, float],
    breakaway: dict[str, tuple[float, float]],
    play: BacklashEstimate | None,
    reading: Reading | None,
    refinement: Refinement | None,
    traces: list[Rollout],
    note: Callable[[str], None],
) -> tuple[DeadZoneEstimate, BacklashEstimate | None, tuple[LawFit, Refinement] | None]:
    """Fit a dead zone to the reversal run (the play's, or a new one), then the play again.

    ``rigid_model`` is the paper's fit, ``J`` and ``B``. With a ``play`` estimate, the zone is
    fitted on its run with the play held at the width where both fit best together
    (:func:`~frictiongym.identification.dead_zone.joint_start`: both weaken the braking after
    a reversal, so either alone takes up the other), and the play is then estimated again
    with the zone held. On a plan
    that refines, the refinement is run again with the zone free first. Returns the zone,
    the play and, after such a refit, the law and the refinement (levels as the body shows
    them while driven, raised by the zone as the rigid model's are) that replace the rigid
    ones.
    """
    device = devices.device_of(runner.env)
    fit, inertia, damping = rigid_model
    rigid = DeviceParams.from_model(fit.model, inertia=inertia, damping=damping, device=device.name)
    dt = runner.spec.dt
    dead_time = None if refinement is None else refinement.dead_time
    held = None
    if play is None:
        limit = 0.95 * runner.spec.limit
        levels = (breakaway["us_pos"][0], breakaway["us_neg"][0])
        up, down = (min(reversal.level * level, limit) for level in levels)
        trace = runner.reversals(up, down, reversal.hold, reversal.reversals, band=reversal.band)
    else:  # the play's run; the zone's fit holds the play where both fit best together
        trace, shares = play.trace, (play.load_inertia, play.load_friction)
        width, _ = joint_start(
            trace, rigid, reversal, shares, dt=dt, reading=reading, dead_time=dead_time
        )
        held = Backlash(width, *shares) if width > 0.0 else None
        rigid = replace(rigid, backlash=held)
    zone = estimate_dead_zone(trace, rigid, reversal, dt=dt, reading=reading, dead_time=dead_time)
    joint = None
    if refinement is not None:
        # The relay runs brake too, so the rigid refinement took up part of the zone (on the
        # Altino with a zone of 50 units: the zone fitted 0, J 4.5 % high): refit it with the
        # zone free (the reversal run added), then the zone again on that rigid model.
        note("refinement with the dead zone")
        drivetrain = None if held is None else (held.width, held.load_inertia, held.load_friction)
        lowered = {k: v - zone.width if k in LEVELS else v for k, v in fit.values.items()}
        refit, refined = refined_law(
            replace(fit, values=lowered),  # the levels below the zone it starts from
            [*traces, trace],
            refinement.estimate("J"),
            refinement.estimate("B"),
            runner,
            reading,
            drivetrain,
            refinement,
            zone=zone.width,
        )
        width = refined.values["d"]
        raised = {k: v + width if k in LEVELS else v for k, v in refined.values.items()}
        refined = replace(refined, values=raised)
        refit = replace(
            refit,
            model=without_zone(refit.model, -width),
            values={k: v + width if k in LEVELS else v for k, v in refit.values.items()},
        )
        joint = (refit, refined)
        rigid = DeviceParams.from_model(
            refit.model, inertia=raised["J"], damping=raised["B"], device=device.name, backlash=held
        )
        dead_time = refined.dead_time
        zone = estimate_dead_zone(
            trace, rigid, reversal, dt=dt, reading=reading, dead_time=dead_time
        )
        zone = replace(zone, refinement_width=width)
    if play is not None and zone.resolved:
        zoned = replace(zone.apply(rigid), backlash=None)
        again = estimate_backlash(
            trace, zoned, reversal, dt=dt, reading=reading, dead_time=dead_time
        )
        play = replace(
            again, earlier=(*play.earlier, play.width), refinement_width=play.refinement_width
        )
    return zone, play, joint if zone.resolved else None
