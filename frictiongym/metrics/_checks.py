"""Input checks shared by the metrics: shapes, finiteness, increasing times."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from frictiongym._validation import real_number

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


def as_times(t: npt.ArrayLike, min_samples: int = 2) -> FloatArray:
    """Return ``t`` as a float array after checking it is 1-D, finite and strictly increasing."""
    try:
        arr = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"t must be an array of numbers (sample times in s): {exc}") from exc
    if arr.ndim != 1:
        raise ValueError(
            f"t must be a 1-D array of sample times, got shape {arr.shape}; "
            "pass a flat array (e.g. np.ravel(t))"
        )
    if arr.size < min_samples:
        raise ValueError(
            f"need at least {min_samples} samples, got {arr.size}; record a longer run"
        )
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"t must be finite, but t[{i}] = {float(arr[i])!r}; drop the non-finite samples first"
        )
    steps = np.diff(arr)
    back = np.flatnonzero(steps <= 0.0)
    if back.size:
        i = int(back[0])
        raise ValueError(
            f"t must be strictly increasing, but t[{i + 1}] = {float(arr[i + 1])!r} <= "
            f"t[{i}] = {float(arr[i])!r}; sort the samples by time and remove duplicate times"
        )
    return arr


def _check_length(name: str, arr: npt.NDArray[np.generic], t: FloatArray, what: str) -> None:
    if arr.ndim != 1 or arr.shape != t.shape:
        raise ValueError(
            f"t and {name} must be 1-D arrays of the same length: t has shape {t.shape}, "
            f"{name} has shape {arr.shape}; pass one {name} {what} per sample time"
        )


def as_samples(name: str, values: npt.ArrayLike, t: FloatArray) -> FloatArray:
    """Return ``values`` as a float array of one finite value per sample time."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an array of numbers: {exc}") from exc
    _check_length(name, arr, t, "value")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"{name} must be finite, but {name}[{i}] = {float(arr[i])!r} (at t = {float(t[i])!r}); "
            "drop or interpolate the non-finite samples first"
        )
    return arr


def as_flags(name: str, values: npt.ArrayLike, t: FloatArray) -> BoolArray:
    """Return ``values`` as a bool array of one flag per sample time (bool or 0/1 input)."""
    arr = np.asarray(values)
    _check_length(name, arr, t, "flag")
    if arr.dtype == np.bool_:
        return arr
    if not np.issubdtype(arr.dtype, np.number) or not np.all((arr == 0) | (arr == 1)):
        raise ValueError(
            f"{name} must hold booleans (or 0/1), got dtype {arr.dtype}; "
            f"pass e.g. np.asarray({name}, dtype=bool)"
        )
    return arr.astype(np.bool_)


def check_scalar(name: str, value: float) -> float:
    """Return ``value`` as a float after checking it is finite (NumPy 0-d arrays taken)."""
    return real_number(name, float(value))


def check_fraction(name: str, value: float) -> float:
    """Return ``value`` after checking ``0 < value <= 1``."""
    out = float(value)
    if not 0.0 < out <= 1.0:
        raise ValueError(f"{name} must be a fraction of the run in (0, 1], got {value!r}")
    return out


def trapezoid(t: FloatArray, f: FloatArray) -> float:
    """Trapezoidal integral of ``f`` over ``t``."""
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(t)))
