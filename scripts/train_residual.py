"""Train a residual policy on top of the compensated PID: ``frictiongym train`` as a script."""

import sys

from frictiongym.cli import tool_main

if __name__ == "__main__":
    sys.exit(tool_main("train"))
