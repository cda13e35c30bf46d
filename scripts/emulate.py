"""Run a device emulator on a pty or a TCP port: ``frictiongym emulate`` as a script."""

import sys

from frictiongym.hardware.command import main

if __name__ == "__main__":
    sys.exit(main())
