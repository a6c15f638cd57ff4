"""Residual terms that involve one image's platform parameters only (no ground-point block).

Each term family (weighted platform states, straight-line observations, ...) provides objects
with this interface; Ceres residual blocks (:mod:`solver.backend`) and the covariance
(:mod:`solver.linalg`) both consume them, so a new family is one module plus one line in
:func:`image_terms`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from solver.problem import Problem


class ImageTerm(Protocol):
    """Whitened residuals r(p) of one image's free parameters p, with dr/dp."""

    image_index: int
    n_residuals: int

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(residuals (m,), jacobian (m, nfree)) at ``params``."""
        ...


def image_terms(problem: Problem) -> list[ImageTerm]:
    """Every image-only term of the problem, in a fixed order."""
    from solver.priors import all_state_priors

    terms: list[ImageTerm] = []
    terms += all_state_priors(problem)
    return terms
