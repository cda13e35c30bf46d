"""Identify a device's friction and linear part: ``frictiongym identify`` as a script."""

import sys

from frictiongym.cli import tool_main

if __name__ == "__main__":
    sys.exit(tool_main("identify"))
