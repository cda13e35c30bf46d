"""Choose the checkpoint of a residual training run on validation plants.

A policy's training return is a poor guide to the benchmark: it is earned on random set-point
steps, with exploration noise, on plants drawn anew at every episode. :class:`Validation` runs
the deterministic policy the way the benchmark does (the paper's step, the nominal plant and
randomised plants, side by side with the compensated PID), on its own seeds, and scores it by
its worst ratio to the compensated PID. ``frictiongym train`` keeps the best-scoring policy
as ``best.zip``; the benchmark's held-out plants (seeds 1000 and up) are never used here.

No torch here; the policy comes in as an object with SB3's ``predict``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from frictiongym.residual.core import ResidualConfig, make_base

#: First seed of the validation plants: below the benchmark's held-out seeds (1000 and up,
#: ``frictiongym.benchmark.scenarios.HELDOUT_SEED``), so choosing on them leaves those unseen.
VALIDATION_SEED = 500
#: Validation plants per device, besides the nominal one.
VALIDATION_PLANTS = 20
#: The metrics compared, in ``ResponseMetrics`` names: ITAE and the steady-state error.
METRICS = ("itae", "steady_state_error")


@dataclass(frozen=True)
class Score:
    """A policy's validation result.

    ``ratios`` maps ``"<plants>/<metric>"`` (plants ``nominal`` or ``randomised``) to the mean
    of the residual's metric over those plants divided by the compensated PID's; ``score`` is
    the largest ratio (below 1: better than the compensated PID on every metric and plant
    set), infinite if a run hit a safety limit.
    """

    ratios: dict[str, float]
    terminated: int

    @property
    def score(self) -> float:
        """The worst ratio, or infinity after a termination."""
        return math.inf if self.terminated else max(self.ratios.values())


class Validation:
    """Run a residual policy on validation plants and score it against the compensated PID.

    Parameters
    ----------
    device : str
        ``"RotaryServo"`` or ``"AltinoDistance"``.
    randomize : dict
        Factor ranges of the randomised plants (``gym.make``'s ``randomize``): the training
        ranges.
    config : ResidualConfig
        The policy's observation config and bound.
    plants : int
        Randomised validation plants, seeds ``VALIDATION_SEED...``.
    base_kind : str
        The base controller (:func:`~frictiongym.residual.core.make_base`).
    """

    def __init__(
        self,
        device: str,
        randomize: dict[str, Any],
        config: ResidualConfig,
        plants: int = VALIDATION_PLANTS,
        base_kind: str = "compensated",
    ) -> None:
        from frictiongym.benchmark.scenarios import residual_scenarios

        key = {"RotaryServo": "rotary", "AltinoDistance": "altino"}[device]
        scenarios = residual_scenarios(
            key, "(in training)", plants, randomize, first_seed=VALIDATION_SEED
        )
        self.config = config
        self.base_kind = base_kind
        #: (plant set, compensated-PID scenario, residual scenario)
        self.pairs = [
            (pair[0].name.split("-")[2].replace("heldout", "randomised"), pair[0], pair[1])
            for pair in zip(scenarios[::2], scenarios[1::2], strict=True)
        ]
        self.reference = {name: self._means(base) for name, base, _ in self.pairs}

    def _means(self, scenario: Any, model: Any = None) -> tuple[dict[str, float], int]:
        from frictiongym.benchmark.run import run_scenario
        from frictiongym.controllers.residual import ResidualController

        def build(env: Any) -> Any:
            return ResidualController(make_base(env, self.base_kind), model, self.config)

        results = run_scenario(scenario, build if model is not None else None)
        means = {m: float(np.mean([getattr(r.metrics, m) for r in results])) for m in METRICS}
        return means, sum(r.terminated for r in results)

    def __call__(self, model: Any) -> Score:
        """Score ``model`` (anything with SB3's ``predict``)."""
        ratios, terminated = {}, 0
        for name, _, scenario in self.pairs:
            means, stopped = self._means(scenario, model)
            terminated += stopped
            base = self.reference[name][0]
            for metric in METRICS:
                ratios[f"{name}/{metric}"] = means[metric] / max(base[metric], 1e-12)
        return Score(ratios, terminated)
