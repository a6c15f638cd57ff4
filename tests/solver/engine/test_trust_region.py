"""The trust-region settings of large solves: non-monotonic steps from
``NONMONOTONIC_MIN_RESIDUAL_BLOCKS`` residual blocks on, and the statistical stop that must not
take a non-monotonic rise of the cost for convergence (measured effect on the iteration counts:
docs/benchmarks.md, bench/bench_scale.py)."""

from __future__ import annotations

import math

import solver.engine.backend as backend
from solver.engine.backend import SolveControl


def feed(control: SolveControl, costs: list[float]) -> None:
    for it, cost in enumerate(costs):
        control.iteration(it, cost, True)


def test_a_rise_above_the_best_cost_is_not_convergence() -> None:
    """With non-monotonic steps Ceres accepts a step that raises the cost (it keeps the best
    parameters): two tiny changes around a cost 10 above the best are no convergence (chi-square
    is 20 above its minimum, parameters far from it); tiny decreases below the best are."""
    control = SolveControl(None, None, 50)
    feed(control, [100.0, 50.0, 60.0, 59.9999, 59.9998])
    assert not control.statistically_converged
    for it, cost in enumerate([49.9999, 49.99985, 49.9998], start=5):
        control.iteration(it, cost, True)
    assert control.statistically_converged


def test_monotonic_small_decreases_still_converge() -> None:
    """The monotonic path is unchanged: two successive decreases of chi-square below the
    tolerance stop the solve; a rejected step (no cost accepted) does not count."""
    control = SolveControl(None, None, 50)
    feed(control, [100.0, 50.0, 49.9999])
    assert not control.statistically_converged
    control.iteration(3, 80.0, False)
    assert not control.statistically_converged
    control.iteration(4, 49.9998, True)
    assert control.statistically_converged


def test_restart_compares_the_new_objective_with_the_last_cost() -> None:
    """After the terms are refreshed (a new objective) the test starts again: a lower best of
    the former objective does not make every cost of the new one look like a rise."""
    control = SolveControl(None, None, 50)
    feed(control, [100.0, 50.0, 49.9999, 49.9998])
    assert control.statistically_converged
    control.restart()
    assert not control.statistically_converged and math.isinf(control._best)
    for it, cost in enumerate([70.0, 60.0, 59.9999, 59.9998]):
        control.iteration(it, cost, True)
    assert control.statistically_converged


def test_nonmonotonic_steps_only_on_large_blocks() -> None:
    def built(n: int) -> backend.CeresProblem:
        return backend.CeresProblem(None, [], True, blocks=[(None, [])] * n)

    n = backend.NONMONOTONIC_MIN_RESIDUAL_BLOCKS
    assert backend.nonmonotonic(built(n)) and not backend.nonmonotonic(built(n - 1))
    options = backend.SolveSettings(50, 1e-10, 1e-10, "none", 3.0)
    assert backend.ceres_options(options, built(n), SolveControl(None, None, 50)).use_nonmonotonic_steps
    assert not backend.ceres_options(options, built(10), SolveControl(None, None, 50)).use_nonmonotonic_steps
