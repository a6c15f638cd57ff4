"""Central differences: the independent evidence of the Jacobian tests.

``(f(x + h e_j) - f(x - h e_j)) / (2 h)`` has a truncation error of order h^2 f''' and a rounding
error of order eps |f| / h; each test chooses its steps (and says why) and its tolerance. The
value of ``f`` may be a scalar, a vector or an array: the derivative has its shape, and a
Jacobian puts the parameter last (a vector f gives rows x parameters).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np


def central_difference(fun: Callable[[np.ndarray], Any], x: np.ndarray, j: int, h: float) -> np.ndarray:
    """d fun / d x_j at ``x`` with step ``h`` (``x`` itself is not changed)."""
    xp = np.array(x, dtype=float, copy=True)
    xm = xp.copy()
    xp[j] += h
    xm[j] -= h
    return (np.asarray(fun(xp), dtype=float) - np.asarray(fun(xm), dtype=float)) / (2 * h)


def central_jacobian(fun: Callable[[np.ndarray], Any], x: np.ndarray, steps: float | Sequence[float] | np.ndarray) -> np.ndarray:
    """The Jacobian of ``fun`` at ``x``: one central difference per parameter (``steps``: one step
    for all, or one per parameter), the parameter as the last axis."""
    hs = np.broadcast_to(np.asarray(steps, dtype=float), np.shape(x))
    return np.moveaxis(np.array([central_difference(fun, x, j, float(h)) for j, h in enumerate(hs)]), 0, -1)


def central_difference_in_place(evaluate: Callable[[], Any], x: np.ndarray, j: int, h: float) -> np.ndarray:
    """The same for a function of no argument that reads ``x`` where it lives (a parameter block
    of the adjustment state): ``x[j]`` is moved by +-h in place and restored, even on error."""
    x0 = x[j]
    try:
        x[j] = x0 + h
        fp = np.array(evaluate(), dtype=float, copy=True)
        x[j] = x0 - h
        fm = np.array(evaluate(), dtype=float, copy=True)
    finally:
        x[j] = x0
    return (fp - fm) / (2 * h)
