"""Random-search PID tuning: the same function as ``frictiongym tune`` (see ``--help``).

python scripts/tune.py --samples 100000 --seed 0 --out tune-results
"""

from __future__ import annotations

from frictiongym.cli import tool_main

if __name__ == "__main__":
    raise SystemExit(tool_main("tune"))
