"""Check the paper's three Altino phenomena on the simulated car (issue [A]).

The paper (§3.2, §5.2) reports, for a target 5 cm from a wall:

* PID ``Kp=25, Kd=12, Ki=10``: the car overshoots and stays around 3 cm;
* the same with ``Ki=20``: a smaller error, but the car oscillates around 5 cm (limit cycle);
* with the friction compensator and ``Kp=25, Ki=0.5, Kd=7``: rise and settling time below 1 s,
  almost no steady-state error, no oscillation.

This script runs the three experiments through :func:`frictiongym.loops.altino_step` on our
assumed Altino model (``ALTINO_PLANT``, ``ALTINO_DT``, ``ALTINO_START_CM``; see
docs/altino-model.md), prints a table of the measured quantities and whether each phenomenon
appears by the criteria below, and optionally plots the three responses (``--plot``) and
varies one model parameter at a time (``--sensitivity``).

Criteria (from the phenomenon descriptions, not from our numbers). A run in which the car
reaches the wall (``Rollout.terminated``) shows none of them.

* *overshoots and stays around 3 cm*: passes the target by at least 1 cm, and the stick that
  follows the closest approach holds the car 1 to 3 cm past the target for at least
  ``DWELL_S`` = 10 s;
* *oscillates around 5 cm* (sustained): at least 3 target crossings in the second half of the
  run (30–60 s for the default 60 s), a mean within 1 cm of the target and a peak-to-peak
  amplitude of at least 0.2 cm;
* *settles in under 1 s*: 10–90 % rise time and 2 % settling time (band: 2 % of the step)
  both below 1 s, steady-state error inside the 2 % band, overshoot below the band and at
  most one target crossing in the second half.

Run ``python scripts/altino_phenomena.py --help`` for the options.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import shlex
import sys
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from frictiongym.controllers import Rollout
from frictiongym.controllers.pid import PIDGains
from frictiongym.friction import (
    ALTINO_LUGRE,
    ALTINO_PAPER,
    FRICTION_NAMES,
    FrictionModel,
    StictionCoulomb,
    friction_from_name,
)
from frictiongym.loops import altino_step
from frictiongym.plants import PlantParams
from frictiongym.plants.presets import (
    ALTINO_DT,
    ALTINO_PAPER_GAINS_COMPENSATED,
    ALTINO_PAPER_GAINS_KI10,
    ALTINO_PAPER_GAINS_KI20,
    ALTINO_PLANT,
    ALTINO_START_CM,
    ALTINO_TARGET_CM,
)

SHAPES = ("linear", "step", "smooth", "exponential")


@dataclass(frozen=True)
class Scenario:
    """One of the paper's experiments."""

    key: str
    label: str
    gains: PIDGains
    compensated: bool
    paper: str


SCENARIOS = (
    Scenario(
        "ki10", "PID Ki=10", PIDGains(**ALTINO_PAPER_GAINS_KI10), False, "overshoots, stays ~3 cm"
    ),
    Scenario(
        "ki20", "PID Ki=20", PIDGains(**ALTINO_PAPER_GAINS_KI20), False, "oscillates around 5 cm"
    ),
    Scenario(
        "comp",
        "compensated",
        PIDGains(**ALTINO_PAPER_GAINS_COMPENSATED),
        True,
        "rise, settling < 1 s",
    ),
)


@dataclass(frozen=True)
class Setup:
    """Everything a run depends on besides the gains."""

    plant: PlantParams = ALTINO_PLANT
    dt: float = ALTINO_DT
    start_cm: float = ALTINO_START_CM
    duration: float = 60.0
    friction: FrictionModel = ALTINO_PAPER
    derivative: Literal["measurement", "error"] = "measurement"
    seed: int = 0  #: of the env's reset: the jitter's stream


@dataclass(frozen=True)
class Summary:
    """What the table reports about one run (distances in cm, times in s)."""

    final: float  #: true distance at the end
    closest: float  #: smallest distance reached
    overshoot: float  #: how far the car passed the target (>= 0)
    rise: float  #: 10-90 % rise time (inf if 90 % is never reached)
    settling: float  #: 2 % settling time (inf if it never stays in the band)
    sse: float  #: mean |target - distance| over the last 10 % of the run
    stuck_at_end: float  #: how long the car has been stuck at the end (0: moving)
    longest_stick: float  #: longest time stuck in one place after the start
    crossings: int  #: target crossings in the second half of the run
    p2p: float  #: peak-to-peak distance in the second half of the run
    period: float  #: mean limit-cycle period in the second half (nan: fewer than 3 crossings)
    mean_tail: float  #: mean distance in the second half of the run
    band: float  #: the 2 % settling band, cm
    duration: float
    rest: float  #: where the first stick after the closest approach holds the car (nan: none)
    dwell: float  #: how long that stick lasts, s (0: none)
    collided: bool  #: the car reached the wall and the run stopped there


#: Minimum stick after the overshoot that counts as "stays around 3 cm", s.
DWELL_S = 10.0


def run_scenario(scenario: Scenario, setup: Setup) -> Rollout:
    """Simulate one experiment."""
    return altino_step(
        scenario.gains,
        friction=setup.friction,
        compensator=ALTINO_PAPER if scenario.compensated else None,
        start_cm=setup.start_cm,
        duration=setup.duration,
        plant=setup.plant,
        dt=setup.dt,
        derivative=setup.derivative,
        seed=setup.seed,
    )


def _stick_spans(stuck: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [i, j) of consecutive stuck samples, the initial rest excluded."""
    spans = []
    i, n = 0, stuck.size
    while i < n and stuck[i]:  # at rest before the first command takes effect
        i += 1
    while i < n:
        if stuck[i]:
            j = i
            while j < n and stuck[j]:
                j += 1
            spans.append((i, j))
            i = j
        else:
            i += 1
    return spans


def summarize(run: Rollout) -> Summary:
    """Measure one run."""
    m = run.metrics()
    t, y, target = run.t, run.signal("position"), float(run.signal("reference")[-1])
    dt = float(t[1] - t[0])
    spans = _stick_spans(run.signal("stuck"))
    stuck_at_end = (spans[-1][1] - spans[-1][0]) * dt if spans and spans[-1][1] == y.size else 0.0
    longest = max(((j - i) * dt for i, j in spans), default=0.0)
    lowest = int(np.argmin(y))
    after = [(i, j) for i, j in spans if j > lowest]
    rest, dwell = (
        (float(y[after[0][0]]), (after[0][1] - after[0][0]) * dt) if after else (math.nan, 0.0)
    )
    tail = t >= t[-1] / 2.0
    off = y[tail] != target  # samples exactly on the target belong to neither side
    side, when = np.sign(y[tail][off] - target), t[tail][off]
    flips = np.flatnonzero(side[1:] != side[:-1])
    # Consecutive crossings are half a cycle apart.
    period = 2.0 * float(np.mean(np.diff(when[flips + 1]))) if flips.size >= 3 else math.nan
    return Summary(
        final=float(y[-1]),
        closest=float(y.min()),
        overshoot=max(0.0, target - float(y.min())),
        rise=m.rise_time,
        settling=m.settling_time,
        sse=m.steady_state_error,
        stuck_at_end=stuck_at_end,
        longest_stick=longest,
        crossings=int(flips.size),
        p2p=float(np.ptp(y[tail])),
        period=period,
        mean_tail=float(np.mean(y[tail])),
        band=0.02 * abs(y[0] - target),
        duration=float(t[-1]),
        rest=rest,
        dwell=dwell,
        collided=bool(run.terminated[0]),
    )


def reproduced(key: str, s: Summary, target: float = ALTINO_TARGET_CM) -> bool:
    """Whether a run shows the paper's phenomenon, by the criteria in the module docstring."""
    if s.collided:
        return False
    if key == "ki10":
        return s.overshoot >= 1.0 and 1.0 <= target - s.rest <= 3.0 and s.dwell >= DWELL_S
    if key == "ki20":
        return s.crossings >= 3 and abs(s.mean_tail - target) < 1.0 and s.p2p >= 0.2
    return (
        s.rise < 1.0
        and s.settling < 1.0
        and s.sse <= s.band
        and s.overshoot < s.band
        and s.crossings <= 1
    )


def _f(value: float, digits: int = 2) -> str:
    if math.isnan(value):
        return "-"
    if math.isinf(value):
        return "never"
    return f"{value:.{digits}f}"


def print_table(setup: Setup, runs: dict[str, Rollout]) -> None:
    """Print the three experiments as a table."""
    header = (
        f"{'experiment':<13}{'final':>7}{'closest':>8}{'rest':>6}{'dwell':>7}{'rise':>6}"
        f"{'settle':>7}{'SSE':>6}{'stuck':>7}{'cross':>6}{'p2p':>6}{'period':>7}"
        f"  {'paper':<24}{'seen'}"
    )
    print(header)
    print(
        f"{'':<13}{'cm':>7}{'cm':>8}{'cm':>6}{'s':>7}{'s':>6}{'s':>7}{'cm':>6}{'s':>7}"
        f"{'':>6}{'cm':>6}{'s':>7}"
    )
    print("-" * len(header))
    for sc in SCENARIOS:
        s = summarize(runs[sc.key])
        seen = "yes" if reproduced(sc.key, s) else "no"
        if s.collided:
            seen += f" (hit the wall at {s.duration:.2f} s)"
        print(
            f"{sc.label:<13}{_f(s.final):>7}{_f(s.closest):>8}{_f(s.rest):>6}"
            f"{_f(s.dwell, 1):>7}{_f(s.rise):>6}{_f(s.settling):>7}{_f(s.sse):>6}"
            f"{_f(s.stuck_at_end, 1):>7}{s.crossings:>6}{_f(s.p2p):>6}{_f(s.period, 1):>7}"
            f"  {sc.paper:<24}{seen}"
        )
    print(
        f"\nfinal/closest: true distance to the wall at the end / minimum; rest/dwell: where "
        f"the first stick after the closest\napproach holds the car, and for how long; rise: "
        f"10-90 %; settle: 2 % band (±{0.02 * abs(setup.start_cm - ALTINO_TARGET_CM):.2f} cm); "
        "SSE: mean |error| over the last 10 %\nof the run; stuck: stuck time at the end; "
        "cross/p2p/period: target crossings, peak-to-peak and mean period over the second\n"
        "half. seen: the paper's phenomenon by the criteria in the script's docstring."
    )


def describe(setup: Setup) -> str:
    """One line naming the model a table was computed with."""
    p = setup.plant
    play = (
        f"play {p.backlash:g} cm (car {p.load_inertia:g} of the mass, {p.load_friction:g} of the "
        "friction), "
        if p.backlash
        else ""
    )
    if p.jitter:
        play += f"latency jitter up to {p.jitter:g} s (seed {setup.seed}), "
    return (
        f"mass {p.inertia:g} units·s²/cm, damping {p.damping:g} + viscous "
        f"{getattr(setup.friction, 'viscous', 0.0):g} units/(cm/s), lag {p.lag:g} s, dead time "
        f"{p.dead_time:g} s, dead zone ±{p.dead_zone:g}, limit ±{p.command_limit:g}, {play}"
        f"dt {setup.dt:g} s, "
        f"{setup.start_cm:g} → {ALTINO_TARGET_CM:g} cm in {setup.duration:g} s, friction "
        f"{_friction_label(setup.friction)}, derivative on {setup.derivative}"
    )


def _friction_label(friction: FrictionModel) -> str:
    if friction == ALTINO_PAPER:
        return "ALTINO_PAPER"
    if friction == ALTINO_LUGRE:
        return "ALTINO_LUGRE"
    if isinstance(friction, StictionCoulomb):
        return f"ALTINO_PAPER with shape={friction.shape!r}"
    return type(friction).__name__


def run_all(setup: Setup) -> dict[str, Rollout]:
    """The three experiments on one setup."""
    return {sc.key: run_scenario(sc, setup) for sc in SCENARIOS}


def sensitivity(base: Setup) -> None:
    """Vary one model choice at a time around ``base`` and print what each experiment does."""
    p = base.plant
    variants: list[tuple[str, Setup]] = [("defaults", base)]
    for mass in (1.1, 1.6, 3.3, 5.5):
        variants.append(
            (
                f"mass {mass:g}",
                dataclasses.replace(base, plant=dataclasses.replace(p, inertia=mass)),
            )
        )
    for lag in (0.02, 0.05, 0.1):
        variants.append(
            (f"lag {lag:g} s", dataclasses.replace(base, plant=dataclasses.replace(p, lag=lag)))
        )
    for periods in (0, 2):
        dead = periods * base.dt
        variants.append(
            (
                f"dead time {dead:g} s",
                dataclasses.replace(base, plant=dataclasses.replace(p, dead_time=dead)),
            )
        )
    for dt in (0.025, 0.1):
        variants.append(
            (
                f"dt {dt:g} s (+1 period)",
                dataclasses.replace(base, dt=dt, plant=dataclasses.replace(p, dead_time=dt)),
            )
        )
    for start in (20.0, 25.0, 35.0, 38.0, 40.0, 45.0):
        variants.append((f"start {start:g} cm", dataclasses.replace(base, start_cm=start)))
    variants.append(("derivative on error", dataclasses.replace(base, derivative="error")))
    for shape in ("exponential", "step"):
        if isinstance(base.friction, StictionCoulomb):
            variants.append(
                (
                    f"shape {shape}",
                    dataclasses.replace(base, friction=base.friction.replace(shape=shape)),
                )
            )
    variants.append(("LuGre", dataclasses.replace(base, friction=ALTINO_LUGRE)))

    print(f"\nOne change at a time from: {describe(base)}")
    header = (
        f"{'variant':<24}| {'Ki=10: closest rest dwell':<28}| "
        f"{'Ki=20: closest dwell cross p2p':<34}| {'comp: rise settle SSE':<22}| seen"
    )
    print(header)
    print("-" * len(header))
    for label, setup in variants:
        cells = []
        flags = ""
        s = {sc.key: summarize(run_scenario(sc, setup)) for sc in SCENARIOS}
        a, b, c = s["ki10"], s["ki20"], s["comp"]
        cells.append(f"{_f(a.closest):>7} {_f(a.rest):>5} {_f(a.dwell, 1):>5} s      ")
        if b.collided:
            cells.append(f"{'hits the wall at ' + _f(b.duration) + ' s':>33} ")
        else:
            cells.append(
                f"{_f(b.closest):>7} {_f(b.dwell, 1):>6} s {b.crossings:>5} {_f(b.p2p):>5}     "
            )
        cells.append(f"{_f(c.rise):>5} {_f(c.settling):>6} {_f(c.sse):>5}    ")
        for sc in SCENARIOS:
            flags += "Y" if reproduced(sc.key, s[sc.key]) else "."
        print(f"{label:<24}| {cells[0]:<28}| {cells[1]:<34}| {cells[2]:<22}| {flags}")
    print("seen: one flag per experiment (Ki=10, Ki=20, compensated); Y = phenomenon present.")

    print("\nIntegral gain at which the model overshoots and sticks (Kp=25, Kd=12, defaults):")
    print(
        f"{'Ki':>5}{'closest':>9}{'rest':>7}{'dwell':>7}{'final':>7}  seen as 'overshoots, stays'"
    )
    for ki in (10.0, 12.0, 14.0, 16.0, 18.0, 20.0):
        sc = dataclasses.replace(SCENARIOS[0], gains=PIDGains(kp=25.0, ki=ki, kd=12.0))
        s_ = summarize(run_scenario(sc, base))
        print(
            f"{ki:>5g}{_f(s_.closest):>9}{_f(s_.rest):>7}{_f(s_.dwell, 1):>7}{_f(s_.final):>7}"
            f"  {'yes' if reproduced('ki10', s_) else 'no'}"
            + (" (hits the wall)" if s_.collided else "")
        )


#: The plausible box of docs/altino-model.md swept by ``--box``.
BOX_MASSES = (1.1, 2.2, 3.3, 5.5)
BOX_LAGS = (0.0, 0.05, 0.1)
BOX_DEAD_PERIODS = (0, 1, 2)
BOX_DTS = (0.025, 0.05, 0.1)
BOX_STARTS = (20.0, 25.0, 30.0, 35.0, 40.0, 45.0)


def box(base: Setup) -> None:
    """Run the three experiments on every point of the plausible box, by start distance.

    Prints, per start distance, at how many plant points each phenomenon is seen, how often
    the ``Ki=20`` run hits the wall, at how many points the two uncompensated phenomena appear
    together, and the range of the compensated rise and settling times.
    """
    plants = list(itertools.product(BOX_MASSES, BOX_LAGS, BOX_DEAD_PERIODS, BOX_DTS))
    print(
        f"\nBox sweep ({len(plants)} plant points per start: mass {BOX_MASSES}, lag {BOX_LAGS} "
        f"s, dead time {BOX_DEAD_PERIODS} periods, dt {BOX_DTS} s, dead zone "
        f"±{base.plant.dead_zone:g};\nfriction "
        f"{_friction_label(base.friction)}, derivative on {base.derivative}, {base.duration:g} s)"
    )
    print(
        f"{'start':>6}{'Ki=10':>7}{'Ki=20':>7}{'wall':>6}{'both':>6}{'comp':>6}"
        f"{'Ki=10 closest':>15}{'comp rise':>13}{'comp settle':>15}"
    )
    for start in BOX_STARTS:
        seen = {sc.key: 0 for sc in SCENARIOS}
        walls = both = 0
        closest, rises, settlings = [], [], []
        for mass, lag, periods, dt in plants:
            plant = dataclasses.replace(base.plant, inertia=mass, lag=lag, dead_time=periods * dt)
            setup = dataclasses.replace(base, plant=plant, dt=dt, start_cm=start)
            s = {sc.key: summarize(run_scenario(sc, setup)) for sc in SCENARIOS}
            flags = {sc.key: reproduced(sc.key, s[sc.key]) for sc in SCENARIOS}
            for key, flag in flags.items():
                seen[key] += flag
            walls += s["ki20"].collided
            both += flags["ki10"] and flags["ki20"]
            closest.append(s["ki10"].closest)
            rises.append(s["comp"].rise)
            settlings.append(s["comp"].settling)
        print(
            f"{start:>6g}{seen['ki10']:>7}{seen['ki20']:>7}{walls:>6}{both:>6}{seen['comp']:>6}"
            f"{min(closest):>8.2f}-{max(closest):<6.2f}{min(rises):>7.2f}-{max(rises):<5.2f}"
            f"{min(settlings):>8.2f}-{_f(max(settlings)):<6}"
        )
    print(
        "Ki=10, Ki=20, comp: points where the phenomenon is seen; wall: points where the Ki=20 "
        "run hits the wall;\nboth: Ki=10 and Ki=20 phenomena at the same point."
    )


#: The plausible drivetrain box swept by ``--drivetrain-box`` (docs/altino-model.md §9 states
#: each range's source): play as car travel, cm; the car's shares of mass and friction; the
#: drive's latency jitter, s; the motor's dead zone, units; the effective mass.
DRIVE_PLAYS = (0.0, 0.05, 0.1, 0.2, 0.3)
DRIVE_LOAD_INERTIAS = (0.6, 0.8, 0.95)
DRIVE_LOAD_FRICTIONS = (0.2, 0.5, 0.8)
DRIVE_JITTERS = (0.0, 0.01, 0.025, 0.045)
DRIVE_DEAD_ZONES = (0.0, 50.0, 100.0)
DRIVE_MASSES = (1.1, 2.2, 3.3)
#: Seeds of the jitter's stream at the closest points.
DRIVE_SEEDS = (0, 1, 2, 3, 4)


def _closeness(s: dict[str, Summary]) -> float:
    """How far a point is from the paper's three phenomena together (0: all three, by margin).

    Sums, over the three experiments, a distance to the paper's description in cm or s:
    Ki=10 resting 1 to 3 cm past the target (2 cm), Ki=20 peak-to-peak amplitude below 0.2 cm
    or fewer than 3 crossings, the compensated loop's settling beyond 1 s.
    """
    a, b, c = s["ki10"], s["ki20"], s["comp"]
    ki10 = abs(a.rest - (ALTINO_TARGET_CM - 2.0)) if math.isfinite(a.rest) else 5.0
    ki20 = 5.0 if b.collided else max(0.0, 0.2 - b.p2p) * 5.0 + max(0, 3 - b.crossings)
    comp = min(5.0, max(0.0, c.settling - 1.0)) + min(5.0, max(0.0, c.rise - 1.0))
    return ki10 + ki20 + comp


def _drivetrain_plant(base: Setup, point: tuple[float, ...]) -> PlantParams:
    """The base plant at a point ``(play, psi, phi, jitter, zone, mass)`` of the box."""
    play, psi, phi, jitter, zone, mass = point
    return dataclasses.replace(
        base.plant,
        inertia=mass,
        backlash=play,
        load_inertia=psi,
        load_friction=phi,
        jitter=jitter,
        dead_zone=zone,
    )


def drivetrain_box(base: Setup) -> None:
    """Run the three experiments over the plausible drivetrain box; report the closest points.

    Prints how many points show each phenomenon and all three, then the ten points closest to
    the paper (:func:`_closeness`), each rerun with the jitter seeds :data:`DRIVE_SEEDS`.
    """
    grid = list(
        itertools.product(
            DRIVE_PLAYS,
            DRIVE_LOAD_INERTIAS,
            DRIVE_LOAD_FRICTIONS,
            DRIVE_JITTERS,
            DRIVE_DEAD_ZONES,
            DRIVE_MASSES,
        )
    )
    print(
        f"\nDrivetrain box ({len(grid)} points: play {DRIVE_PLAYS} cm, car's mass share "
        f"{DRIVE_LOAD_INERTIAS}, friction share {DRIVE_LOAD_FRICTIONS}, jitter {DRIVE_JITTERS} s, "
        f"dead zone {DRIVE_DEAD_ZONES}, mass {DRIVE_MASSES}; the rest: {describe(base)})"
    )
    seen = {sc.key: 0 for sc in SCENARIOS}
    together = 0
    scored = []
    for point in grid:
        play, psi, phi = point[:3]
        if play == 0.0 and (psi, phi) != (DRIVE_LOAD_INERTIAS[0], DRIVE_LOAD_FRICTIONS[0]):
            continue  # without play the shares change nothing
        setup = dataclasses.replace(base, plant=_drivetrain_plant(base, point))
        s = {sc.key: summarize(run_scenario(sc, setup)) for sc in SCENARIOS}
        flags = [reproduced(sc.key, s[sc.key]) for sc in SCENARIOS]
        for sc, flag in zip(SCENARIOS, flags, strict=True):
            seen[sc.key] += flag
        together += all(flags)
        scored.append((-sum(flags), _closeness(s), point))
    runs = len(scored)
    print(
        f"points run: {runs}; Ki=10 seen at {seen['ki10']}, Ki=20 at {seen['ki20']}, "
        f"compensated at {seen['comp']}, all three at {together}"
    )
    print(
        f"\n{'play':>5}{'car m':>6}{'car f':>6}{'jitter':>7}{'zone':>5}{'mass':>5} | seed "
        f"{'Ki10 rest':>9}{'Ki20 p2p':>9}{'cross':>6}{'comp rise':>10}{'settle':>7} seen"
    )
    for _, _, point in sorted(scored)[:10]:
        play, psi, phi, jitter, zone, mass = point
        plant = _drivetrain_plant(base, point)
        for seed in DRIVE_SEEDS if jitter else DRIVE_SEEDS[:1]:
            setup = dataclasses.replace(base, plant=plant, seed=seed)
            s = {sc.key: summarize(run_scenario(sc, setup)) for sc in SCENARIOS}
            flags = "".join("Y" if reproduced(sc.key, s[sc.key]) else "." for sc in SCENARIOS)
            a, b, c = s["ki10"], s["ki20"], s["comp"]
            print(
                f"{play:>5g}{psi:>6g}{phi:>6g}{jitter:>7g}{zone:>5g}{mass:>5g} | {seed:>4} "
                f"{_f(a.rest):>9}{_f(b.p2p):>9}{b.crossings:>6}{_f(c.rise):>10}"
                f"{_f(c.settling):>7} {flags}"
            )


def plot(runs: dict[str, Rollout], setup: Setup, path: str) -> None:
    """Write the three responses (distance and command) to a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_y, ax_u) = plt.subplots(
        2, 1, figsize=(8, 6), sharex=True, gridspec_kw={"height_ratios": [2, 1]}
    )
    for sc in SCENARIOS:
        run = runs[sc.key]
        ax_y.plot(run.t, run.signal("position"), label=f"{sc.label} (paper: {sc.paper})")
        ax_u.plot(run.t, run.signal("command"), lw=0.9)
    ax_y.axhline(ALTINO_TARGET_CM, color="k", lw=0.8, ls="--", label="target")
    ax_y.set(
        ylabel="distance to wall [cm]",
        ylim=(0.0, None),
        title="Altino model: the paper's three experiments",
    )
    ax_y.legend(fontsize=8)
    for level in (200.0, -200.0):
        ax_u.axhline(level, color="grey", lw=0.6, ls=":")
    ax_u.set(xlabel="time [s]", ylabel="command [units]")
    fig.text(0.01, 0.005, textwrap.fill(describe(setup), 150), fontsize=6, color="grey")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)
    print(f"figure written to {path}")


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser."""
    p = ALTINO_PLANT
    parser = argparse.ArgumentParser(
        description="Run the paper's three Altino experiments (PID Ki=10, Ki=20, compensated "
        "PID) on the simulated car and report whether its phenomena appear.",
    )
    parser.add_argument("--duration", type=float, default=60.0, help="simulated time, s (60)")
    parser.add_argument(
        "--dt", type=float, default=ALTINO_DT, help=f"control period, s ({ALTINO_DT:g})"
    )
    parser.add_argument(
        "--mass", type=float, default=p.inertia, help=f"effective mass, units·s²/cm ({p.inertia:g})"
    )
    parser.add_argument("--lag", type=float, default=p.lag, help=f"actuator lag, s ({p.lag:g})")
    parser.add_argument(
        "--dead-time",
        type=float,
        default=None,
        help="dead time, s, whole periods (default: one period)",
    )
    parser.add_argument(
        "--dead-zone",
        type=float,
        default=p.dead_zone,
        help=f"half-width of the motor's dead zone, motor units ({p.dead_zone:g}; the "
        "compensator does not model it)",
    )
    parser.add_argument(
        "--backlash",
        type=float,
        default=p.backlash,
        help=f"play between motor and car as car travel, cm ({p.backlash:g}: none)",
    )
    parser.add_argument(
        "--jitter",
        type=float,
        default=p.jitter,
        help=f"latency jitter of the drive, s, below --dt ({p.jitter:g}: none)",
    )
    parser.add_argument("--seed", type=int, default=0, help="the env's seed: the jitter's (0)")
    parser.add_argument(
        "--load-inertia",
        type=float,
        default=p.load_inertia,
        help=f"the car's share of the mass, with --backlash ({p.load_inertia:g})",
    )
    parser.add_argument(
        "--load-friction",
        type=float,
        default=p.load_friction,
        help=f"the car's share of the friction, with --backlash ({p.load_friction:g})",
    )
    parser.add_argument(
        "--start",
        type=float,
        default=ALTINO_START_CM,
        help=f"start distance, cm ({ALTINO_START_CM:g})",
    )
    parser.add_argument(
        "--friction",
        choices=FRICTION_NAMES,
        default="paper",
        help="friction law of the car (paper)",
    )
    parser.add_argument(
        "--shape",
        choices=SHAPES,
        default=None,
        help="decay shape of the paper law from u_s to u_c (linear, as ALTINO_PAPER)",
    )
    parser.add_argument(
        "--derivative",
        choices=("measurement", "error"),
        default="measurement",
        help="where the D term acts (measurement)",
    )
    parser.add_argument(
        "--sensitivity",
        action="store_true",
        help="also vary one model choice at a time and scan Ki",
    )
    parser.add_argument(
        "--box", action="store_true", help="also sweep the plausible box of model choices"
    )
    parser.add_argument(
        "--drivetrain-box",
        action="store_true",
        help="also sweep the plausible drivetrain box: play, its shares, latency jitter, dead "
        "zone and mass (issue L; a few minutes)",
    )
    parser.add_argument("--plot", metavar="PATH", help="write the three responses to this PNG")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the experiments; return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not (args.duration > 1.0 and args.dt > 0.0 and args.mass > 0.0 and args.lag >= 0.0):
        parser.error("need --duration > 1, --dt > 0, --mass > 0 and --lag >= 0")
    if not ALTINO_TARGET_CM < args.start <= 100.0:
        parser.error(f"--start must lie between the {ALTINO_TARGET_CM:g} cm target and 100 cm")
    friction = friction_from_name(args.friction, ALTINO_PAPER, ALTINO_LUGRE)
    if args.shape is not None:
        if not isinstance(friction, StictionCoulomb):
            parser.error("--shape applies to --friction paper or stribeck only")
        friction = friction.replace(shape=args.shape)
    dead_time = args.dt if args.dead_time is None else args.dead_time
    try:
        plant = dataclasses.replace(
            ALTINO_PLANT,
            inertia=args.mass,
            lag=args.lag,
            dead_time=dead_time,
            dead_zone=args.dead_zone,
            backlash=args.backlash,
            load_inertia=args.load_inertia,
            load_friction=args.load_friction,
            jitter=args.jitter,
        )
        plant.delay_steps(args.dt)
    except ValueError as err:
        parser.error(str(err))
    setup = Setup(plant, args.dt, args.start, args.duration, friction, args.derivative, args.seed)
    argv_used = sys.argv[1:] if argv is None else list(argv)
    print(f"$ python scripts/altino_phenomena.py {shlex.join(argv_used)}".rstrip())
    print(f"Model: {describe(setup)}\n")
    runs = run_all(setup)
    print_table(setup, runs)
    if args.sensitivity:
        sensitivity(setup)
    if args.box:
        box(setup)
    if args.drivetrain_box:
        drivetrain_box(setup)
    if args.plot:
        plot(runs, setup, args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
