"""Compiled kernels for the per-frame hot paths (numba).

A frame's fusion handles ~20 boxes and ~20 twin vehicles: arrays so small that numpy's
cost is its per-call overhead (~1-3 us per operation, hundreds of operations per frame),
not the arithmetic. The few loops that run every frame are therefore compiled with numba,
written as plain loops over the same formulas as their numpy originals, so the numbers are
the same: no ``fastmath`` (no reassociation or fused multiply-add), numpy's error model
(division by zero gives inf/NaN, as in numpy), and every random draw and every reduction
whose rounding numpy defines (sums, medians) stays in numpy.

Compiled code is cached on disk beside the module (``__pycache__``), so only the very first
use on a machine pays the compilation (a few seconds). ``NUMBA_DISABLE_JIT=1`` runs the
same functions as plain Python, for debugging.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from numba import njit

F = TypeVar("F", bound=Callable)


def kernel(fn: F) -> F:
    """Compile ``fn`` with the project's settings (cached, numpy error model, no fastmath)."""
    return njit(cache=True, nogil=True, error_model="numpy")(fn)  # type: ignore[return-value]


@kernel
def fmax(a: float, b: float) -> float:
    """``np.maximum`` of two floats in a kernel (a NaN wins, as in numpy)."""
    return a if (a >= b or a != a) else b


@kernel
def fmin(a: float, b: float) -> float:
    """``np.minimum`` of two floats in a kernel (a NaN wins, as in numpy)."""
    return a if (a <= b or a != a) else b
