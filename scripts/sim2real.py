"""Compare a controller on a device and in simulation: ``frictiongym sim2real`` as a script."""

import sys

from frictiongym.cli import tool_main

if __name__ == "__main__":
    sys.exit(tool_main("sim2real"))
