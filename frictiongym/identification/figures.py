"""The identification's figure: the measured friction map with the fitted laws (Fig. 8(b))."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from frictiongym._io import pyplot, save_figure
from frictiongym.identification.identify import Identification

_COLORS = {"paper": "C0", "stribeck": "C1", "smooth": "C2", "coulomb": "C3"}


def plot_map(result: Identification, path: str | Path, units: tuple[str, str]) -> Path:
    """Write the map, the fits and their residuals to ``path`` (PNG) whole; return it.

    Parameters
    ----------
    result : Identification
    path : str or Path
    units : tuple of str
        Velocity and command units for the axis labels, e.g. ``("rad/s", "V")``.
    """
    plt = pyplot()
    vel_unit, cmd_unit = units
    moving = [p for p in result.points if p.moved]
    v = np.array([p.sign * p.velocity for p in moving])
    u = np.array([p.sign * p.level for p in moving])
    stuck = [p for p in result.points if not p.moved]
    span = float(np.abs(v).max()) * 1.05 if v.size else 1.0
    grid = np.concatenate([np.linspace(-span, -1e-9, 400), np.linspace(1e-9, span, 400)])

    fig, (ax, ax_nl, ax_res) = plt.subplots(
        3, 1, figsize=(7.5, 9.5), gridspec_kw={"height_ratios": [3, 3, 2]}
    )
    ax.plot(v, u, "k.", ms=7, label="steady speed of a held level", zorder=3)
    for ramp in result.breakaways:
        ax.plot(0.0, ramp.sign * ramp.level, "kx", ms=7)
    ax.plot([], [], "kx", label="break-away of a slow ramp")
    if stuck:
        ax.plot(
            np.zeros(len(stuck)),
            [p.sign * p.level for p in stuck],
            "o",
            mfc="none",
            mec="0.5",
            label="held level that did not move",
        )
    for law, each in result.fits.items():
        label = (
            f"{law} law (RMS {each.rms:.3g} {cmd_unit})"
            if np.isfinite(each.rms)
            else f"{law} law (refined on all samples)"
        )
        ax.plot(grid, each.predict(grid), color=_COLORS.get(law), lw=1.4, label=label)
    ax.axhline(0, color="0.7", lw=0.6)
    ax.axvline(0, color="0.7", lw=0.6)
    title = f"{result.device}: steady-state friction map (cf. paper Fig. 8(a)/10(a))"
    ax.set(xlabel=f"velocity [{vel_unit}]", ylabel=f"command [{cmd_unit}]", title=title)
    ax.legend(fontsize="small", loc="upper left")

    # Fig. 8(b): the paper's law split into its viscous line and its stiction/Coulomb part.
    fit = result.fits.get("paper")
    if fit is not None:
        b = fit.values["viscous"]
        total = fit.predict(grid)
        ax_nl.plot(grid, total, color="C0", lw=1.6, label="fitted law (total)")
        ax_nl.plot(
            grid, b * grid, "k-.", lw=1.0, label=f"viscous slope {b:.4g} {cmd_unit}/({vel_unit})"
        )
        ax_nl.plot(grid, total - b * grid, color="C3", lw=1.6, label="stiction + Coulomb part")
        ax_nl.plot(v, u - b * v, "k.", ms=5, label="measured minus viscous")
        vals = fit.values
        text = (
            f"$u_s^+$={vals['us_pos']:.4g}, $u_c^+$={vals['uc_pos']:.4g}, "
            f"$v_0^+$={vals['v0_pos']:.4g}\n$u_s^-$={-vals['us_neg']:.4g}, "
            f"$u_c^-$={-vals['uc_neg']:.4g}, $v_0^-$={-vals['v0_neg']:.4g}"
        )
        ax_nl.text(0.02, 0.04, text, transform=ax_nl.transAxes, fontsize="small")
        ax_nl.axhline(0, color="0.7", lw=0.6)
        ax_nl.axvline(0, color="0.7", lw=0.6)
        ax_nl.set(
            xlabel=f"velocity [{vel_unit}]",
            ylabel=f"command [{cmd_unit}]",
            title="the paper's law (cf. Fig. 8(b)/10(b))",
        )
        ax_nl.legend(fontsize="small", loc="upper left")

    order = np.argsort(v)
    v, u = v[order], u[order]
    for law, f in result.fits.items():
        ax_res.plot(v, u - f.predict(v), "o-", ms=3, lw=0.8, color=_COLORS.get(law), label=law)
    ax_res.axhline(0, color="k", lw=0.6)
    ax_res.set(
        xlabel=f"velocity [{vel_unit}]",
        ylabel=f"residual [{cmd_unit}]",
        title="goodness of fit: measured minus fitted level",
    )
    ax_res.legend(fontsize="small", ncol=4)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
