"""Train a residual policy on top of the compensated PID: ``frictiongym train`` as a script."""

import sys

from frictiongym.residual.command import main

if __name__ == "__main__":
    sys.exit(main())
