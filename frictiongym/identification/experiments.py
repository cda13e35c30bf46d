"""Identification experiments run through the env interface, so they run unchanged on a device.

An experiment is a command profile held from rest (``env.reset``): a constant level, a slow
ramp, a velocity step between two levels, a relay that drives back and forth across a band
of the output (closed loop on the measured output, so it stays where the sensor resolves
it), or a reversal test that reverses a constant command after each steady slide (for a play
between motor and load). Each returns a :class:`~frictiongym.controllers.Rollout` of what a
controller would see: the time, the command sent, the measured output (the observation the
env's :class:`~frictiongym.controllers.LoopSpec` points at; ``plant_output()`` turns it into
the plant's own direction, in which a positive command moves the output positively) and
whether the sensor resolved it; its ``settings`` hold the experiment's
``kind``, ``sign`` and levels. Nothing here reads the simulator's true state (``info``), so a
hardware backend with the same observations gives the same analysis.

A run ends early when the measured output leaves the plan's usable span (the Altino's IR
sensor sees only the last 21 cm before the wall) or when the env terminates; the command
sent after that is zero.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from frictiongym.controllers.base import LoopSpec
from frictiongym.controllers.rollout import Rollout, observation_bounds

FloatArray = npt.NDArray[np.float64]
Kind = Literal["constant", "ramp", "step", "relay", "reversal"]

#: Samples at the start of a ramp taken as the rest position (the ramp starts below break-away).
REST_SAMPLES = 20
#: Consecutive samples beyond the span that end a run (a single one may be sensor noise).
_OUTSIDE_SAMPLES = 2


@dataclass(frozen=True)
class Span:
    """Usable range of the measured output (env units) and where a run starts in it.

    The Altino's IR sensor reads only the last 21.47 cm before the wall, so a run toward the
    wall starts near the far end and one away from it near the wall.
    """

    low: float
    high: float
    margin: float  #: distance kept from either end before the run is stopped

    def start(self, moving_up: bool) -> float:
        """Start position (env units) of a run whose output increases when ``moving_up``."""
        return self.low + self.margin if moving_up else self.high - self.margin


class Runner:
    """Runs command profiles on one env and records each as a :class:`Rollout`.

    Parameters
    ----------
    env : gymnasium.Env
        A frictiongym env (simulated or on a device backend), single, not vectorised.
    span : Span, optional
        Usable range of the output; runs start inside it and stop at its ends.
    seed : int, optional
        Seed of the first reset (noise draws in simulation); later resets continue the stream.
    """

    def __init__(self, env: Any, span: Span | None = None, seed: int | None = None) -> None:
        self.env = env
        self.spec = LoopSpec.from_env(env)
        self.span = span
        self._seed = seed
        self._bounds = observation_bounds(env, self.spec.position)
        self.steps = 0  #: env steps taken so far

    def _measure(self, observation: npt.ArrayLike) -> tuple[float, bool]:
        y = float(np.asarray(observation, dtype=np.float64).reshape(-1)[self.spec.position])
        low, high = self._bounds
        return self.spec.direction * y, bool(low < y < high)

    def _outside(self, y_env: float) -> bool:
        span = self.span
        return span is not None and not (span.low < y_env < span.high)

    def run(
        self,
        profile: Callable[[FloatArray], FloatArray],
        duration: float,
        kind: Kind,
        sign: float,
        settings: dict[str, float] | None = None,
        stop: Callable[[FloatArray, int], bool] | None = None,
        start_at: float | None = None,
        feedback: Callable[[FloatArray, int], float] | None = None,
    ) -> Rollout:
        """Reset the env at rest, apply ``profile(t)`` for ``duration`` s and record it.

        Parameters
        ----------
        profile : callable
            Command as a function of the sample times (vectorised), before saturation.
        duration : float
            Longest run, s.
        kind, sign, settings
            Stored in the record's ``settings`` (``kind`` and ``sign`` first).
        stop : callable, optional
            ``stop(positions_so_far, k)`` ends the run early when true (after sample ``k``).
        start_at : float, optional
            Start position, env units (default: the span's start for this direction).
        feedback : callable, optional
            ``feedback(positions_so_far, k)`` gives the command of sample ``k`` from the
            measured output (a closed-loop experiment); it replaces ``profile``'s value.
        """
        n = max(1, round(duration / self.spec.dt))
        t = np.arange(n, dtype=np.float64) * self.spec.dt
        limit = self.spec.limit
        command = np.clip(profile(t), -limit, limit)
        if not np.all(np.isfinite(command)):
            raise ValueError(f"the {kind} profile produced non-finite commands")
        options: dict[str, float] = {}
        if start_at is not None:
            options["position"] = float(start_at)
        elif self.span is not None:
            options["position"] = self.span.start(sign * self.spec.direction > 0)
        obs, _ = self.env.reset(seed=self._seed, options=options or None)
        self._seed = None
        position = np.empty(n)
        valid = np.empty(n, dtype=bool)
        action = np.zeros(1, dtype=np.float32)
        count, ended = n, False
        outside = 0  # consecutive samples beyond the span (one may be noise)
        for k in range(n):
            position[k], valid[k] = self._measure(obs)  # in the plant's direction
            outside = outside + 1 if self._outside(self.spec.direction * position[k]) else 0
            if k > 0 and (outside >= _OUTSIDE_SAMPLES or (stop and stop(position[: k + 1], k))):
                count = k + 1
                break
            if feedback is not None:
                command[k] = np.clip(feedback(position[: k + 1], k), -limit, limit)
            action[0] = command[k]
            obs, _, terminated, truncated, _ = self.env.step(action)
            self.steps += 1
            if terminated or truncated:
                count, ended = k + 1, bool(terminated)
                break
        self.env.step(np.zeros(1, dtype=np.float32))  # leave the motor off between runs
        self.steps += 1
        return Rollout.of_one_run(
            t[:count],
            terminated=ended,
            direction=self.spec.direction,
            settings={"kind": kind, "sign": float(sign), **(settings or {})},
            command=command[:count],
            measured=self.spec.direction * position[:count],  # back to env units, exactly
            valid=valid[:count],
        )

    def constant(self, level: float, duration: float) -> Rollout:
        """Hold ``level`` (signed, command units) from rest."""
        return self.run(
            lambda t: np.full(t.shape, level),
            duration,
            "constant",
            float(np.sign(level)),
            {"level": float(level)},
        )

    def ramp(
        self,
        sign: float,
        start: float,
        rate: float,
        duration: float,
        factor: float = 15.0,
        start_at: float | None = None,
    ) -> Rollout:
        """Ramp ``sign * (start + rate t)`` from rest until the output moved ``factor`` scatters.

        ``start`` must lie below the break-away level, so the first samples are at rest: their
        scatter (noise, or one quantisation step once the body moves) sets the threshold.
        ``start_at`` (env units) overrides the span's start.
        """

        def stop(y: FloatArray, k: int) -> bool:
            if k < REST_SAMPLES:
                return False
            rest = y[:REST_SAMPLES]
            scatter = rest_scatter(rest, y)
            return bool(abs(y[-1] - rest.mean()) > factor * scatter > 0.0)

        return self.run(
            lambda t: sign * (start + rate * t),
            duration,
            "ramp",
            sign,
            {"start": float(start), "rate": float(rate)},
            stop,
            start_at,
        )

    def relay(
        self,
        level_up: float,
        level_down: float,
        band: tuple[float, float],
        duration: float,
        start_at: float | None = None,
        lead: float = 3.0,
    ) -> Rollout:
        """Drive back and forth across ``band`` (env units) for ``duration`` s, from rest.

        The command is ``+level_up`` (plant direction: the output grows) until the measured
        output passes the band's upper end in that direction, then ``-level_down`` until it
        passes the lower end, and so on. Both levels are magnitudes above break-away. The
        output is extrapolated ``lead`` periods ahead from its last two samples, so a fast
        body reverses early enough to stop near the band's end despite the dead time and its
        deceleration. The run starts at ``start_at`` (default: the band's middle), moving up.
        """
        ends = sorted(self.spec.direction * b for b in band)
        state = {"command": abs(level_up)}

        def feedback(y: FloatArray, k: int) -> float:
            ahead = y[-1] + lead * (y[-1] - y[-2]) if k > 0 else y[-1]
            if ahead > ends[1]:
                state["command"] = -abs(level_down)
            elif ahead < ends[0]:
                state["command"] = abs(level_up)
            return state["command"]

        return self.run(
            lambda t: np.zeros(t.shape),
            duration,
            "relay",
            1.0,
            {
                "level_up": float(level_up),
                "level_down": float(level_down),
                "low": float(min(band)),
                "high": float(max(band)),
                "lead": float(lead),
            },
            start_at=0.5 * (band[0] + band[1]) if start_at is None else start_at,
            feedback=feedback,
        )

    def reversals(
        self,
        level_up: float,
        level_down: float,
        hold: float,
        count: int,
        band: tuple[float, float] | None = None,
        start_at: float | None = None,
        lead: float = 3.0,
    ) -> Rollout:
        """Alternate ``+level_up`` and ``-level_down`` from rest, reversing ``count`` times.

        The reversal test of a play (:mod:`~frictiongym.identification.backlash`): each leg
        holds its constant (plant direction; both levels are magnitudes above break-away) for
        ``hold`` s, long enough to reach steady sliding, then the command reverses. With
        ``band`` (env units) a leg also reverses as soon as the measured output, extrapolated
        ``lead`` periods ahead, passes the band's end it moves toward (as :meth:`relay`), so a
        sensor of short range keeps reading. The run starts at ``start_at`` (default: the
        band's end the first leg moves away from, else the span's start), moving up, and ends
        after the leg that follows the last reversal.
        """
        if count < 1 or hold <= 0.0:
            raise ValueError(
                f"a reversal test needs count >= 1 reversals and a hold > 0 s, got count={count!r}"
                f", hold={hold!r}"
            )
        ends = None if band is None else sorted(self.spec.direction * b for b in band)
        hold_samples = max(1, round(hold / self.spec.dt))
        state = {"sign": 1.0, "since": 0, "legs": 1}

        def feedback(y: FloatArray, k: int) -> float:
            ahead = y[-1] + lead * (y[-1] - y[-2]) if k > 0 else y[-1]
            passed = ends is not None and (
                ahead > ends[1] if state["sign"] > 0 else ahead < ends[0]
            )
            if k - state["since"] >= hold_samples or passed:
                state.update(legs=state["legs"] + 1)  # the leg after the last one ends the run
                if state["legs"] <= count + 1:
                    state.update(sign=-state["sign"], since=k)
            return state["sign"] * (abs(level_up) if state["sign"] > 0 else abs(level_down))

        def stop(y: FloatArray, k: int) -> bool:
            return state["legs"] > count + 1

        if start_at is None and band is not None:
            start_at = self.spec.direction * ends[0]  # type: ignore[index]  # band is set
        return self.run(
            lambda t: np.zeros(t.shape),
            (count + 1) * hold + self.spec.dt,
            "reversal",
            1.0,
            {
                "level_up": float(level_up),
                "level_down": float(level_down),
                "hold": float(hold),
                "count": float(count),
                **({} if band is None else {"low": float(min(band)), "high": float(max(band))}),
            },
            stop=stop,
            start_at=start_at,
            feedback=feedback,
        )

    def step(self, first: float, second: float, step_time: float, duration: float) -> Rollout:
        """Hold ``first`` until ``step_time``, then ``second`` (signed levels, same sign)."""
        return self.run(
            lambda t: np.where(t < step_time, first, second),
            duration,
            "step",
            float(np.sign(second)),
            {"first": float(first), "second": float(second), "step_time": float(step_time)},
        )


def rest_scatter(rest: FloatArray, whole: FloatArray) -> float:
    """Measurement scatter: the noise std at ``rest``, at least one quantisation step.

    The step is the smallest non-zero change anywhere in ``whole`` (a body at rest under a
    noiseless quantised sensor shows none; it shows up once the body moves).
    """
    steps = np.abs(np.diff(whole))
    steps = steps[steps > 0.0]
    return max(float(np.std(rest)), float(steps.min()) if steps.size else 0.0)
