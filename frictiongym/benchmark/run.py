"""Run benchmark scenarios and turn each run into a record."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import frictiongym  # noqa: F401  (registers the env ids)
from frictiongym import envs
from frictiongym.benchmark.scenarios import Scenario
from frictiongym.controllers import Controller, Rollout, rollout
from frictiongym.metrics import ResponseMetrics

#: Metric names of a record, in the order of the tables (``ResponseMetrics`` fields).
METRICS = tuple(ResponseMetrics.__dataclass_fields__)


@dataclass(frozen=True)
class Result:
    """One run: its scenario, seed, metrics, and the rollout it came from (column ``env``)."""

    scenario: Scenario
    seed: int
    metrics: ResponseMetrics
    rollout: Rollout
    env: int

    @property
    def terminated(self) -> bool:
        """Whether the episode ended early (the Altino touching the wall)."""
        return bool(self.rollout.terminated[self.env])

    def record(self) -> dict[str, Any]:
        """Return the run as a JSON-ready dict (non-finite numbers become None; see the docs).

        A residual run also carries ``residual``: the model's path (its base controller is
        in ``gains`` and ``compensator``).
        """
        s = self.scenario
        extra = {} if s.residual is None else {"residual": {"model": s.residual}}
        return {
            "scenario": s.name,
            "group": s.group,
            "env_id": s.env_id,
            "env_kwargs": dict(s.env_kwargs),
            "controller": s.controller_name,
            "gains": {"kp": s.gains.kp, "ki": s.gains.ki, "kd": s.gains.kd},
            "compensator": None if s.mode is None else s.compensator_record(),
            "seed": self.seed,
            "terminated": self.terminated,
            "metrics": {k: _finite(v) for k, v in self.metrics.as_dict().items()},
            **extra,
        }


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def run_scenario(
    scenario: Scenario, controller: Callable[[Any], Controller] | None = None
) -> list[Result]:
    """Run every seed of ``scenario`` side by side in one vector env.

    ``controller`` builds the controller for the vector env instead of
    ``scenario.controller`` (e.g. a residual policy still in training).
    """
    env = envs.make_vec(
        scenario.env_id,
        num_envs=len(scenario.seeds),
        max_episode_steps=scenario.steps,
        **scenario.env_kwargs,
    )
    try:
        build = controller or scenario.controller
        run = rollout(env, build(env), scenario.steps, seed=list(scenario.seeds))
    finally:
        env.close()
    return [
        Result(scenario, seed, _metrics(run, i), run, i) for i, seed in enumerate(scenario.seeds)
    ]


def _metrics(run: Rollout, env: int) -> ResponseMetrics:
    """Return the run's metrics; NaN for a run too short to have any (it ended at once)."""
    if run.length[env] < 3:  # terminated within two steps: a device's own loop that diverges
        return ResponseMetrics(**{f.name: math.nan for f in dataclasses.fields(ResponseMetrics)})
    return run.metrics(env)


def run_benchmark(
    scenarios: Sequence[Scenario],
    progress: Callable[[Scenario], None] | None = None,
) -> list[Result]:
    """Run ``scenarios`` in order; ``progress`` is called after each one."""
    names = [s.name for s in scenarios]
    if len(set(names)) != len(names):
        raise ValueError("scenario names must be unique")
    results: list[Result] = []
    for scenario in scenarios:
        results.extend(run_scenario(scenario))
        if progress is not None:
            progress(scenario)
    return results
