"""Reference generators: what the controller is asked to track.

Each generator is a frozen dataclass that packs itself into a row of floats at every reset
(:meth:`Reference.sample`, drawing from the env's generator when it is random). The env kernel
reads the row through :func:`reference_at`, the one place a reference is evaluated; call a
generator (``Step(1.0)(t)``) or :func:`evaluate` to see the values it produces.

Switching times are compared with a 1 ns tolerance, so a step at ``time = k * dt`` takes
effect at sample ``k`` despite the rounding of ``k * dt``.
"""

from __future__ import annotations

import math
import numbers
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from numba import njit

from frictiongym._validation import check_finite, check_positive, real_number

FloatArray = npt.NDArray[np.float64]

KIND_STEP = 0
KIND_SEQUENCE = 1
KIND_RAMP = 2
KIND_SINE = 3

#: Most levels a step sequence (or a random-steps draw) holds.
MAX_LEVELS = 16
# Row: [kind, p0, p1, p2, p3, level count, levels...]
_KIND, _P0, _COUNT, _LEVELS = 0, 1, 5, 6
REF_SIZE = _LEVELS + MAX_LEVELS
_EPS_TIME = 1e-9


@njit(cache=True, inline="always")
def sequence_slot(t: float, period: float, count: float) -> int:
    """Index of the level a step sequence of ``count`` levels holds at time ``t``."""
    return min(math.floor(t / period + _EPS_TIME), int(count) - 1)


@njit(cache=True, inline="always")
def piecewise_value(t: float, kind: float, p0: float, p1: float, p2: float, level: float) -> float:
    """Value of a step, ramp or step-sequence reference (``level``: the sequence's level now).

    Conditional expressions only, so that a loop over envs compiles to SIMD code.
    """
    step = p2 if t + _EPS_TIME >= p0 else p1  # p0 time, p1 initial, p2 value
    ramp = p1 + p2 * max(t - p0, 0.0)  # p0 start, p1 initial, p2 slope
    return step if kind == KIND_STEP else (level if kind == KIND_SEQUENCE else ramp)


@njit(cache=True, inline="always")
def is_sine(rows: npt.NDArray[np.float64], i: int, offset: int) -> bool:
    """Whether the reference packed in ``rows[offset:, i]`` is a sine."""
    return rows[offset + _KIND, i] == KIND_SINE


@njit(cache=True, inline="always")
def piecewise_at(t: float, rows: npt.NDArray[np.float64], i: int, offset: int) -> float:
    """:func:`reference_at` of a reference that is not a sine (no branch: SIMD code)."""
    kind = rows[offset + _KIND, i]
    p0 = rows[offset + _P0, i]
    # p0 is the period of a sequence
    slot = sequence_slot(t, p0, rows[offset + _COUNT, i]) if kind == KIND_SEQUENCE else 0
    level = rows[offset + _LEVELS + slot, i]
    return piecewise_value(t, kind, p0, rows[offset + _P0 + 1, i], rows[offset + _P0 + 2, i], level)


@njit(cache=True, inline="always")
def reference_at(t: float, rows: npt.NDArray[np.float64], i: int, offset: int) -> float:
    """Value at time ``t`` of the reference packed in ``rows[offset:offset + REF_SIZE, i]``."""
    if is_sine(rows, i, offset):  # p0 period, p1 amplitude, p2 offset, p3 phase
        p0, p1, p2 = rows[offset + _P0, i], rows[offset + _P0 + 1, i], rows[offset + _P0 + 2, i]
        return p2 + p1 * math.sin(2.0 * math.pi * t / p0 + rows[offset + _P0 + 3, i])
    return piecewise_at(t, rows, i, offset)


@njit(cache=True)
def _evaluate(row: npt.NDArray[np.float64], t: npt.NDArray[np.float64]) -> FloatArray:
    out = np.empty(t.shape[0])
    for j in range(t.shape[0]):
        out[j] = reference_at(t[j], row, 0, 0)
    return out


def evaluate(row: npt.ArrayLike, t: npt.ArrayLike) -> FloatArray:
    """Values of a packed reference row at the times ``t`` (s), with the env kernel's code."""
    r = np.ascontiguousarray(row, dtype=np.float64).reshape(REF_SIZE, 1)  # one column
    times = np.asarray(t, dtype=np.float64)
    return np.asarray(_evaluate(r, times.reshape(-1))).reshape(times.shape)


def _row(kind: int, *params: float, levels: tuple[float, ...] = ()) -> FloatArray:
    row = np.zeros(REF_SIZE)
    row[_KIND] = kind
    row[_P0 : _P0 + len(params)] = params
    row[_COUNT] = len(levels)
    row[_LEVELS : _LEVELS + len(levels)] = levels
    return row


class Reference(ABC):
    """A reference signal, packed into a row for the env kernel at each reset."""

    @abstractmethod
    def sample(self, rng: np.random.Generator | None = None) -> FloatArray:
        """Packed row for one episode (random generators draw from ``rng``)."""

    @property
    def random(self) -> bool:
        """Whether :meth:`sample` draws from the generator."""
        return False

    def __call__(self, t: npt.ArrayLike, rng: np.random.Generator | None = None) -> FloatArray:
        """Values at the times ``t`` (s) of one episode's reference."""
        return evaluate(self.sample(rng), t)


@dataclass(frozen=True)
class Step(Reference):
    """``initial`` until ``time``, then ``value`` (a constant ``value`` when ``time`` is 0).

    Parameters
    ----------
    value : float
        Level after the step (rad for the servo, cm from the wall for the Altino).
    time : float, default 0.0
        Time of the step, s.
    initial : float, default 0.0
        Level before the step.
    """

    value: float
    time: float = 0.0
    initial: float = 0.0

    def __post_init__(self) -> None:
        check_finite(self, "value", "time", "initial")

    def sample(self, rng: np.random.Generator | None = None) -> FloatArray:  # noqa: D102
        return _row(KIND_STEP, self.time, self.initial, self.value)


@dataclass(frozen=True)
class StepSequence(Reference):
    """``values[k]`` during ``[k * period, (k + 1) * period)``; the last value is then held.

    Parameters
    ----------
    values : tuple of float
        Levels, 1 to ``MAX_LEVELS`` (16) of them.
    period : float
        Time each level is held, s.
    """

    values: tuple[float, ...]
    period: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "values", tuple(float(v) for v in self.values))
        if not 1 <= len(self.values) <= MAX_LEVELS:
            raise ValueError(
                f"StepSequence.values holds {len(self.values)} levels; give 1 to {MAX_LEVELS}"
            )
        for k, v in enumerate(self.values):
            real_number(f"StepSequence.values[{k}]", v)
        check_positive(self, "period")

    def sample(self, rng: np.random.Generator | None = None) -> FloatArray:  # noqa: D102
        return _row(KIND_SEQUENCE, self.period, levels=self.values)


@dataclass(frozen=True)
class Ramp(Reference):
    """``initial`` until ``start``, then rising at ``slope`` per second.

    Parameters
    ----------
    slope : float
        Rate, units per second.
    start : float, default 0.0
        Time the ramp starts, s.
    initial : float, default 0.0
        Level before the ramp.
    """

    slope: float
    start: float = 0.0
    initial: float = 0.0

    def __post_init__(self) -> None:
        check_finite(self, "slope", "start", "initial")

    def sample(self, rng: np.random.Generator | None = None) -> FloatArray:  # noqa: D102
        return _row(KIND_RAMP, self.start, self.initial, self.slope)


@dataclass(frozen=True)
class Sine(Reference):
    """``offset + amplitude * sin(2 pi t / period + phase)``.

    Parameters
    ----------
    amplitude : float
        Amplitude.
    period : float
        Period, s (> 0).
    offset : float, default 0.0
        Mean level.
    phase : float, default 0.0
        Phase at t = 0, rad.
    """

    amplitude: float
    period: float
    offset: float = 0.0
    phase: float = 0.0

    def __post_init__(self) -> None:
        check_finite(self, "amplitude", "period", "offset", "phase")
        check_positive(self, "period")

    def sample(self, rng: np.random.Generator | None = None) -> FloatArray:  # noqa: D102
        return _row(KIND_SINE, self.period, self.amplitude, self.offset, self.phase)


@dataclass(frozen=True)
class RandomSteps(Reference):
    """A new level drawn uniformly from ``[low, high]`` every ``period`` seconds.

    The ``MAX_LEVELS`` (16) levels of an episode are drawn at its reset from the env's
    generator; after ``16 * period`` the last one is held.

    Parameters
    ----------
    low, high : float
        Range of the levels.
    period : float
        Time each level is held, s.
    """

    low: float
    high: float
    period: float

    def __post_init__(self) -> None:
        check_finite(self, "low", "high", "period")
        if self.low > self.high:
            raise ValueError(f"RandomSteps.low={self.low!r} exceeds high={self.high!r}")
        check_positive(self, "period")

    @property
    def random(self) -> bool:  # noqa: D102
        return True

    def sample(self, rng: np.random.Generator | None = None) -> FloatArray:  # noqa: D102
        if rng is None:
            raise ValueError("RandomSteps.sample needs a generator (rng=np.random.default_rng())")
        levels = rng.uniform(self.low, self.high, size=MAX_LEVELS)
        return _row(KIND_SEQUENCE, self.period, levels=tuple(levels.tolist()))


#: The generator class of each reference kind a device's presets name.
PRESET_CLASSES: dict[str, type[Reference]] = {
    "step": Step,
    "step_sequence": StepSequence,
    "ramp": Ramp,
    "sine": Sine,
    "random_steps": RandomSteps,
}


def resolve_reference(spec: object, presets: Mapping[str, Mapping[str, Any]]) -> Reference:
    """Turn a ``reference=`` argument into a :class:`Reference`.

    Parameters
    ----------
    spec : Reference, str or float
        A generator; a name of ``presets`` (``"step"``, ``"step_sequence"``, ``"ramp"``,
        ``"sine"``, ``"random_steps"``: the env's defaults for each kind); or a number, meaning
        a constant set-point (``Step(value)``).
    presets : mapping
        The env's default generator of each kind, as the keyword arguments of its class in
        :data:`PRESET_CLASSES` (:attr:`frictiongym.devices.Device.references`).
    """
    if isinstance(spec, Reference):
        return spec
    if isinstance(spec, str):
        if spec not in presets:
            raise ValueError(
                f"unknown reference {spec!r}; use one of {sorted(presets)}, a number (a constant "
                "set-point) or a generator from frictiongym.envs.references"
            )
        return PRESET_CLASSES[spec](**presets[spec])
    if isinstance(spec, numbers.Real) and not isinstance(spec, bool):
        return Step(float(spec))
    raise TypeError(
        f"reference must be a name, a number or a Reference, got {spec!r} "
        f"(e.g. 'step', 2.0 or frictiongym.envs.references.Sine(amplitude=1.0, period=2.0))"
    )
