"""``frictiongym <command>``: the project's command-line entry point."""

from __future__ import annotations

import argparse
import importlib
import math
import os
import shlex
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any

from frictiongym import __version__
from frictiongym._io import OutputError, check_file_target, pyplot, save_figure


def _format(value: float, unit: str) -> str:
    if math.isinf(value):
        return "never"
    return f"{value:.3f} {unit}".rstrip()


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan  # refused with the option's own message


def _positive_seconds(text: str) -> float:
    value = _number(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def _nonzero_angle(text: str) -> float:
    value = _number(text)
    if not (math.isfinite(value) and value):
        raise argparse.ArgumentTypeError(f"must be a nonzero finite angle in rad, got {text}")
    return value


def _check_plot(path: Path) -> None:
    """Check ``--plot PATH`` before the simulation: its folder, and matplotlib has its format."""
    check_file_target(path, "--plot")
    image_format = path.suffix[1:].lower() or "png"
    try:  # matplotlib only for a plot: heavy, and optional for the metrics
        from matplotlib.backend_bases import FigureCanvasBase
    except ImportError:  # said after the metrics, which are complete without it
        return
    formats = FigureCanvasBase.get_supported_filetypes()
    if image_format not in formats:
        raise OutputError(
            f"--plot {path}: matplotlib cannot write .{image_format} files; "
            f"end the name with one of .{', .'.join(sorted(formats))}"
        )


def _demo(args: argparse.Namespace) -> int:
    if args.plot is not None:
        _check_plot(args.plot)
    # Imported here, so that `frictiongym --help` stays light (no numba, no gymnasium).
    from frictiongym.controllers.pid import PIDGains
    from frictiongym.devices import ROTARY
    from frictiongym.friction import FrictionModel, NoFriction, friction_from_name
    from frictiongym.loops import rotary_step

    gains = PIDGains(**ROTARY.paper_gains["pid"])
    presets = (ROTARY.paper_friction, ROTARY.lugre_friction)
    cases: list[tuple[str, FrictionModel]] = [
        ("nominal (no friction)", NoFriction()),
        (f"friction: {args.friction}", friction_from_name(args.friction, *presets)),
    ]
    print(
        f"QUBE-Servo 2, step of {args.reference} rad, PID Kp={gains.kp} Ki={gains.ki} "
        f"Kd={gains.kd} (paper §3.1), {args.duration} s at 500 Hz, "
        f"encoder {'on' if args.encoder else 'off'}"
    )
    header = f"{'case':<28}{'rise':>10}{'peak':>10}{'settling':>10}{'overshoot':>11}{'SSE':>9}"
    print(header)
    print("-" * len(header))
    runs = []
    for label, friction in cases:
        run = rotary_step(friction, gains, args.reference, args.duration, args.encoder)
        m = run.metrics()
        runs.append((label, run))
        print(
            f"{label:<28}{_format(m.rise_time, 's'):>10}{_format(m.peak_time, 's'):>10}"
            f"{_format(m.settling_time, 's'):>10}{m.overshoot_pct:>10.2f}%"
            f"{m.steady_state_error_pct:>8.2f}%"
        )
    print(
        "\nPaper specs: rise < 0.05 s, peak < 0.1 s, settling < 1.5 s, overshoot < 20 %. "
        "Paper hardware: SSE 2.78 % without compensation."
    )
    print("SSE: mean |r - y| over the last 10 % of the run, % of the step; settling: 2 % band.")
    if args.plot:
        try:
            plt = pyplot()
        except ImportError:
            print(
                "error: --plot needs matplotlib: pip install matplotlib (the metrics above are "
                "complete without it)",
                file=sys.stderr,
            )
            return 1
        fig, (ax, ax_err) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
        for label, run in runs:
            (line,) = ax.plot(run.t, run.signal("position"), label=label)
            error_pct = (args.reference - run.signal("position")) / args.reference * 100.0
            ax_err.plot(run.t, error_pct, color=line.get_color(), label=label)
            if run.stuck[1:].any():  # shade where friction holds the disk (not the start)
                ax_err.fill_between(
                    run.t,
                    0,
                    1,
                    where=run.signal("stuck"),
                    color=line.get_color(),
                    alpha=0.12,
                    transform=ax_err.get_xaxis_transform(),
                    label=f"{label}: stuck",
                )
        ax.axhline(args.reference, color="k", lw=0.8, ls="--", label="reference")
        ax.set(ylabel="angle [rad]", title="QUBE-Servo 2 step under the paper's PID")
        ax.legend(loc="lower right")
        ax_err.axhline(0.0, color="k", lw=0.8, ls="--")
        ax_err.set(xlabel="time [s]", ylabel="error [% of step]", ylim=(-4.0, 4.0))
        ax_err.legend(loc="upper right", fontsize="small")
        fig.tight_layout()
        save_figure(fig, args.plot, dpi=120)
        print(f"figure written to {args.plot}")
    return 0


def _add_tool_arguments(name: str, parser: argparse.ArgumentParser) -> None:
    """Give ``parser`` the description and arguments of the tool command ``name``.

    This imports the tool's module (numba, scipy, gymnasium...), so only the chosen command's
    parser is filled: ``frictiongym --help`` lists the commands from :data:`TOOLS` alone.
    """
    module = importlib.import_module(TOOLS[name][0])
    parser.description = module.DESCRIPTION
    module.add_arguments(parser)
    parser.set_defaults(func=_run_tool)


def _run_tool(args: argparse.Namespace) -> int:
    status: int = importlib.import_module(TOOLS[args.command][0]).run(args, args.command_line)
    return status


def tool_parser(name: str) -> argparse.ArgumentParser:
    """Build the parser of the tool command ``name`` alone (for its tests and help)."""
    parser = argparse.ArgumentParser(
        prog=f"frictiongym {name}", formatter_class=argparse.RawDescriptionHelpFormatter
    )
    _add_tool_arguments(name, parser)
    return parser


def tool_main(name: str, argv: Sequence[str] | None = None) -> int:
    """Run ``frictiongym NAME ARGV...`` (ARGV: the command line's arguments by default).

    The ``scripts/`` wrappers call this.
    """
    return main([name, *(sys.argv[1:] if argv is None else argv)])


#: Tool commands: name -> (module with DESCRIPTION, add_arguments and run; one-line help).
#: A module is imported only when its command is chosen.
TOOLS = {
    "benchmark": (
        "frictiongym.benchmark.command",
        "PID vs compensated PID on the paper's experiments and robustness grids",
    ),
    "identify": (
        "frictiongym.identification.command",
        "measure a device's friction map, break-away levels, J and B; write friction.json",
    ),
    "tune": (
        "frictiongym.tuning.command",
        "the paper's random-search PID tuning against rise/peak/settling/overshoot specs",
    ),
    "sim2real": (
        "frictiongym.sim2real.command",
        "run a controller on a device and in simulation; report the gap and the loop timing",
    ),
    "emulate": (
        "frictiongym.hardware.command",
        "emulate a QUBE-Servo 2, an Altino or a described device behind the protocol",
    ),
    "train": (
        "frictiongym.residual.command",
        "train a residual policy (SAC, TD3, PPO) on top of the compensated PID",
    ),
    "device": (
        "frictiongym.device_command",
        "print a device's description file (show), or check one (check)",
    ),
    "sweep": (
        "frictiongym.sweep.command",
        "seeds x hyperparameter grids of train as Ray Tune trials, ranked on held-out plants",
    ),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """Build the argument parser of ``frictiongym``, with the arguments of ``command`` alone.

    The other tool commands get their name and one-line help, which is all ``--help`` shows.
    """
    parser = argparse.ArgumentParser(
        prog="frictiongym",
        description="Friction identification and compensation for motion control: "
        "simulated plants, Gymnasium envs, controllers and tools.",
    )
    parser.add_argument("--version", action="version", version=f"frictiongym {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    demo = sub.add_parser(
        "demo",
        help="simulate the paper's PID step on the friction-augmented servo",
        description="Simulate the paper's QUBE-Servo 2 step response under its PID "
        "(Kp=7.8, Ki=1.5, Kd=0.275), on the nominal plant and with friction, and print the "
        "step metrics of both.",
    )
    demo.add_argument(
        "--friction",
        default="paper",
        choices=["paper", "coulomb", "stribeck", "lugre"],
        help="friction law added to the nominal plant (default: paper)",
    )
    demo.add_argument(
        "--reference", type=_nonzero_angle, default=1.0, help="step size in rad (default: 1.0)"
    )
    demo.add_argument(
        "--duration",
        type=_positive_seconds,
        default=5.0,
        help="simulated time in s (default: 5.0)",
    )
    demo.add_argument(
        "--no-encoder",
        dest="encoder",
        action="store_false",
        help="feed the PID the true angle instead of 2048-count encoder readings",
    )
    demo.add_argument(
        "--plot",
        type=Path,
        metavar="PNG",
        help="also write the responses to this PNG file (its folder must exist; an existing "
        "file is replaced)",
    )
    demo.set_defaults(func=_demo)

    for name, (_, summary) in TOOLS.items():
        tool = sub.add_parser(
            name, help=summary, formatter_class=argparse.RawDescriptionHelpFormatter
        )
        if name == command:
            _add_tool_arguments(name, tool)
    return parser


class Terminated(KeyboardInterrupt):
    """A ``SIGTERM`` or ``SIGHUP`` (``kill``, ``timeout``, a closed terminal, a CI cancel).

    A command ends on it as on a Ctrl-C, its cleanup included (partial outputs removed,
    ``train``'s checkpoint saved, a device's motor stopped), with status 128 + the signal.
    """

    def __init__(self, signum: int) -> None:
        super().__init__()  # no text: the cleanup may add what it kept, as for a Ctrl-C
        self.signum = signum


def _terminate(signum: int, frame: FrameType | None) -> None:
    raise Terminated(signum)


@contextmanager
def _terminate_like_ctrl_c() -> Iterator[None]:
    """Turn ``SIGTERM``/``SIGHUP`` into :class:`Terminated` while a command runs.

    Only signals left at their default action are taken (an ignored one, as under ``nohup``,
    stays ignored), only from the main thread, and the earlier handlers come back after.
    """
    taken: dict[int, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for name in ("SIGTERM", "SIGHUP"):
            sig = getattr(signal, name, None)
            if sig is not None and signal.getsignal(sig) is signal.SIG_DFL:
                taken[sig] = signal.signal(sig, _terminate)
    try:
        yield
    finally:
        for sig, previous in taken.items():
            signal.signal(sig, previous)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status.

    A Ctrl-C ends a command with one line on stderr and status 130, a ``SIGTERM`` or
    ``SIGHUP`` likewise with 143 or 129 (:class:`Terminated`); the command's own cleanup
    (``frictiongym._io.OutputDir``) has by then removed its partial outputs.
    """
    words = list(sys.argv[1:] if argv is None else argv)
    prog = "frictiongym"
    try:
        with _terminate_like_ctrl_c():
            # The top level takes no option with a value: the first other word is the command.
            command = next((word for word in words if not word.startswith("-")), None)
            parser = build_parser(command)
            args = parser.parse_args(words)
            args.command_line = shlex.join(["frictiongym", *words])
            if args.command is None:
                parser.print_help()
                return 0
            prog = f"frictiongym {args.command}"
            status: int = args.func(args)
    except KeyboardInterrupt as interrupt:
        detail = f"; {interrupt}" if interrupt.args else ""
        if isinstance(interrupt, Terminated):
            name = signal.Signals(interrupt.signum).name
            print(f"{prog}: terminated by {name}{detail}", file=sys.stderr, flush=True)
            return 128 + interrupt.signum
        print(f"{prog}: interrupted{detail}", file=sys.stderr, flush=True)
        return 130
    except OutputError as error:  # an --out or --plot that cannot be written, found up front
        print(f"error: {error}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into e.g. `head`, which closed early: not an error
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # keep Python's exit flush from failing again
        return 0
    return status


if __name__ == "__main__":
    sys.exit(main())
