"""The adjustment driver: validate, build, initialise, check rank, solve, assess, report.

Small verbs, one per step; pyceres is used only through :mod:`solver.engine.backend`.
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable

import numpy as np

from solver.engine.assemble import build_problem, parameter_names
from solver.engine.initialize import initialise
from solver.engine.linalg import check_rank, linearise, schur
from solver.engine.validate import require_valid
from solver.errors import Cancelled, Problem, RankDeficientError, UnusableSolution
from solver.report.document import assess
from solver.schema.job import Job
from solver.state import AdjustmentState

__all__ = ["adjust_job", "assert_full_rank", "assess", "parameter_names", "prepare", "solve_problem"]


def _progress(progress, fraction: float, message: str, info: dict | None = None) -> None:
    if progress is not None:
        progress(fraction, message, info or {})


def prepare(job: Job, models: dict[str, str] | None = None) -> AdjustmentState:
    """Validated, assembled and initialised problem (raises JobError on bad input)."""
    require_valid(job)
    problem = build_problem(job, models)
    initialise(problem)
    return problem


def assert_full_rank(problem: AdjustmentState) -> None:
    """Raise RankDeficientError naming the parameters the control geometry does not fix."""
    lin = linearise(problem)
    parts = schur(lin, problem)
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
    rank = check_rank(parts, parameter_names(problem))
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


def solve_problem(problem: AdjustmentState, control):
    """The bundle solve from the initial values.

    A per-image resection on the control before the bundle was tried and removed: it moves each
    image along its weakly determined pitch / along-track-position direction, and the bundle then
    needs 3-4x more iterations (triplet: 21 instead of 6) than from the header state.
    """
    from solver.engine.backend import solve
    from solver.engine.terms import solve_with_refreshes

    # terms that linearise around the solution (line corrections) are refreshed between solves
    return solve_with_refreshes(problem, problem.job.options, control, solve)


def _significance_analysis(job: Job, progress, cancel, models) -> dict[str, Any]:
    """Seed 001 Figure 14: adjust, drop the interior-orientation parameter whose |estimate| is
    smallest relative to its sigma if it is below its sigma, re-adjust; repeat. Every step is
    reported; the final report is that of the last adjustment."""
    sc = job.options.self_calibration
    exclude = list(sc.exclude)
    steps = []
    report: dict[str, Any] = {}
    for step in range(200):
        lo = 1.0 - 0.5**step
        hi = 1.0 - 0.5 ** (step + 1)
        j = job.model_copy(
            update={"options": job.options.model_copy(update={"self_calibration": sc.model_copy(update={"exclude": list(exclude), "significance_analysis": False})})}
        )
        report = adjust_job(j, progress=progress, cancel=cancel, models=models, fraction_range=(lo, hi))
        weak = [
            (abs(p["value"]) / p["sigma"], cam["id"], p)
            for cam in report["cameras"]
            for p in cam["parameters"]
            if p["estimated"] and p["sigma"] and abs(p["value"]) < sc.significance_threshold * p["sigma"]
        ]
        cp = report["checkpoints"]["rmse_m"]
        entry = {
            "step": step,
            "sigma0": report["adjustment"]["sigma0_aposteriori"],
            "n_iop": sum(p["estimated"] for c in report["cameras"] for p in c["parameters"]),
            "check_rmse_m": cp,
            "dropped": None,
        }
        steps.append(entry)
        if not weak:
            break
        ratio, cam_id, p = min(weak, key=lambda w: w[0])
        entry["dropped"] = {"name": f"{cam_id}/{p['name']}", "value": p["value"], "sigma": p["sigma"], "ratio": ratio}
        exclude.append(f"{cam_id}/{p['name']}")
    report["parameter_analysis"] = {
        "rule": f"drop, one at a time, the parameter with the smallest |estimate|/sigma while below {sc.significance_threshold:g}",
        "steps": steps,
        "dropped": [s["dropped"]["name"] for s in steps if s["dropped"]],
        "correlated_pairs": [p for p in report["correlations"]["pairs"] if "IOP" in p.get("kinds", "")],
    }
    if progress is not None:
        progress(1.0, "significance analysis done", {})
    return report


def adjust_job(
    job: Job,
    progress: Callable[..., None] | None = None,
    cancel: Callable[[], bool] | None = None,
    models: dict[str, str] | None = None,
    fraction_range: tuple[float, float] = (0.0, 1.0),
) -> dict[str, Any]:
    """Run the whole adjustment of ``job`` and return the report (docs/report-contract.md).

    ``models`` optionally overrides the platform model per image id (model comparison).
    """
    from solver.engine.backend import SolveControl  # imports pyceres: workers only

    sc = job.options.self_calibration
    if sc is not None and sc.significance_analysis:
        return _significance_analysis(job, progress, cancel, models)
    f0, f1 = fraction_range

    def frac(x: float) -> float:
        return f0 + (f1 - f0) * x

    t_start = time.perf_counter()
    _progress(progress, frac(0.01), "validating")
    problem = prepare(job, models)
    _progress(progress, frac(0.05), "initial values computed")
    assert_full_rank(problem)
    if cancel is not None and cancel():
        raise Cancelled("cancelled before the solve")
    control = SolveControl(progress, cancel, job.options.max_iterations, (frac(0.08), frac(0.9)))
    outcome = solve_problem(problem, control)
    if outcome.cancelled:
        raise Cancelled(f"cancelled after {outcome.iterations} iterations")
    reasons = outcome.unusable_reasons()
    if reasons:
        raise UnusableSolution.from_outcome(reasons, _outcome_detail(outcome))
    _progress(progress, frac(0.92), "assessing the solution")
    report = assess(problem, outcome)
    report["adjustment"]["total_time_s"] = time.perf_counter() - t_start
    _progress(progress, frac(1.0), "done", {"sigma0": report["adjustment"]["sigma0_aposteriori"]})
    return report


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
