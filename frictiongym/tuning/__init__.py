"""Random-search PID tuning against time-domain specs (the paper's §3.1).

Contents
--------
:func:`random_search` → :class:`TuneResult`
    Draw gain triples, simulate them on the batched plant, keep the feasible, choose one.
:class:`StepSpecs`, :class:`GainBounds`
    The paper's requirements and bounds (the defaults).
:class:`TuningModel`, :func:`simulate` → :class:`Evaluation`
    The sampled-data loop the tuner simulates, and its batched, early-stopping simulation.
:mod:`frictiongym.tuning.reference`
    The same loop in python-control, to check and time the tuner against.
:mod:`frictiongym.tuning.command`
    ``frictiongym tune``.
"""

from frictiongym.tuning.evaluate import Evaluation, TuningModel, simulate
from frictiongym.tuning.search import (
    DEFAULT_HORIZON,
    RULES,
    TuneResult,
    random_search,
    rule_scores,
)
from frictiongym.tuning.specs import GainBounds, StepSpecs

__all__ = [
    "DEFAULT_HORIZON",
    "RULES",
    "Evaluation",
    "GainBounds",
    "StepSpecs",
    "TuneResult",
    "TuningModel",
    "random_search",
    "rule_scores",
    "simulate",
]
