"""Compare a controller on a device and in simulation: ``frictiongym sim2real`` as a script."""

import sys

from frictiongym.sim2real.command import main

if __name__ == "__main__":
    sys.exit(main())
