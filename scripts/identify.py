"""Identify a device's friction and linear part: ``frictiongym identify`` as a script."""

import sys

from frictiongym.identification.command import main

if __name__ == "__main__":
    sys.exit(main())
