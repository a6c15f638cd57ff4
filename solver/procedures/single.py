"""One adjustment of a job: validate, build, initialise, check rank, solve; its outcome a
:class:`solver.report.solution.Solution` (what the procedures read, and the report built from it).

Small verbs, one per step (as Ceres' bundle_adjuster.cc); pyceres is used only through
:mod:`solver.engine.backend`, imported when a solve runs (the server process never loads it).
The procedures that adjust more than once (:mod:`solver.procedures.snooping`,
:mod:`solver.procedures.parsimony`, :mod:`solver.procedures.significance`) are built on
:func:`adjust_once`. A job handed validated (:class:`solver.engine.validate.ValidatedJob`) is not
checked again.
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable

import numpy as np

from solver.engine.assemble import build_problem, parameter_names
from solver.engine.initialize import initialise
from solver.engine.linalg import check_rank, linearise, schur
from solver.engine.validate import ValidatedJob, validated
from solver.errors import Cancelled, JobError, Problem, RankDeficientError, UnusableSolution
from solver.quality.control_fit import control_misfits, control_problems
from solver.quality.datum import DatumAnalysis, analyse_datum, datum_problem, dem_bias
from solver.report.document import assess  # noqa: F401 (the report of a problem at its solution, for benchmarks and tests)
from solver.report.solution import Solution
from solver.schema.job import Job
from solver.schema.settings import JobSettings
from solver.state import AdjustmentState

Adjust = Callable[["Job | ValidatedJob", tuple[float, float]], Solution]
"""``adjust(job, fraction_range) -> solution``: the adjustment a procedure repeats (the progress
of that run mapped into ``fraction_range`` of the whole)."""


def _progress(progress, fraction: float, message: str, info: dict | None = None) -> None:
    if progress is not None:
        progress(fraction, message, info or {})


def prepare(job: Job | ValidatedJob, models: dict[str, str] | None = None) -> AdjustmentState:
    """Validated (unless handed validated), assembled and initialised problem (raises JobError on bad input)."""
    problem = build_problem(validated(job).job, models)
    initialise(problem)
    return problem


def check_control(problem: AdjustmentState) -> list[str]:
    """Control that does not fit the orientation the job starts from
    (:mod:`solver.quality.control_fit`): a JobError naming a set that does not belong (unless
    ``options.control_check`` is ``warn``), else the sentences for the report's warnings."""
    misfits = control_misfits(problem)
    refuse = JobSettings.from_options(problem.job.options).procedures.control_check == "refuse"
    if refuse and any(m.refused for m in misfits):
        raise JobError(control_problems([m for m in misfits if m.refused]))
    return [m.sentence() + (" (adjusted anyway: options.control_check warn)" if m.refused else " (left to data snooping)")
            for m in misfits]


def assert_full_rank(problem: AdjustmentState) -> DatumAnalysis:
    """Raise RankDeficientError naming the parameters the control geometry does not fix, and
    the directions of the datum it leaves not determined at all (:mod:`solver.quality.datum`:
    refused unless ``options.datum.undetermined`` is ``"report"``); the datum analysis at the
    initial values (a direction only weakly determined there is confirmed at the solution by
    :func:`confirm_datum`)."""
    lin = linearise(problem)
    parts = schur(lin, problem, rebuildable=True)
    datum_options = JobSettings.from_options(problem.job.options).blocks.datum
    datum = analyse_datum(problem, lin, parts, parameter_names(problem), datum_options.max_sigma_m)
    issues = []
    for q in np.flatnonzero(parts.point_singular):
        p = problem.points[parts.est_points[q]]
        issues.append(
            Problem(
                "point_geometry_singular",
                f"point {p.id!r}: its rays are (nearly) parallel, its coordinates cannot be determined",
                ("points", p.index),
            )
        )
    if datum.unbounded and datum_options.undetermined == "refuse":
        issues.append(datum_problem(datum.to_report()))
    rank = check_rank(parts, parameter_names(problem), fast=True)
    if rank.deficient:
        names = ", ".join(n for n, _ in rank.null_parameters) or "(spread over many parameters)"
        issues.append(
            Problem(
                "rank_deficient",
                "the control geometry leaves these parameters undetermined (the normal matrix is "
                f"singular, condition {rank.condition:.3g}): {names}. Add or spread control points, "
                "or choose a model with fewer parameters.",
                ("images",),
                {
                    "parameters": [n for n, _ in rank.null_parameters],
                    # JSON has no infinity: an exactly singular matrix has no finite condition
                    "condition": rank.condition if np.isfinite(rank.condition) else None,
                },
            )
        )
    if issues:
        raise RankDeficientError(issues)
    return datum


def confirm_datum(problem: AdjustmentState, before: DatumAnalysis) -> DatumAnalysis:
    """The datum analysis again at the solution when the one at the initial values found a
    direction undetermined (initial values far from the truth can make a determined direction
    look weak: an orbit-attitude block's initial linearisation put 287 m on a shift its solution
    determines to 0.3 m); refused there (RankDeficientError) unless the job says "report"."""
    if not before.undetermined:
        return before
    datum_options = JobSettings.from_options(problem.job.options).blocks.datum
    lin = linearise(problem)
    datum = analyse_datum(problem, lin, schur(lin, problem, rebuildable=True), parameter_names(problem), datum_options.max_sigma_m)
    datum.at = "solution"
    if datum.undetermined and datum_options.undetermined == "refuse":
        raise RankDeficientError([datum_problem(datum.to_report())])
    return datum


def solve_problem(problem: AdjustmentState, control):
    """The bundle solve from the initial values.

    A per-image resection on the control before the bundle was tried and removed: it moves each
    image along its weakly determined pitch / along-track-position direction, and the bundle then
    needs 3-4x more iterations (triplet: 21 instead of 6) than from the header state.
    """
    from solver.engine.backend import solve
    from solver.engine.terms import solve_with_refreshes

    # terms that linearise around the solution (line corrections) are refreshed between solves
    return solve_with_refreshes(problem, JobSettings.from_options(problem.job.options).solve, control, solve)


def adjust_once(
    job: Job | ValidatedJob,
    progress: Callable[..., None] | None = None,
    cancel: Callable[[], bool] | None = None,
    models: dict[str, str] | None = None,
    fraction_range: tuple[float, float] = (0.0, 1.0),
    keep_linearised: bool = False,
) -> Solution:
    """One adjustment of ``job``: the problem at its solution (the report is built from it when
    asked); ``keep_linearised``: the solution keeps the report's linearisation for data snooping
    (:meth:`Solution.take_linearised`)."""
    from solver.engine.backend import SolveControl  # imports pyceres: workers only

    f0, f1 = fraction_range

    def frac(x: float) -> float:
        return f0 + (f1 - f0) * x

    t_start = time.perf_counter()
    _progress(progress, frac(0.01), "validating")
    problem = prepare(job, models)
    _progress(progress, frac(0.05), "initial values computed")
    foreign = check_control(problem)
    datum = assert_full_rank(problem)
    if cancel is not None and cancel():
        raise Cancelled("cancelled before the solve")
    control = SolveControl(progress, cancel, JobSettings.from_options(problem.job.options).solve.max_iterations, (frac(0.08), frac(0.9)))
    outcome = solve_problem(problem, control)
    if outcome.cancelled:
        raise Cancelled(f"cancelled after {outcome.iterations} iterations")
    reasons = outcome.unusable_reasons()
    if reasons:
        raise UnusableSolution.from_outcome(reasons, _outcome_detail(outcome))
    _progress(progress, frac(0.92), "assessing the solution")
    datum = confirm_datum(problem, datum)
    with_dem = problem.job.dem is not None  # the job as solved (handed validated or not)
    solution = Solution(problem, outcome, time.perf_counter() - t_start, datum, keep_linearised or with_dem)
    for k, sentence in enumerate(foreign):  # the control that does not fit, first among the warnings
        solution.prepend_warning(sentence, k)
    quality: dict[str, Any] = {"datum": datum.to_report()}
    if with_dem:
        bias = _dem_bias(solution, JobSettings.of(problem.job).statistics.alpha)
        if not keep_linearised:
            solution.take_linearised()  # not kept for anyone else
        if bias is not None:
            quality["dem_bias"] = bias
    solution.set_quality(quality)
    if datum.undetermined:
        solution.prepend_warning(f"the datum is not determined: {datum.message()} (quality.datum)")
    _progress(progress, frac(1.0), "done", {"sigma0": solution.sigma0})
    return solution


def _dem_bias(solution: Solution, alpha: float) -> dict[str, Any] | None:
    """The test of a common DEM bias at the solution (:func:`solver.quality.datum.dem_bias`), on
    the report's linearisation and the covariance's inverse of the reduced matrix, as data
    snooping's tests; linearised again only where the report kept none (no covariance)."""
    problem = solution.problem
    kept = solution.kept_linearised()
    if kept is not None:
        return dem_bias(problem, kept.lin, kept.parts, alpha, kept.s_inv)
    lin = linearise(problem)
    return dem_bias(problem, lin, schur(lin, problem), alpha)


def _outcome_detail(outcome) -> dict[str, Any]:
    """The solver's own account of a solve, JSON-ready (a non-finite cost is null)."""

    def finite(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    return {
        "termination": outcome.termination,
        "message": outcome.message,
        "iterations": outcome.iterations,
        "successful_iterations": outcome.successful_steps,
        "initial_cost": finite(outcome.initial_cost),
        "final_cost": finite(outcome.final_cost),
    }
