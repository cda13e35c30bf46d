"""``frictiongym identify``: measure a device's friction and linear part into ``friction.json``."""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from typing import Any

from frictiongym import devices
from frictiongym._io import OutputDir, add_output_arguments, write_text_atomic
from frictiongym._validation import check_seed, real_number
from frictiongym.hardware.errors import HardwareError
from frictiongym.identification.backlash import ReversalPlan
from frictiongym.identification.drivetrain import PLAY_ROUNDS
from frictiongym.identification.estimates import IdentificationError
from frictiongym.identification.figures import plot_map
from frictiongym.identification.fit import LAWS
from frictiongym.identification.from_log import describe_source
from frictiongym.identification.identify import (
    Identification,
    identify,
    make_env,
    plan_for,
)
from frictiongym.identification.log_command import add_log_arguments, run_from_log
from frictiongym.identification.validate import KEYS, truth
from frictiongym.params import save_params

DESCRIPTION = """\
Identify the friction and the linear part of a device through its env, as the paper does
(section 4): slow ramps from rest give the break-away levels u_s+/-, levels held in both
directions give the steady-state friction map, velocity steps give J and B, and least squares
fits the paper's law (and the Stribeck, smooth and Coulomb alternatives) to the map.

Writes to --out:
  friction.json   the parameters (us_pos us_neg uc_pos uc_neg v0_pos v0_neg viscous J B law),
                  their standard errors and the experiments; load it with
                  gym.make(ID, params=PATH) or FrictionCompensator(pid, model=PATH)
  friction_map.png  the measured map with the fitted laws and residuals (paper Fig. 8)
  summary.md      the table printed at the end

An --out holding an earlier run's results is refused unless --overwrite replaces them (all
three; other files there stay); an error or a Ctrl-C leaves --out as it was.

On the simulator the table also shows the simulated truth. Every experiment runs through
the env's observations only, so a device backend (--backend) runs the same procedure.

--backlash adds a reversal test: the command reverses after each steady slide, and the play
W between motor and load is fitted to the load's path after each reversal. The load's sensor
sees the play only through the motor's motion inside it, so W holds for the device preset's
shares of inertia and friction, which are assumed, not measured. A resolved W goes into
friction.json as "backlash" (gym.make(ID, params=PATH) then simulates it); one below the
sensor's resolution is reported as not resolved, with the bound, in the summary and in
friction.json's metadata.

--dead-zone fits an actuator dead zone (the band of commands the amplifier or motor ignores)
to the same reversal run: every other experiment drives the body the way it moves, where a
zone of half-width d only raises each friction level by d; after a reversal the zone weakens
the braking command instead. A resolved d goes into friction.json as "dead_zone" with each
level lowered by it (FrictionCompensator(model=PATH) then inverts the zone).
"""

#: What a run may write into --out.
OUTPUTS = ("friction.json", "friction_map.png", "summary.md")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the command's options to ``parser``."""
    parser.add_argument(
        "--env",
        "--device",
        dest="env",
        required=True,
        metavar="ID|FILE",
        help=f"the device: an env id ({', '.join(d.env_id for d in devices.DEVICES)}) or a "
        "device description file (.toml or .json, docs/devices.md)",
    )
    add_output_arguments(
        parser, "identify-results", "friction.json, friction_map.png and summary.md"
    )
    parser.add_argument(
        "--backend",
        default="sim",
        metavar="URI",
        help="where the env runs: sim (default) or a device backend URI",
    )
    parser.add_argument(
        "--law",
        default="paper",
        choices=[*LAWS, "best"],
        help="law written to friction.json: the paper's (default) or the lowest-AIC one",
    )
    parser.add_argument(
        "--friction",
        default="paper",
        metavar="LAW",
        help="simulator only: the true friction law of the simulated device (default: paper)",
    )
    parser.add_argument(
        "--noise",
        action="store_true",
        help="simulator only: add the device's default sensor noise",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulator (default: 0)")
    parser.add_argument(
        "--backlash",
        action="store_true",
        help="also run the reversal test and estimate a play between motor and load "
        "(off by default; needs --law paper)",
    )
    parser.add_argument(
        "--true-backlash",
        type=float,
        default=None,
        metavar="W",
        help="simulator only: a play of full width W (position units) in the simulated device "
        "(default: none)",
    )
    parser.add_argument(
        "--max-backlash",
        type=float,
        default=None,
        metavar="W",
        help="with --backlash: the widest play searched, position units (default: the "
        "device's, 0.2 rad on the servo, 1 cm on the Altino)",
    )
    parser.add_argument(
        "--dead-zone",
        action="store_true",
        help="also fit an actuator dead zone to the reversal run (off by default; needs --law "
        "paper)",
    )
    parser.add_argument(
        "--true-dead-zone",
        type=float,
        default=None,
        metavar="D",
        help="simulator only: a dead zone of half-width D (command units) in the simulated "
        "device (default: none)",
    )
    add_log_arguments(parser)
    parser.add_argument("--no-figures", action="store_true", help="skip friction_map.png")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def summary(result: Identification, law: str, truth: dict[str, float] | None) -> str:
    """Return the result as a markdown table (value, standard error, simulated truth, error)."""
    params = result.params(law)
    values = params.to_dict()
    header = "| parameter | identified | std. error |"
    rule = "|---|---|---|"
    if truth is not None:
        header += " simulated truth | error |"
        rule += "---|---|"
    shape = getattr(params.friction, "shape", None)
    what = f"{result.device} ({params.law} law{f', shape {shape}' if shape else ''})"
    if result.source is None:
        lines = [
            f"Identification of {what}: {len(result.traces)} experiments, "
            f"{result.env_steps} env steps, {result.seconds:.1f} s"
        ]
    else:
        lines = [f"Identification of {what}.", "", *describe_source(result.source)]
    lines += ["", header, rule]
    for key in KEYS:
        value = values.get(key)
        if value is None:
            continue
        se = params.uncertainty.get(key, math.nan)
        row = f"| {key} | {value:.6g} | {'-' if math.isnan(se) else f'{se:.2g}'} |"
        if truth is not None:
            true = truth.get(key, math.nan)
            error = (value - true) / true * 100.0 if true else math.nan
            row += f" {true:.6g} | {error:+.2f} % |"
        lines.append(row)
    lines += ["", "| law | RMS of the map fit | AIC |", "|---|---|---|"]
    for fit in result.fits.values():
        rms = "refined on all samples" if math.isnan(fit.rms) else f"{fit.rms:.3g}"
        lines.append(f"| {fit.law} | {rms} | {fit.aic:.1f} |")
    if result.backlash is not None:
        lines += ["", f"Reversal test: {result.backlash.describe()}."]
        true_play = None if truth is None else truth.get("backlash")
        if true_play is not None:
            lines.append(f"Simulated truth: W = {true_play:.6g} {result.backlash.unit}.")
    if result.dead_zone is not None:
        lines += ["", f"Reversal test: {result.dead_zone.describe()}."]
        true_zone = None if truth is None else truth.get("dead_zone")
        if true_zone is not None:
            lines.append(f"Simulated truth: d = {true_zone:.6g} {result.dead_zone.unit}.")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace, command_line: str) -> int:
    """Run the command; return the exit status."""
    if args.from_log is not None:
        return run_from_log(args, command_line, _write, OUTPUTS)
    if args.inertia is not None:
        print("error: --inertia applies to --from-log with a map", file=sys.stderr)
        return 2
    sim = args.backend in ("sim", "sim://")
    kwargs: dict[str, Any] = {"backend": args.backend}
    try:  # named by their flags here; the env would name its keywords
        for flag, value in (
            ("--true-backlash", args.true_backlash),
            ("--true-dead-zone", args.true_dead_zone),
        ):
            if value is not None:
                real_number(flag, value, ">= 0")
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if sim:
        kwargs.update(friction=args.friction, sensor_noise=bool(args.noise))
        if args.true_backlash is not None:  # only when given: default runs record no key
            kwargs["backlash"] = args.true_backlash
        if args.true_dead_zone is not None:
            kwargs["deadzone"] = args.true_dead_zone
    elif (
        args.noise
        or args.friction != "paper"
        or args.true_backlash is not None
        or args.true_dead_zone is not None
    ):
        print(
            "error: --noise, --friction, --true-backlash and --true-dead-zone apply to the "
            "simulator only",
            file=sys.stderr,
        )
        return 2
    for flag, given in (("--backlash", args.backlash), ("--dead-zone", args.dead_zone)):
        if given and args.law != "paper":
            print(
                f"error: {flag} is estimated with the paper law; drop --law {args.law} or {flag}",
                file=sys.stderr,
            )
            return 2
    try:
        check_seed(args.seed)
        plan = plan_for(args.env)
        args.reversal = None
        if args.backlash or args.dead_zone:
            args.reversal = ReversalPlan.for_device(args.env)
        if args.max_backlash is not None:
            if not args.backlash:
                raise ValueError("--max-backlash sets the reversal test's search: add --backlash")
            width = real_number("--max-backlash", args.max_backlash, "> 0")
            args.reversal = replace(args.reversal, max_width=width)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    with OutputDir(args.out, OUTPUTS, overwrite=args.overwrite) as out:  # before the device
        status = _identify(args, plan, kwargs, sim, command_line, out)
        if status == 0:
            written = out.commit()
    if status == 0:
        print(f"wrote {', '.join(str(p) for p in written)}")
    return status


def _identify(
    args: argparse.Namespace,
    plan: Any,
    kwargs: dict[str, Any],
    sim: bool,
    command_line: str,
    out: OutputDir,
) -> int:
    """Open the env, identify and write the outputs into ``out.path``; return the status."""
    try:
        env = make_env(args.env, plan, **kwargs)
    except (ValueError, TypeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (OSError, HardwareError) as exc:  # a device backend that cannot be opened
        print(f"error: backend {args.backend}: {exc}", file=sys.stderr)
        return 2
    from tqdm import tqdm  # only when running: keeps every `frictiongym` start-up lean

    total = 2 + 2 * (plan.ramp_repeats + len(plan.levels) + plan.step_repeats)
    total += len(plan.relay_levels) + plan.refine
    total += args.backlash * (1 + (PLAY_ROUNDS if plan.refine else 0))
    total += args.dead_zone * (1 + plan.refine)
    bar = tqdm(total=total, unit="run", desc="identify", leave=False, disable=args.quiet)

    def progress(label: str) -> None:
        bar.set_postfix_str(label, refresh=False)
        bar.update(1)

    try:
        result = identify(
            env,
            plan,
            seed=args.seed,
            progress=progress,
            backlash=args.reversal if args.backlash else False,
            dead_zone=args.dead_zone,
        )
    except IdentificationError as exc:
        print(f"error: identification failed: {exc}", file=sys.stderr)
        return 1
    finally:
        bar.close()
        env.close()
    true: dict[str, float] | None = None
    if sim:
        true = truth(env.unwrapped.sim.friction, env.unwrapped.sim.plant)
        if result.backlash is not None:
            true["backlash"] = env.unwrapped.sim.plant.backlash
        if result.dead_zone is not None:
            true["dead_zone"] = env.unwrapped.sim.plant.dead_zone
    _write(result, args, out, {"command": command_line, "env_kwargs": kwargs}, true)
    return 0


def _write(
    result: Identification,
    args: argparse.Namespace,
    out: OutputDir,
    metadata: dict[str, Any],
    true: dict[str, float] | None,
) -> None:
    """Write friction.json (``metadata`` added), summary.md and the figure; print the table."""
    params = result.params(args.law)
    save_params(
        out.path / "friction.json", replace(params, metadata={**params.metadata, **metadata})
    )
    table = summary(result, args.law, true)
    write_text_atomic(out.path / "summary.md", table)
    if not args.no_figures:
        units = devices.get(result.device).units
        plot_map(result, out.path / "friction_map.png", (units["velocity"], units["force"]))
    print(table)
