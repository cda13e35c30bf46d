"""Plot the friction laws of both presets, in the spirit of the paper's Figs. 8(b) and 10(b).

Each panel shows the steady sliding friction ``F(v)`` of every named law for one plant, the
static band at rest (the vertical segment at ``v = 0``: any input inside it holds the body)
and, for the Altino, the viscous part alone.

    python scripts/plot_friction.py --out docs/figures/friction_laws.png
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np

from frictiongym.friction import (
    ALTINO_LUGRE,
    ALTINO_PAPER,
    FRICTION_NAMES,
    ROTARY_LUGRE,
    ROTARY_PAPER,
    FrictionModel,
    friction_from_name,
)


def _panel(ax, title: str, laws: dict[str, FrictionModel], v_max: float, units: str) -> None:  # type: ignore[no-untyped-def]
    v = np.concatenate([np.linspace(-v_max, -1e-9, 600), np.linspace(1e-9, v_max, 600)])
    for name, law in laws.items():
        ax.plot(v, law.force(v), label=name, lw=1.6 if name == "paper" else 1.1)
    us_pos, us_neg = laws["paper"].breakaway
    ax.plot([0.0, 0.0], [-us_neg, us_pos], color="k", lw=3, solid_capstyle="butt",
            label="at rest: holds inside")  # fmt: skip
    viscous = getattr(laws["paper"], "viscous", 0.0)
    if viscous:
        ax.plot(v, viscous * v, color="grey", ls="-.", lw=0.9, label="viscous part")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set(title=title, xlabel=f"velocity [{units[1]}]", ylabel=f"friction [{units[0]}]")
    ax.legend(fontsize="small", loc="upper left")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="friction_laws.png", help="PNG to write")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    rotary = {n: friction_from_name(n, ROTARY_PAPER, ROTARY_LUGRE) for n in FRICTION_NAMES}
    altino = {n: friction_from_name(n, ALTINO_PAPER, ALTINO_LUGRE) for n in FRICTION_NAMES}
    _panel(axes[0], "QUBE-Servo 2 (B_e's viscous part is in the plant)", rotary, 6.0,
           ("V", "rad/s"))  # fmt: skip
    _panel(axes[1], "Altino", altino, 30.0, ("units", "cm/s"))
    fig.tight_layout()
    fig.savefig(args.out, dpi=120)
    print(f"figure written to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
