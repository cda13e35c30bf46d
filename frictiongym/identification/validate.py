"""Check the identification on simulated devices whose true parameters are known.

``python -m frictiongym.identification.validate --env ID [--noise] [--draws 0-3] [--seeds 0,1]``
identifies the paper's preset (draw ``-``) and devices drawn at random within ±15 % of it, with
each noise seed, and prints every parameter's error as a markdown table, with the issue's
tolerances (3 % for the friction parameters, 2 % for ``J`` and ``B``). The numbers in
docs/identification.md come from it; ``tests/test_identification.py`` checks the same draws.

``--backlash W1,W2`` instead identifies the preset with each play in the simulated device and
the reversal test on (:mod:`~frictiongym.identification.backlash`), and prints the play's
estimate against the truth; ``--shares PSI,PHI`` makes the test assume other shares than the
preset's (the simulated device keeps the preset's).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from frictiongym import devices
from frictiongym._validation import real_number
from frictiongym.friction import FrictionModel, StictionCoulomb
from frictiongym.identification.backlash import ReversalPlan
from frictiongym.identification.identify import identify, make_env
from frictiongym.plants.plant import PlantParams

#: The friction levels and kinks drawn independently.
FRICTION_KEYS = ("us_pos", "us_neg", "uc_pos", "uc_neg", "v0_pos", "v0_neg")
#: Keys of :func:`errors`, in the parameter file's order.
KEYS = (*FRICTION_KEYS, "viscous", "J", "B")
#: The issue's tolerances: relative error of each friction parameter, of ``J`` and of ``B``.
TOLERANCE = {**{k: 0.03 for k in (*FRICTION_KEYS, "viscous")}, "J": 0.02, "B": 0.02}


def draw_device(
    rng: np.random.Generator, friction: StictionCoulomb, plant: PlantParams, spread: float = 0.15
) -> tuple[StictionCoulomb, PlantParams]:
    """Draw a device within ``±spread`` of a preset, its low-speed map branch still rising.

    Each friction level, ``v_0``, the viscous slope, ``J`` and ``B`` are drawn independently
    and uniformly. Draws are rejected until ``u_c < u_s`` and the map's slope just above rest
    is at least a fifth of the total damping in both directions: an open-loop map cannot
    observe a falling branch (an open-loop level on it is unstable; docs/identification.md).
    """
    low, high = 1.0 - spread, 1.0 + spread
    while True:
        f = {k: getattr(friction, k) * rng.uniform(low, high) for k in FRICTION_KEYS}
        inertia = plant.inertia * rng.uniform(low, high)
        damping = plant.damping * rng.uniform(low, high)
        viscous = friction.viscous * rng.uniform(low, high)
        total = damping + viscous
        rising = all(
            total - (f[f"us_{d}"] - f[f"uc_{d}"]) / f[f"v0_{d}"] > 0.2 * total
            for d in ("pos", "neg")
        )
        if rising and f["uc_pos"] < f["us_pos"] and f["uc_neg"] < f["us_neg"]:
            law = StictionCoulomb(**f, viscous=viscous, shape=friction.shape)
            return law, PlantParams(
                inertia, damping, plant.command_limit, plant.lag, plant.dead_time
            )


def truth(friction: FrictionModel, plant: PlantParams) -> dict[str, float]:
    """Return a simulated device's true parameters (:data:`KEYS`) as the parameter file has them.

    ``B`` and ``viscous`` are the total linear damping: the plant's and the law's viscous slope.
    """
    total = plant.damping + float(getattr(friction, "viscous", 0.0))
    true = {k: float(getattr(friction, k, math.nan)) for k in FRICTION_KEYS}
    return {**true, "viscous": total, "J": plant.inertia, "B": total}


def errors(
    env_id: str,
    friction: StictionCoulomb,
    plant: PlantParams,
    seed: int = 3,
    **kwargs: Any,
) -> dict[str, float]:
    """Identify the simulated device and return each parameter's relative error (:func:`truth`)."""
    env = make_env(env_id, friction=friction, plant=plant, **kwargs)
    params = identify(env, seed=seed).params()
    found = {k: getattr(params.friction, k) for k in (*FRICTION_KEYS, "viscous")}
    found.update(J=params.inertia, B=params.damping)
    true = truth(friction, plant)
    return {k: found[k] / true[k] - 1.0 for k in KEYS}


def backlash_table(
    env_id: str,
    widths: Sequence[float],
    seeds: Sequence[int],
    noise: bool,
    shares: tuple[float, float] | None = None,
) -> list[str]:
    """Identify the preset with each play and the reversal test on; return a markdown table.

    Each row: the true and estimated width, its standard error, the error in per cent and in
    standard errors, whether it was resolved (else the bound), and the largest error of the
    rigid parameters (:data:`KEYS`) identified beside it.
    """
    device = devices.get(env_id)
    plan = ReversalPlan.for_device(device)
    if shares is not None:
        plan = replace(plan, shares=shares)
    unit = device.position_unit
    rows = [
        f"| true W ({unit}) | seed | estimated W | std. error | error | error / s.e. | "
        "resolved | worst rigid error |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for width in widths:
        for seed in seeds:
            env = make_env(env_id, backlash=width, sensor_noise=noise, quantize=True)
            result = identify(env, seed=seed, backlash=plan)
            play = result.backlash
            if play is None:  # identify runs the test when asked: a bug if it did not
                raise RuntimeError("identify(backlash=...) returned no reversal test")
            params = result.params()
            found = {k: getattr(params.friction, k) for k in (*FRICTION_KEYS, "viscous")}
            found.update(J=params.inertia, B=params.damping)
            true = truth(device.paper_friction, device.plant)
            rigid = max(abs(found[k] / true[k] - 1.0) for k in KEYS)
            error = play.width - width
            relative = f"{100 * error / width:+.1f} %" if width else "-"
            resolved = "yes" if play.resolved else f"no: W < {play.upper:.3g}"
            if not (play.resolved or math.isfinite(play.upper)):
                resolved = f"no: {play.note}"
            rows.append(
                f"| {width:g} | {seed} | {play.width:.4g} | {play.stderr:.2g} | {relative} | "
                f"{error / play.stderr:+.1f} | {resolved} | {100 * rigid:.2f} % |"
            )
            print(rows[-1], file=sys.stderr, flush=True)
    return rows


def _integers(text: str, option: str) -> list[int]:
    """Parse ``"0,2,5-7"`` into ``[0, 2, 5, 6, 7]``; a bad list names ``option``."""
    out: list[int] = []
    for part in filter(None, text.split(",")):
        first, _, last = part.partition("-")
        try:
            out += list(range(int(first), int(last or first) + 1))
        except ValueError:
            raise ValueError(
                f"{option} takes integers and ranges such as 0,2,5-7, got {text!r}"
            ) from None
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the error table; return 0 if every run is within the tolerances, else 1."""
    parser = argparse.ArgumentParser(prog="python -m frictiongym.identification.validate")
    parser.add_argument("--env", required=True, metavar="ID")
    parser.add_argument("--noise", action="store_true", help="the device's sensor noise on")
    parser.add_argument(
        "--draws", default="", help="random devices, e.g. 0-3 (the preset always runs)"
    )
    parser.add_argument("--seeds", default="0", help="noise seeds of the simulator, e.g. 0,1")
    parser.add_argument(
        "--backlash",
        default="",
        metavar="W1,W2",
        help="plays (position units) to simulate and estimate by the reversal test, instead "
        "of the random devices",
    )
    parser.add_argument(
        "--shares",
        default="",
        metavar="PSI,PHI",
        help="with --backlash: the load's shares of inertia and friction the test assumes "
        "(default: the device preset's)",
    )
    args = parser.parse_args(argv)
    try:
        device = devices.get(args.env)
        widths = [float(w) for w in filter(None, args.backlash.split(","))]
        shares = [float(x) for x in filter(None, args.shares.split(","))]
        if shares and len(shares) != 2:
            raise ValueError(f"--shares takes two fractions PSI,PHI, got {args.shares!r}")
        if shares and not widths:
            raise ValueError("--shares applies to the reversal test: give --backlash too")
        for width in widths:
            real_number("--backlash", width, ">= 0")
        if shares:  # checked as the test will take them
            replace(ReversalPlan.for_device(device), shares=(shares[0], shares[1]))
        seeds, draws = _integers(args.seeds, "--seeds"), _integers(args.draws, "--draws")
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if widths:
        started = time.perf_counter()
        assumed = (shares[0], shares[1]) if shares else None
        rows = backlash_table(args.env, widths, seeds, args.noise, assumed)
        print("\n".join(rows))
        print(
            f"{len(rows) - 2} identifications in {time.perf_counter() - started:.0f} s",
            file=sys.stderr,
        )
        return 0
    preset_friction, preset_plant = device.paper_friction, device.plant
    if not isinstance(preset_friction, StictionCoulomb):
        print(f"error: {args.env}'s preset is not the paper's law", file=sys.stderr)
        return 2
    print("| device | seed | " + " | ".join(KEYS) + " | within |")
    print("|---|---|" + "---|" * len(KEYS) + "---|")
    worst = dict.fromkeys(KEYS, 0.0)
    runs, good_runs, started = 0, 0, time.perf_counter()
    for draw in [None, *draws]:
        if draw is None:
            friction, plant = preset_friction, preset_plant
        else:
            rng = np.random.default_rng(draw)
            friction, plant = draw_device(rng, preset_friction, preset_plant)
        for seed in seeds:
            result = errors(args.env, friction, plant, seed, sensor_noise=args.noise, quantize=True)
            good = all(abs(result[k]) < TOLERANCE[k] for k in KEYS)
            runs, good_runs = runs + 1, good_runs + good
            worst = {k: max(worst[k], abs(result[k])) for k in KEYS}
            cells = " | ".join(f"{100 * result[k]:+.2f} %" for k in KEYS)
            name = "preset" if draw is None else f"draw {draw}"
            print(f"| {name} | {seed} | {cells} | {'yes' if good else 'NO'} |", flush=True)
    cells = " | ".join(f"{100 * worst[k]:.2f} %" for k in KEYS)
    print(f"| worst \\|error\\| | | {cells} | {good_runs} of {runs} |")
    seconds = time.perf_counter() - started
    print(f"{runs} identifications in {seconds:.0f} s", file=sys.stderr)
    return 0 if good_runs == runs else 1


if __name__ == "__main__":
    sys.exit(main())
