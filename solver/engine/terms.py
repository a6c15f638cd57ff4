"""Residual terms that involve one image's platform parameters only (no ground-point block).

Each term family (weighted platform states, straight-line observations, ...) provides objects
with this interface; Ceres residual blocks (:mod:`solver.engine.backend`) and the covariance
(:mod:`solver.engine.linalg`) both consume them, so a new family is one module plus one line in
:func:`image_terms`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from solver.state import Problem


class ImageTerm(Protocol):
    """Whitened residuals r(p) of one image's free parameters p, with dr/dp."""

    image_index: int
    n_residuals: int

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(residuals (m,), jacobian (m, nfree)) at ``params``."""
        ...


def image_terms(problem: Problem) -> list[ImageTerm]:
    """Every image-only term of the problem, in a fixed order."""
    from solver.observations.attitude import attitude_terms
    from solver.observations.lines import line_terms
    from solver.observations.state_priors import all_state_priors

    terms: list[ImageTerm] = []
    terms += all_state_priors(problem)
    terms += attitude_terms(problem)
    terms += line_terms(problem)
    return terms


def refresh_image_terms(problem: Problem) -> float:
    """Let term families that linearise around the solution (the pushbroom correction of the
    equivalent planes line model) recompute that state at the current parameters.

    Returns the largest change this makes to any whitened residual (0: nothing to redo).
    """
    from solver.observations.lines import refresh_lines

    return refresh_lines(problem)


def solve_with_refreshes(problem: Problem, options, control, solve):
    """``solve(problem, options, control)``, repeated while :func:`refresh_image_terms` changes
    some residual by more than ``solver.observations.lines.REFRESH_TOL`` (at most ``MAX_REFRESHES`` times).

    The outcomes are merged: iterations, times and cost history add up, the initial cost is the
    first solve's, the rest is the last solve's.
    """
    import dataclasses

    from solver.observations.lines import MAX_REFRESHES, REFRESH_TOL

    outcome = solve(problem, options, control)
    for _ in range(MAX_REFRESHES):
        if outcome.cancelled or not outcome.usable or refresh_image_terms(problem) <= REFRESH_TOL:
            break
        # a new objective: the statistical convergence test starts again
        control.statistically_converged = False
        if hasattr(control, "_small_steps"):
            control._small_steps = 0
        nxt = solve(problem, options, control)
        timing = {k: outcome.timing_s.get(k, 0.0) + v for k, v in nxt.timing_s.items()}
        outcome = dataclasses.replace(
            nxt,
            iterations=outcome.iterations + nxt.iterations,
            successful_steps=outcome.successful_steps + nxt.successful_steps,
            initial_cost=outcome.initial_cost,
            time_s=outcome.time_s + nxt.time_s,
            timing_s=timing,
        )
    return outcome
