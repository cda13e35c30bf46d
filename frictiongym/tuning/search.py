"""Random search for PID gains that meet the paper's step specs (§3.1).

:func:`random_search` draws ``samples`` gain triples uniformly from the bounds with
``np.random.default_rng(seed)``, simulates them in chunks on the batched plant
(:func:`~frictiongym.tuning.evaluate.simulate`), keeps those that meet all four specs and
chooses one of them by a stated rule (the paper does not say how it chose its gains among its
328 feasible candidates). The paper's own gains are evaluated in the same model alongside.

All samples are drawn before the first chunk runs, so the result does not depend on the chunk
size; the same seed, model and options give the same result. The chunks are independent, so
they may run anywhere (``map_chunks``: ``frictiongym tune --ray`` runs them as Ray tasks) with
the same result.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from frictiongym import __version__
from frictiongym.metrics.step import StepMetricsBatch
from frictiongym.tuning.evaluate import STOP_REASONS, Evaluation, TuningModel, simulate
from frictiongym.tuning.specs import SPEC_FIELDS, GainBounds, StepSpecs

FloatArray = npt.NDArray[np.float64]

#: Selection rules among the feasible candidates: name -> what is optimised.
RULES = {
    "itae": "smallest ITAE of the unit step, ∫ t |1 - y| dt over the horizon",
    "margin": "largest worst-case relative margin to the specs, min_i (1 - metric_i / limit_i)",
    "effort": "smallest peak |command| over the step (the gentlest feasible controller)",
}

#: Default number of samples: about a second of simulation on 2 cores (docs/tuning.md), and
#: enough to estimate a feasible fraction near 0.5 % to about ±0.02 percentage points.
DEFAULT_SAMPLES = 100_000

#: Default simulated time, s: twice the settling-time spec, so a response that leaves the
#: 2 % band late (a slow integral tail, a friction stick) is seen (assumed; docs/tuning.md).
DEFAULT_HORIZON = 3.0

#: Candidates simulated at once. Measured on 100 000 samples (2 cores): 45 MB peak memory and
#: 234 k candidates/s; 4 096 ran at 92 k/s, 65 536 at 261 k/s, all 100 000 at once at 240 k/s
#: with 118 MB (docs/tuning.md, "Speed").
DEFAULT_CHUNK = 32_768


def rule_scores(rule: str, evaluation: Evaluation, specs: StepSpecs) -> FloatArray:
    """Score of every candidate under ``rule`` (lower is better; NaN unless feasible)."""
    if rule == "itae":
        score = evaluation.itae
    elif rule == "margin":
        score = -specs.margin(evaluation.metrics)
    elif rule == "effort":
        score = evaluation.peak_command
    else:
        raise ValueError(f"unknown rule {rule!r}; choose one of {', '.join(RULES)}")
    return np.where(evaluation.feasible, score, math.nan)


def _concat(parts: list[Evaluation]) -> Evaluation:
    """One Evaluation from chunks of the same grid (traces dropped)."""

    def cat(name: str, of: Any = parts) -> Any:
        return np.concatenate([getattr(p, name) for p in of])

    metrics = StepMetricsBatch(
        **{
            name: cat(name, [p.metrics for p in parts])
            for name in StepMetricsBatch.__dataclass_fields__
        }
    )
    arrays = ("feasible", "complete", "stopped_at", "stop_reason", "peak_command", "iae", "itae")
    return Evaluation(
        t=parts[0].t, metrics=metrics, traces=None, **{name: cat(name) for name in arrays}
    )


@dataclass(frozen=True)
class TuneResult:
    """Outcome of :func:`random_search` (per-sample arrays in sample order)."""

    gains: FloatArray  #: (n_samples, 3) kp, ki, kd
    evaluation: Evaluation  #: of every sample (metrics NaN where stopped early)
    scores: FloatArray  #: the rule's score, NaN unless feasible
    chosen: int | None  #: index of the chosen sample; None without a feasible one
    paper: Evaluation  #: the paper's gains, simulated to the horizon
    rule: str
    model: TuningModel
    specs: StepSpecs
    bounds: GainBounds
    seed: int | None
    horizon: float
    early_stop: bool
    wall_time: float  #: s, sampling and simulation
    extra: dict[str, Any] = field(default_factory=dict)  #: added to the record (command line)

    @property
    def n_samples(self) -> int:
        """Number of candidates evaluated."""
        return int(self.gains.shape[0])

    @property
    def n_feasible(self) -> int:
        """Number of candidates that meet all four specs."""
        return int(self.evaluation.feasible.sum())

    @property
    def feasible_indices(self) -> npt.NDArray[np.intp]:
        """Sample indices of the feasible candidates."""
        return np.flatnonzero(self.evaluation.feasible)

    def candidate(self, index: int) -> dict[str, Any]:
        """One candidate's gains, metrics, ITAE/IAE, margin and peak command (JSON-ready)."""
        ev = self.evaluation
        kp, ki, kd = (float(g) for g in self.gains[index])
        margin = self.specs.margin(ev.metrics.take([index]))[0]
        return {
            "index": int(index),
            "kp": kp,
            "ki": ki,
            "kd": kd,
            **{k: _finite(v) for k, v in ev.metrics[index].as_dict().items()},
            "iae": _finite(ev.iae[index]),
            "itae": _finite(ev.itae[index]),
            "margin": _finite(margin),
            "peak_command": _finite(ev.peak_command[index]),
        }

    def paper_record(self) -> dict[str, Any]:
        """Return the paper's gains in this model: metrics, feasibility and the failing specs."""
        p = self.paper
        fails = self.specs.failures(p.metrics)
        return {
            **dict(zip(("kp", "ki", "kd"), self.model.baseline, strict=True)),
            "feasible": bool(p.feasible[0]),
            "failing_specs": [name for name, _, _ in SPEC_FIELDS if fails[name][0]],
            "metrics": {k: _finite(v) for k, v in p.metrics[0].as_dict().items()},
            "margin": _finite(self.specs.margin(p.metrics)[0]),
            "peak_command": _finite(p.peak_command[0]),
            "within_bounds": bool(self.bounds.contains(self.model.baseline)[0]),
        }

    def record(self) -> dict[str, Any]:
        """Return the content of ``tune.json``."""
        ev = self.evaluation
        stopped = {
            STOP_REASONS[code]: int(np.sum(ev.stop_reason == code))
            for code in sorted(STOP_REASONS)
            if code
        }
        fails = self.specs.failures(ev.metrics.take(ev.complete))
        return {
            "format": "frictiongym.tune/1",
            **self.extra,
            "software": {
                "frictiongym": __version__,
                "numpy": np.__version__,
                "numba": numba.__version__,
            },
            "n_samples": self.n_samples,
            "n_feasible": self.n_feasible,
            "feasible_fraction": self.n_feasible / self.n_samples,
            "seed": self.seed,
            "model": self.model.record(),
            "dt": self.model.dt,
            "horizon": float(ev.t[-1]),
            "reference_step": self.model.step,
            "specs": self.specs.record(),
            "bounds": self.bounds.record(),
            "rule": {"name": self.rule, "description": RULES[self.rule]},
            "chosen": None if self.chosen is None else self.candidate(self.chosen),
            "paper_gains": self.paper_record(),
            "early_stop": self.early_stop,
            "stopped_early": stopped,
            "complete": int(ev.complete.sum()),
            "failing_at_horizon": {k: int(v.sum()) for k, v in fails.items()},
            "wall_time_s": round(self.wall_time, 3),
            "feasible": [self.candidate(int(i)) for i in self.feasible_indices],
        }


def _finite(value: float) -> float | None:
    v = float(value)
    return v if math.isfinite(v) else None


def simulate_chunk(
    gains: FloatArray, model: TuningModel, specs: StepSpecs, horizon: float, early_stop: bool
) -> Evaluation:
    """Simulate one chunk of candidates (:func:`simulate`, with the arguments in a fixed order).

    What ``map_chunks`` of :func:`random_search` applies to each chunk.
    """
    return simulate(gains, model, specs, horizon, early_stop=early_stop)


#: ``map_chunks(simulate_chunk, chunks, model, specs, horizon, early_stop)``: yields
#: ``simulate_chunk(chunk, model, specs, horizon, early_stop)`` of each chunk, in order.
ChunkMap = Callable[..., Iterable[Evaluation]]


def _serial_map(
    function: Callable[..., Evaluation], chunks: Sequence[FloatArray], *shared: Any
) -> Iterable[Evaluation]:
    return (function(chunk, *shared) for chunk in chunks)


def random_search(
    samples: int,
    seed: int | None = 0,
    model: TuningModel | None = None,
    specs: StepSpecs | None = None,
    bounds: GainBounds | None = None,
    horizon: float = DEFAULT_HORIZON,
    rule: str = "itae",
    chunk: int = DEFAULT_CHUNK,
    early_stop: bool = True,
    progress: Callable[[int], None] | None = None,
    map_chunks: ChunkMap | None = None,
) -> TuneResult:
    """Run the paper's random search: sample, simulate, keep the feasible, choose by ``rule``.

    Parameters
    ----------
    samples : int
        Number of gain triples to draw (>= 1).
    seed : int or None, default 0
        Seed of ``np.random.default_rng``; None draws fresh entropy.
    model : TuningModel, optional
        Default: the nominal servo (``TuningModel()``).
    specs : StepSpecs, optional
        Default: the paper's four requirements.
    bounds : GainBounds, optional
        Default: the paper's bounds.
    horizon : float, default DEFAULT_HORIZON
        Simulated time per candidate, s (> ``specs.settling_time``).
    rule : {"itae", "margin", "effort"}, default "itae"
        How to choose among the feasible candidates (:data:`RULES`).
    chunk : int, default DEFAULT_CHUNK
        Candidates simulated at once (memory, not results).
    early_stop : bool, default True
        Drop provably failed candidates early (same feasible set, much faster).
    progress : callable, optional
        Called with the number of candidates of each finished chunk.
    map_chunks : callable, optional
        Runs the chunks (:data:`ChunkMap`); by default one after the other in this process.
        Any map gives the same result.

    Returns
    -------
    TuneResult
    """
    for name, value in (("samples", samples), ("chunk", chunk)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
            raise ValueError(f"{name} must be a whole number >= 1, got {value!r}")
    if rule not in RULES:
        raise ValueError(f"unknown rule {rule!r}; choose one of {', '.join(RULES)}")
    model = model or TuningModel()
    specs = specs or StepSpecs()
    bounds = bounds or GainBounds()
    start = time.perf_counter()
    gains = bounds.sample(np.random.default_rng(seed), int(samples))
    chunks = [gains[lo : lo + int(chunk)] for lo in range(0, int(samples), int(chunk))]
    parts = []
    run = map_chunks or _serial_map
    for part, evaluation in zip(
        chunks, run(simulate_chunk, chunks, model, specs, horizon, early_stop), strict=True
    ):
        parts.append(evaluation)
        if progress is not None:
            progress(part.shape[0])
    evaluation = _concat(parts)
    paper = simulate([model.baseline], model, specs, horizon, early_stop=False)
    wall = time.perf_counter() - start
    scores = rule_scores(rule, evaluation, specs)
    chosen = int(np.nanargmin(scores)) if evaluation.feasible.any() else None
    return TuneResult(
        gains=gains,
        evaluation=evaluation,
        scores=scores,
        chosen=chosen,
        paper=paper,
        rule=rule,
        model=model,
        specs=specs,
        bounds=bounds,
        seed=seed,
        horizon=horizon,
        early_stop=early_stop,
        wall_time=wall,
    )
