"""Plot the friction laws of both presets, in the spirit of the paper's Figs. 8(b) and 10(b).

Each panel shows the steady sliding friction ``F(v)`` of every named law for one plant, the
static band at rest (the vertical segment at ``v = 0``: any input inside it holds the body)
and, for the Altino, the viscous part alone. ``frictiongym benchmark`` draws the same figure.

    python scripts/plot_friction.py --out docs/figures/friction_laws.png
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from frictiongym.benchmark.figures import plot_friction_curves


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="friction_laws.png", help="PNG to write")
    args = parser.parse_args(argv)
    print(f"figure written to {plot_friction_curves(Path(args.out))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
