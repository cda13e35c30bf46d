"""Run a device emulator on a pty or a TCP port: ``frictiongym emulate`` as a script."""

import sys

from frictiongym.cli import tool_main

if __name__ == "__main__":
    sys.exit(tool_main("emulate"))
