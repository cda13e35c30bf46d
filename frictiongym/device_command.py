"""``frictiongym device``: print a device's description file, or check one."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import Any

from frictiongym import device_file, devices, envs
from frictiongym.device_file import AXIS_ENV_ID
from frictiongym.plants import sensors

DESCRIPTION = """\
Describe a device in a file (TOML or JSON; docs/devices.md), the input of every tool's
--device and of gym.make("frictiongym/Axis-v0", device=FILE).

  frictiongym device show rotary --name MyServo > my_servo.toml   a file to start from
  frictiongym device check my_servo.toml           read it as the tools will; print a summary

show --name gives the copy its own name (and kind: the name in lower case) and the env id of
described devices, frictiongym/Axis-v0; without it, the copy is the built-in device itself.

check prints the device's units, plant, friction law, sensor, task and what the tools have
for it (identification plan, reversal test, tuning specs), or one line naming the field
that is wrong, its unit and what it may be (exit status 2).
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the command's arguments to ``parser``."""
    parser.add_argument("action", choices=("show", "check"), help="show a file, or check one")
    parser.add_argument(
        "device",
        metavar="KIND|FILE",
        help=f"a built-in device ({', '.join(d.kind for d in devices.DEVICES)}) or a file",
    )
    parser.add_argument(
        "--name", help="show: the copy's own name (letters, digits and _), kind and env id"
    )


def summary(device: devices.Device) -> str:
    """Return what ``check`` prints of a readable description."""
    law, plant = device.paper_friction, device.plant
    units = device.units
    sensor = (
        f"encoder, {device.counts_per_rev} counts per {device.position_per_rev:g} "
        f"{device.position_unit} ({device.encoder_step:.4g} {device.position_unit} per count)"
        if device.counts_per_rev
        else "IR readout 0..800, d = 966/(x + 45) (the paper's Eq. (1))"
    )
    plan = device.identification
    identify = f"plan of {len(plan['levels'])} levels" if "levels" in plan else "no plan"
    identify += ", reversal test" if "reversal" in plan else ""
    tune = "the file's specs" if device.tuning else "the paper's specs"
    if device.sensor != sensors.SENSOR_ENCODER:
        tune = "not for this sensor (it steps from rest at 0 of an encoder device)"
    lines = [
        f"{device.name} ({device.kind}): {device.title}, {device.env_id}",
        f"  units: position {device.position_unit}, command {device.command_unit}, "
        f"period {device.dt * 1e3:g} ms",
        f"  plant: J {plant.inertia:g} {units['J']}, B {plant.damping:g} {units['B']}, "
        f"limit ±{plant.command_limit:g} {device.command_unit}, dead time "
        f"{plant.dead_time * 1e3:g} ms",
        f"  friction: break-away {law.us_pos:g}/{law.us_neg:g}, Coulomb "
        f"{law.uc_pos:g}/{law.uc_neg:g} {device.command_unit}, viscous {law.viscous:g}",
        f"  sensor: {sensor}",
        f"  task: step to {device.references['step']['value']:g} {device.position_unit}, "
        f"{device.episode_steps} steps, safety limit {device.limit:g} {device.position_unit}",
        f"  PID: {dict(device.paper_gains['pid'])}",
        f"  identify: {identify}",
        f"  tune: {tune}",
    ]
    return "\n".join(lines)


def check_for_tools(device: devices.Device) -> None:
    """Build what each tool builds from ``device`` and the env of its training; raise if not.

    Raises
    ------
    ValueError
        What a tool would raise, prefixed with the file and the table.
    """
    from frictiongym.controllers.residual_core import ResidualConfig
    from frictiongym.identification.backlash import ReversalPlan
    from frictiongym.identification.identify import Plan
    from frictiongym.tuning.specs import GainBounds, StepSpecs

    where = device.source or device.name
    plan = device.identification
    steps: list[tuple[str, Any]] = [("references", lambda: envs.checked_device(device))]
    if "levels" in plan:
        steps.append(("identification", lambda: Plan.for_device(device)))
    if "reversal" in plan:
        steps.append(("identification.reversal", lambda: ReversalPlan.for_device(device)))
    if device.residual:
        limit = device.plant.command_limit
        steps.append(("residual", lambda: ResidualConfig(device.name, limit, **device.residual)))
    specs = {k: v for k, v in device.tuning.items() if k not in ("kp", "ki", "kd")}
    bounds = {k: tuple(v) for k, v in device.tuning.items() if k in ("kp", "ki", "kd")}
    steps.append(("tuning", lambda: (StepSpecs(**specs), GainBounds(**bounds))))
    steps.append(("training_env", lambda: envs.make(device, **device.training_env).close()))
    for table, build in steps:
        try:
            build()
        except (TypeError, ValueError) as error:
            message = str(error).removeprefix(f"{where}: ")
            raise ValueError(f"{where}: [{table}]: {message}") from None


def run(args: argparse.Namespace, command_line: str = "frictiongym device") -> int:
    """Run the command; return the exit status."""
    try:
        device = devices.get(args.device)
        if args.action == "check":
            check_for_tools(device)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.action == "show":
        if args.name is not None:
            renamed = {"name": args.name, "kind": args.name.lower(), "env_id": AXIS_ENV_ID}
            try:
                device_file.parse({**device_file.toml_loads(device_file.dump(device)), **renamed})
            except device_file.DeviceFileError as error:
                print(f"error: --name: {error}", file=sys.stderr)
                return 2
            device = dataclasses.replace(device, **renamed)
        sys.stdout.write(device_file.dump(device))
    else:
        print(summary(device))
    return 0
