"""Ufuncs of compiled scalar functions that also run under ``NUMBA_DISABLE_JIT=1``.

numba's ``vectorize`` compiles its function whatever ``NUMBA_DISABLE_JIT`` says, but in that
debugging mode the ``njit`` functions it calls are plain Python, which it cannot compile: with
an empty cache the first import failed. There the same Python function is wrapped by
``np.vectorize`` instead: slower, with the same arithmetic.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np
from numba import float64, vectorize


def float64_ufunc(arity: int) -> Callable[[Callable[..., float]], Any]:
    """Return a decorator: a cached numba ufunc of ``arity`` float64 arguments to one float64.

    With ``NUMBA_DISABLE_JIT=1`` the decorator returns ``np.vectorize`` of the function.
    """

    def make(function: Callable[..., float]) -> Any:
        if numba.config.DISABLE_JIT:  # type: ignore[attr-defined]
            return np.vectorize(function, otypes=[np.float64])
        return vectorize([float64(*[float64] * arity)], cache=True)(function)

    return make
