"""Sim-to-real evaluation: the same controller on a device and on simulated models of it.

:func:`run_sim2real` runs it; :func:`write_report` writes ``report.md``, ``sim2real.json``
and the figures; ``frictiongym sim2real`` does both from the command line.
"""

from frictiongym.sim2real.report import write_report
from frictiongym.sim2real.run import fit_percent, rmse, run_sim2real

__all__ = ["fit_percent", "rmse", "run_sim2real", "write_report"]
