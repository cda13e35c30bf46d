"""Benchmark figures in the spirit of the paper's: responses and friction curves.

Responses as in Figs. 6, 7, 11 and 12, friction curves as in Figs. 8 and 10, and the
compensator variants under model mismatch.

matplotlib is imported inside the functions (``frictiongym._io.pyplot``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from frictiongym import devices
from frictiongym._io import pyplot, save_figure
from frictiongym.benchmark.report import residual_pairs
from frictiongym.benchmark.run import Result
from frictiongym.devices import Device
from frictiongym.friction import FRICTION_NAMES, FrictionModel, friction_from_name


def _friction_panel(
    ax: Any, title: str, laws: dict[str, FrictionModel], v_max: float, units: tuple[str, str]
) -> None:
    v = np.concatenate([np.linspace(-v_max, -1e-9, 600), np.linspace(1e-9, v_max, 600)])
    for name, law in laws.items():
        ax.plot(v, law.force(v), label=name, lw=1.6 if name == "paper" else 1.1)
    us_pos, us_neg = laws["paper"].breakaway
    ax.plot(
        [0.0, 0.0],
        [-us_neg, us_pos],
        color="k",
        lw=3,
        solid_capstyle="butt",
        label="at rest: holds inside",
    )
    viscous = getattr(laws["paper"], "viscous", 0.0)
    if viscous:
        ax.plot(v, viscous * v, color="grey", ls="-.", lw=0.9, label="viscous part")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set(title=title, xlabel=f"velocity [{units[1]}]", ylabel=f"friction [{units[0]}]")
    ax.legend(fontsize="small", loc="upper left")


def plot_friction_curves(path: Path, among: Sequence[Device] | None = None) -> Path:
    """Steady friction of every law for every device (the paper's Figs. 8(b), 10(b))."""
    among = devices.DEVICES if among is None else among
    plt = pyplot()
    fig, axes = plt.subplots(1, len(among), figsize=(5.5 * len(among), 4.2), squeeze=False)
    for ax, device in zip(axes[0], among, strict=True):
        presets = (device.paper_friction, device.lugre_friction)
        laws = {name: friction_from_name(name, *presets) for name in FRICTION_NAMES}
        units = (device.command_unit, device.units["velocity"])
        _friction_panel(ax, device.figures.friction, laws, device.figures.speed, units)
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


#: Legends of the paper scenarios' runs in their device's response figure (another scenario's
#: legend is its description).
PAPER_LABELS = {
    "paper-rotary-nominal": "PID, nominal (no friction)",
    "paper-rotary-pid": "PID, paper friction",
    "paper-rotary-compensated": "PID + compensator",
    "paper-altino-pid-ki10": "PID Ki 10",
    "paper-altino-pid-ki20": "PID Ki 20",
    "paper-altino-compensated": "PID (Ki 0.5, Kd 7) + compensator",
}


def figure_names(among: Sequence[Device] | None = None) -> list[str]:
    """Return the file names :func:`write_figures` may write, for the devices ``among``."""
    among = devices.DEVICES if among is None else among
    shared = ["compensator_mismatch.png", "residual_plants.png", "friction_curves.png"]
    return [f"{p}{d.kind}_response.png" for d in among for p in ("", "residual_")] + shared


def _responses(
    results: Sequence[Result],
    names: dict[str, str],
    path: Path,
    title: str,
    zoom: float,
) -> Path | None:
    """Output and command of the named runs on shared axes (output, error zoom, command)."""
    runs = {r.scenario.name: r for r in results if r.seed == r.scenario.seeds[0]}
    chosen = [(label, runs[name]) for name, label in names.items() if name in runs]
    if not chosen:
        return None
    device = devices.get(chosen[0][1].scenario.env_id)
    units = (device.position_unit, device.command_unit)
    plt = pyplot()
    fig, (ax, ax_err, ax_u) = plt.subplots(
        3, 1, figsize=(8, 8), sharex=True, gridspec_kw={"height_ratios": [3, 2, 2]}
    )
    for label, r in chosen:
        t = r.rollout.t[: r.rollout.length[r.env]]
        y = r.rollout.signal("position", r.env)
        ref = r.rollout.signal("reference", r.env)
        (line,) = ax.plot(t, y, label=label, lw=1.3)
        ax_err.plot(t, ref - y, color=line.get_color(), lw=1.1)
        ax_u.plot(t, r.rollout.signal("command", r.env), color=line.get_color(), lw=0.9)
    first = chosen[0][1]
    ax.plot(
        first.rollout.t, first.rollout.reference[:, first.env], "k--", lw=0.8, label="reference"
    )
    ax.set(title=title, ylabel=f"output [{units[0]}]")
    ax.legend(loc="best", fontsize="small")
    ax_err.axhline(0.0, color="k", lw=0.6)
    ax_err.set(ylabel=f"error r - y [{units[0]}]", ylim=(-zoom, zoom))
    ax_u.set(xlabel="time [s]", ylabel=f"command [{units[1]}]")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def plot_mismatch(results: Sequence[Result], path: Path) -> Path | None:
    """SSE and limit-cycle amplitude of each compensator variant against model mismatch."""
    runs = [r for r in results if r.scenario.group == "mismatch"]
    if not runs:
        return None
    plt = pyplot()
    kinds = list(dict.fromkeys(r.scenario.device for r in runs))  # in the runs' order
    fig, axes = plt.subplots(2, len(kinds), figsize=(5.5 * len(kinds), 6.5), squeeze=False)
    for col, device in enumerate(kinds):
        mine = [r for r in runs if r.scenario.device == device]
        unit = devices.get(device).position_unit
        for mode in dict.fromkeys(r.scenario.mode for r in mine):
            pts = sorted((r.scenario.scale, r.metrics) for r in mine if r.scenario.mode == mode)
            scales = [s for s, _ in pts]
            axes[0, col].plot(scales, [m.steady_state_error_pct for _, m in pts], "o-", label=mode)
            axes[1, col].plot(scales, [m.limit_cycle_amplitude for _, m in pts], "o-", label=mode)
        axes[0, col].set(title=f"{device}: compensator model mismatch", ylabel="SSE [% of step]")
        axes[1, col].set(
            xlabel="compensator friction / plant friction", ylabel=f"limit-cycle amplitude [{unit}]"
        )
        for ax in axes[:, col]:
            ax.axvline(1.0, color="k", lw=0.6, ls=":")
            ax.legend(fontsize="small")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def plot_residual_plants(results: Sequence[Result], path: Path) -> Path | None:
    """Per-plant ITAE and SSE of the residual against the compensated PID (held-out plants).

    One point per plant, log-log, with the diagonal: below it the residual is better. The
    means hide how a stuck body's resting place scatters from plant to plant; this shows it.
    """
    heldout = {
        device: pairs
        for (device, plants), pairs in residual_pairs(results).items()
        if plants == "heldout"
    }
    kinds = [kind for kind in dict.fromkeys(r.scenario.device for r in results) if kind in heldout]
    if not kinds:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(len(kinds), 2, figsize=(9, 4.2 * len(kinds)), squeeze=False)
    for row, device in enumerate(kinds):
        pairs = heldout[device]
        unit = devices.get(device).position_unit
        for col, (metric, label) in enumerate(
            (("itae", f"ITAE [{unit}·s²]"), ("steady_state_error", f"SSE [{unit}]"))
        ):
            x = np.array([getattr(base.metrics, metric) for base, _ in pairs])
            y = np.array([getattr(resid.metrics, metric) for _, resid in pairs])
            wins = int(np.sum(y < x))  # before the floor, as in the results table
            floor = max(min(np.min(x[x > 0], initial=1.0), np.min(y[y > 0], initial=1.0)), 1e-9)
            x, y = np.maximum(x, floor), np.maximum(y, floor)
            ax = axes[row, col]
            ax.loglog(x, y, "o", ms=4, alpha=0.7, label=f"residual better on {wins}/{len(x)}")
            span = [min(x.min(), y.min()) / 1.5, max(x.max(), y.max()) * 1.5]
            ax.loglog(span, span, "k--", lw=0.8, label="equal")
            ax.set(
                title=f"{device}: {len(pairs)} held-out plants",
                xlabel=f"compensated PID {label}",
                ylabel=f"residual {label}",
            )
            ax.legend(fontsize="small", loc="upper left")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def write_figures(
    results: Sequence[Result], out: Path, among: Sequence[Device] | None = None
) -> list[Path]:
    """Write every figure the results of the devices ``among`` (default all) allow into ``out``."""
    among = devices.DEVICES if among is None else among
    paper = [r.scenario for r in results if r.scenario.group == "paper"]
    written = []
    for device in among:
        kind, figures = device.kind, device.figures
        mine = {s.name: PAPER_LABELS.get(s.name, s.description) for s in paper if s.device == kind}
        residual = {
            f"residual-{kind}-nominal-compensated": "PID + compensator",
            f"residual-{kind}-nominal-residual": "PID + compensator + residual",
        }
        written += [
            _responses(results, mine, out / f"{kind}_response.png", figures.response, figures.zoom),
            _responses(
                results,
                residual,
                out / f"residual_{kind}_response.png",
                figures.residual,
                figures.residual_zoom,
            ),
        ]
    written.append(plot_mismatch(results, out / "compensator_mismatch.png"))
    written.append(plot_residual_plants(results, out / "residual_plants.png"))
    written.append(plot_friction_curves(out / "friction_curves.png", among))
    return [p for p in written if p is not None]
