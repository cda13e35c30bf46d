"""The benchmark: PID vs compensated PID on the paper's experiments and around them.

``frictiongym benchmark`` (and ``scripts/benchmark.py``) run
:func:`~frictiongym.benchmark.command.run`; the pieces are
:mod:`~frictiongym.benchmark.scenarios` (what runs), :mod:`~frictiongym.benchmark.run`
(running and records), :mod:`~frictiongym.benchmark.report` (JSON, CSV, markdown) and
:mod:`~frictiongym.benchmark.figures` (PNG).
"""
