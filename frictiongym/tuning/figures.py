"""``tune.png``: the feasible set in the three gain planes and the feasible step responses.

matplotlib is imported inside the functions (``frictiongym._io.pyplot``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from frictiongym import devices
from frictiongym._io import pyplot, save_figure
from frictiongym.tuning.evaluate import PAPER_GAINS, simulate
from frictiongym.tuning.search import RULES, TuneResult

#: Infeasible samples drawn in the planes at most (a random subset: the grey cloud's density is
#: all it shows, and 100 000 markers make a slow, heavy PNG).
MAX_GREY = 4_000
#: Feasible step responses drawn at most (the best by the rule's score).
MAX_RESPONSES = 200


def _labels(result: TuneResult) -> dict[int, str]:
    """Axis labels of the three gains, in the device's units."""
    units = _units(result)
    c, p = units["force"], units["position"]
    return {0: f"Kp [{c}/{p}]", 1: f"Ki [{c}/({p}·s)]", 2: f"Kd [{c}·s/{p}]"}


def _units(result: TuneResult) -> dict[str, str]:
    try:
        device = devices.get(result.model.device)
    except ValueError:  # a description file not loaded in this process
        return {"force": "command", "position": "position"}
    return {"force": device.command_unit, "position": device.position_unit}


def _baseline_label(result: TuneResult) -> str:
    gains = ", ".join(f"{g:g}" for g in result.model.baseline)
    return f"paper ({gains})" if result.model.baseline == PAPER_GAINS else f"device's PID ({gains})"


def _zoom(result: TuneResult, i: int) -> tuple[float, float]:
    """Axis range around the feasible set and the paper's gains along gain ``i``."""
    values = [*result.gains[result.feasible_indices, i], result.model.baseline[i]]
    lo, hi = min(values), max(values)
    pad = 0.1 * (hi - lo) or 0.05 * float(result.bounds.high[i])
    return max(lo - pad, float(result.bounds.low[i])), min(hi + pad, float(result.bounds.high[i]))


def _planes(axes: Any, result: TuneResult, pairs: Any, zoom: bool) -> Any:
    gains, feasible = result.gains, result.evaluation.feasible
    grey = np.flatnonzero(~feasible)
    if grey.size > MAX_GREY:
        grey = np.random.default_rng(0).choice(grey, MAX_GREY, replace=False)
    good = result.feasible_indices
    good = good[np.argsort(-result.scores[good])]  # best drawn last, on top
    sc = None
    for ax, (i, j) in zip(axes, pairs, strict=True):
        ax.scatter(
            gains[grey, i],
            gains[grey, j],
            s=1.5,
            c="0.82",
            lw=0,
            rasterized=True,
            label=f"infeasible ({result.n_samples - result.n_feasible})",
        )
        if good.size:
            sc = ax.scatter(
                gains[good, i],
                gains[good, j],
                s=8,
                c=result.scores[good],
                cmap="viridis_r",
                lw=0,
                label=f"feasible ({good.size})",
            )
        if result.chosen is not None:
            c = result.gains[result.chosen]
            ax.plot(c[i], c[j], "*", ms=15, mfc="red", mec="k", label="chosen")
        ax.plot(
            result.model.baseline[i],
            result.model.baseline[j],
            "X",
            ms=10,
            mfc="orange",
            mec="k",
            label=_baseline_label(result),
        )
        lo, hi = result.bounds.low, result.bounds.high
        xlim, ylim = ((lo[i], hi[i]), (lo[j], hi[j]))
        if zoom and good.size:
            xlim, ylim = _zoom(result, i), _zoom(result, j)
        ax.set(
            xlim=xlim,
            ylim=ylim,
            xlabel=_labels(result)[i],
            ylabel=_labels(result)[j],
            title="zoom on the feasible set" if zoom else "",
        )
    return sc


def _responses(ax: Any, result: TuneResult) -> None:
    s, good = result.specs, result.feasible_indices
    good = good[np.argsort(result.scores[good])][:MAX_RESPONSES]
    picks = [*good, *([] if result.chosen is None else [result.chosen])]
    baseline = [result.model.baseline]
    gains = np.vstack([result.gains[picks], baseline]) if picks else np.array(baseline)
    ev = simulate(gains, result.model, s, result.horizon, early_stop=False, keep_traces=True)
    step = result.model.step
    t, y = ev.t, ev.traces
    assert y is not None  # keep_traces=True always returns them
    n = len(good)
    if n:
        ax.plot(t, y[:, :n], color="tab:blue", lw=0.5, alpha=0.25)
        ax.plot([], [], color="tab:blue", lw=0.8, label=f"feasible (best {n} by {result.rule})")
    if result.chosen is not None:
        ax.plot(t, y[:, n], color="red", lw=1.8, label="chosen")
    ax.plot(t, y[:, -1], color="orange", lw=1.8, ls="--", label=_baseline_label(result))
    ax.axhline(
        step * (1 + s.overshoot_pct / 100),
        color="k",
        lw=0.8,
        ls=":",
        label=f"overshoot limit {s.overshoot_pct:g} %",
    )
    ax.axvline(s.peak_time, color="k", lw=0.8, ls="-.", label=f"peak-time limit {s.peak_time:g} s")
    ax.axvspan(
        0,
        s.rise_time,
        color="tab:green",
        alpha=0.08,
        label=f"rise-time limit {s.rise_time:g} s (10→90 %)",
    )
    band = f"±{s.settling_band * 100:g} % band (settled by {s.settling_time:g} s)"
    ax.axhspan(
        step * (1 - s.settling_band),
        step * (1 + s.settling_band),
        color="0.6",
        alpha=0.3,
        label=band,
    )
    ax.set(
        xlim=(0.0, min(0.5, float(t[-1]))),
        ylim=(0.0, 1.35 * step),
        xlabel="time [s]",
        ylabel=f"position [{_units(result)['position']}]",
        title=f"{step:g} {_units(result)['position']} step responses (first 0.5 s)",
    )
    ax.legend(fontsize="x-small", loc="lower right")


def plot_feasible_set(result: TuneResult, path: Path, responses: bool = True) -> Path:
    """Write the figure of ``result`` to ``path`` (PNG) atomically; return ``path``.

    Top row: the three gain planes over the full bounds; bottom row: the Kp-Kd and Ki-Kd
    planes zoomed on the feasible set, and the feasible step responses with the spec limits.
    """
    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(15, 9), layout="constrained")
    _planes(axes[0], result, ((0, 1), (0, 2), (1, 2)), zoom=False)
    sc = _planes(axes[1, :2], result, ((0, 2), (1, 2)), zoom=True)
    axes[0, 0].legend(fontsize="small", loc="upper left", markerscale=1.5, framealpha=0.9)
    if sc is not None:
        fig.colorbar(
            sc,
            ax=axes[:, :2].ravel().tolist(),
            shrink=0.5,
            pad=0.01,
            label=f"rule '{result.rule}' score (lower is better)",
        )
    if responses:
        _responses(axes[1, 2], result)
    else:
        axes[1, 2].axis("off")
    m = result.model
    law = "no" if m.friction.name == "none" else f"'{m.friction.name}'"
    fig.suptitle(
        f"Random search, {m.name} model ({law} friction, {m.velocity} velocity, dt {m.dt * 1e3:g} "
        f"ms): {result.n_feasible} of {result.n_samples} feasible (seed {result.seed}); "
        f"chosen by {result.rule}: {RULES[result.rule].split(',')[0]}",
        fontsize="medium",
    )
    return save_figure(fig, path, dpi=100)
