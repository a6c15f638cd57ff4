"""The residual terms of the observation families (:mod:`solver.observations.registry`): each acts
on one parameter block (of a kind of :mod:`solver.blocks.registry`) and has the interface
:class:`solver.observations.family.Term`; Ceres residual blocks (:mod:`solver.engine.backend`)
and the linearisation (:mod:`solver.engine.linalg`) both walk :func:`family_terms`, in the
registry's order.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from solver.blocks import registry as blocks
from solver.observations import registry
from solver.observations.family import MAX_REFRESHES, REFRESH_TOL, Labelled
from solver.state import AdjustmentState


def family_terms(problem: AdjustmentState) -> list[Labelled]:
    """Every family's terms, families in the registry's order, each family's in its own order."""
    out: list[Labelled] = []
    for family in registry.FAMILIES:
        out += family.terms(problem)
    return out


def block_owner(problem: AdjustmentState, labelled: Labelled) -> Any:
    """The parameter block (``params``, ``nfree``) a term acts on (:func:`solver.blocks.registry.block_of`)."""
    return blocks.block_of(problem, labelled.block, labelled.index)


def refresh_family_terms(problem: AdjustmentState) -> float:
    """Let families that linearise around the solution (the pushbroom correction of the
    equivalent planes line model) recompute that state at the current parameters.

    Returns the largest change this makes to any whitened residual (0: nothing to redo).
    """
    return max([0.0, *(family.refresh(problem) for family in registry.FAMILIES)])


def solve_with_refreshes(problem: AdjustmentState, options, control, solve):
    """``solve(problem, options, control)``, repeated while :func:`refresh_family_terms` changes
    some residual by more than ``solver.observations.family.REFRESH_TOL`` (at most
    ``MAX_REFRESHES`` times).

    The outcomes are merged: iterations, times and cost history add up, the initial cost is the
    first solve's, the rest is the last solve's.
    """
    outcome = solve(problem, options, control)
    for _ in range(MAX_REFRESHES):
        if outcome.cancelled or not outcome.usable or refresh_family_terms(problem) <= REFRESH_TOL:
            break
        # a new objective: the statistical convergence test starts again
        control.restart()
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
