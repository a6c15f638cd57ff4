"""The adjustment of a job: :func:`adjust_job` runs the procedures the job's options ask for
(parsimony, significance analysis, data snooping: :mod:`solver.procedures`) around one
adjustment (:func:`solver.procedures.single.adjust_once`: validate, build, initialise, check
rank, solve, assess).

The verbs of one adjustment are re-exported here: ``from solver.adjust import prepare``.
"""

from __future__ import annotations

from typing import Any, Callable

from solver.engine.assemble import parameter_names
from solver.engine.validate import ValidatedJob, job_of
from solver.procedures.parsimony import parsimony_analysis
from solver.procedures.significance import significance_analysis
from solver.procedures.single import adjust_once, assert_full_rank, assess, prepare, solve_problem
from solver.procedures.snooping import snooping_adjustment
from solver.procedures.weak_control import weak_control_rule
from solver.report.solution import Solution
from solver.schema.job import Job
from solver.schema.settings import JobSettings

__all__ = ["adjust_job", "adjust_once", "adjust_solution", "assert_full_rank", "assess", "parameter_names", "prepare", "solve_problem"]


def adjust_job(
    job: Job | ValidatedJob,
    progress: Callable[..., None] | None = None,
    cancel: Callable[[], bool] | None = None,
    models: dict[str, str] | None = None,
    fraction_range: tuple[float, float] = (0.0, 1.0),
) -> dict[str, Any]:
    """Run the whole adjustment of ``job`` and return the report (docs/report-contract.md):
    :func:`adjust_solution`'s, built once at the end."""
    return adjust_solution(job, progress, cancel, models, fraction_range).report()


def adjust_solution(
    job: Job | ValidatedJob,
    progress: Callable[..., None] | None = None,
    cancel: Callable[[], bool] | None = None,
    models: dict[str, str] | None = None,
    fraction_range: tuple[float, float] = (0.0, 1.0),
) -> Solution:
    """Run the whole adjustment of ``job`` (a job handed validated is not checked again) and
    return the last adjustment's solution, the procedures' notes on it.

    ``models`` optionally overrides the platform model per image id (model comparison).
    The procedures nest in this order: the weak-control rule (``options.weak_control``, on by
    default; off when the parsimony analysis is asked for, which decides the time terms, and in
    model comparisons, whose ``models`` replace the job's)
    repeats parsimony (``options.parsimony``), which repeats the
    significance analysis of the interior orientation (``options.self_calibration``), which
    repeats data snooping (``options.blunder_detection``), which repeats one adjustment; each
    gets the next one as its ``adjust``.
    """

    def inner(j: Job | ValidatedJob, window: tuple[float, float]) -> Solution:
        return adjust_solution(j, progress, cancel, models, window)

    procedures = JobSettings.from_options(job_of(job).options).procedures
    if procedures.weak_control == "act" and procedures.parsimony is None and not models:
        return weak_control_rule(job, inner, progress)
    if procedures.parsimony is not None:
        return parsimony_analysis(job, inner, progress)
    if procedures.significance_analysis:
        return significance_analysis(job, inner, progress)
    if procedures.blunder_detection is not None:
        return snooping_adjustment(job, progress, cancel, models, fraction_range)
    return adjust_once(job, progress, cancel, models, fraction_range)
