"""Residual terms that involve one image's platform parameters only (no ground-point block).

Each term family (weighted platform states, measured attitude, straight-line observations, ...)
provides objects with the interface :class:`solver.observations.family.ImageTerm`; Ceres residual
blocks (:mod:`solver.engine.backend`) and the covariance (:mod:`solver.engine.linalg`) both
consume them. A family in the registry's shape is one module plus one line in
:mod:`solver.observations.registry`; state priors and lines are still named here.
"""

from __future__ import annotations

import dataclasses

from solver.observations.family import ImageTerm
from solver.observations.lines import MAX_REFRESHES, REFRESH_TOL, line_terms, refresh_lines
from solver.observations.registry import FAMILIES
from solver.observations.state_priors import all_state_priors
from solver.state import AdjustmentState


def image_terms(problem: AdjustmentState) -> list[ImageTerm]:
    """Every image-only term of the problem, in a fixed order."""
    terms: list[ImageTerm] = []
    terms += all_state_priors(problem)
    for family in FAMILIES:
        terms += family.terms(problem)
    terms += line_terms(problem)
    return terms


def refresh_image_terms(problem: AdjustmentState) -> float:
    """Let term families that linearise around the solution (the pushbroom correction of the
    equivalent planes line model) recompute that state at the current parameters.

    Returns the largest change this makes to any whitened residual (0: nothing to redo).
    """
    return max([refresh_lines(problem), *(family.refresh(problem) for family in FAMILIES)])


def solve_with_refreshes(problem: AdjustmentState, options, control, solve):
    """``solve(problem, options, control)``, repeated while :func:`refresh_image_terms` changes
    some residual by more than ``solver.observations.lines.REFRESH_TOL`` (at most ``MAX_REFRESHES`` times).

    The outcomes are merged: iterations, times and cost history add up, the initial cost is the
    first solve's, the rest is the last solve's.
    """
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
