"""Controllers behind one interface: ``reset()`` and ``controller(observation) -> action``.

* :class:`PID`: discrete PID, derivative on the measurement, anti-windup.
* :class:`FrictionCompensator`: any controller plus the modelled friction (the paper's).
* :class:`ControllerPolicy`: any controller as an SB3-style policy (``predict``).
* :class:`ResidualController`: a base controller plus a trained residual policy (SB3 lazily).
* :func:`rollout`: one episode of any controller on any env, single or vector.

Build a controller for an env with ``PID.for_env(env, gains)``: it reads the env's
:class:`LoopSpec` (observation layout, ``dt``, action limit, sign of the plant's gain).
"""

from frictiongym.controllers.base import Controller, LoopSpec
from frictiongym.controllers.compensation import MODES, FrictionCompensator
from frictiongym.controllers.pid import PID, PIDGains
from frictiongym.controllers.policy import ControllerPolicy
from frictiongym.controllers.residual import ResidualController
from frictiongym.controllers.rollout import Rollout, rollout

__all__ = [
    "MODES",
    "PID",
    "Controller",
    "ControllerPolicy",
    "FrictionCompensator",
    "LoopSpec",
    "PIDGains",
    "ResidualController",
    "Rollout",
    "rollout",
]
