"""``frictiongym sweep``: seeds x hyperparameter grids of ``frictiongym train`` on Ray Tune.

* :mod:`~frictiongym.sweep.grid`: the trials (``--seeds``, ``--grid``) and their settings.
* :mod:`~frictiongym.sweep.trial`: one trial in a Ray worker: train, then the held-out
  evaluation of its best policy.
* :mod:`~frictiongym.sweep.run`: the trials as Ray Tune trials, resumed with ``--resume``.
* :mod:`~frictiongym.sweep.report`: ``sweep.csv``, ``sweep.md`` and ``best/``.
* :mod:`~frictiongym.sweep.command`: the command line.

Ray is imported inside functions only: it is an optional extra (``frictiongym[cluster]``).
"""
