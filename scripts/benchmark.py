"""Run the benchmark: the same function as ``frictiongym benchmark`` (see ``--help``).

python scripts/benchmark.py --out benchmark-results
"""

from __future__ import annotations

from frictiongym.cli import tool_main

if __name__ == "__main__":
    raise SystemExit(tool_main("benchmark"))
