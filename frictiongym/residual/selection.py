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

from frictiongym.benchmark.report import residual_comparisons
from frictiongym.benchmark.run import run_scenario
from frictiongym.benchmark.scenarios import residual_scenarios
from frictiongym.controllers.residual import ResidualController
from frictiongym.controllers.residual_core import ResidualConfig, make_base

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

    The residual runs on the compensated PID with the paper's gains, the base
    ``frictiongym train`` trains on.

    Parameters
    ----------
    device : str
        The device, by any spelling :func:`frictiongym.devices.get` takes.
    randomize : dict
        Factor ranges of the randomised plants (``gym.make``'s ``randomize``): the training
        ranges.
    config : ResidualConfig
        The policy's observation config and bound.
    plants : int
        Randomised validation plants, seeds ``VALIDATION_SEED...``.
    """

    def __init__(
        self,
        device: str,
        randomize: dict[str, Any],
        config: ResidualConfig,
        plants: int = VALIDATION_PLANTS,
    ) -> None:
        scenarios = residual_scenarios(
            device, "(in training)", plants, randomize, first_seed=VALIDATION_SEED
        )
        self.config = config
        self.candidates = [s for s in scenarios if s.residual is not None]
        #: The compensated PID's runs, which do not depend on the policy: run once.
        self.reference = [r for s in scenarios if s.residual is None for r in run_scenario(s)]

    def __call__(self, model: Any) -> Score:
        """Score ``model`` (anything with SB3's ``predict``) on the base the training used."""

        def build(env: Any) -> ResidualController:
            return ResidualController(make_base(env), model, self.config)

        runs = [r for s in self.candidates for r in run_scenario(s, build)]
        ratios, terminated = {}, 0
        for c in residual_comparisons(self.reference + runs):
            name = "randomised" if c.plants == "heldout" else c.plants
            terminated += c.terminated[1]
            for metric, (base, residual) in zip(METRICS, (c.itae, c.sse), strict=True):
                ratios[f"{name}/{metric}"] = residual / max(base, 1e-12)
        return Score(ratios, terminated)
