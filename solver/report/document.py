"""The adjustment report (docs/report-contract.md), built at the solution by :func:`assess`:
the adjustment's statistics and the covariance, once, then the sections of the registry
:mod:`solver.report.sections` (the core's: images, correlations, observations, points, check
points, quality; the parameter blocks': cameras, passes, ...; the observation families':
ephemeris, attitude, lines, ...).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from solver.engine.linalg import Covariance, Linearisation, SchurParts, covariance, linearise, schur
from solver.report.core_sections import creeping_warning
from solver.report.sections import ReportInputs, build_sections
from solver.schema.settings import JobSettings
from solver.state import AdjustmentState


@dataclass
class Linearised:
    """The report's linearisation at the solution with the observations' Jacobians, its
    eliminated points (the reduced matrix itself dropped) and the inverse of the reduced
    matrix (the covariance's): what data snooping's tests are built from
    (:func:`solver.quality.outlier_tests.snoop`), handed over instead of computed again."""

    lin: Linearisation
    parts: SchurParts
    s_inv: np.ndarray


def _covariance(lin: Linearisation, problem: AdjustmentState, warnings: list[str]) -> tuple[Covariance | None, SchurParts]:
    """The covariance at the solution, or None with a warning when the normal matrix is not
    positive definite; and the eliminated points."""
    parts = schur(lin, problem)
    try:
        return covariance(lin, parts, problem), parts
    except np.linalg.LinAlgError:
        warnings.append(
            "the normal matrix is not positive definite at the solution: no covariance, "
            "sigmas or correlation coefficients"
        )
        return None, parts


def assess(problem: AdjustmentState, outcome) -> dict[str, Any]:
    """Statistics, covariance, check points and the report, at the current parameters."""
    return build_sections(report_inputs(problem, outcome)[0])


def report_inputs(problem: AdjustmentState, outcome, keep_linearised: bool = False) -> tuple[ReportInputs, Linearised | None]:
    """What the report's sections are built from (:class:`solver.report.sections.ReportInputs`),
    at the current parameters: the statistics and the covariance, computed once; with
    ``keep_linearised`` also the linearisation they came from (:class:`Linearised`; None
    without a covariance), else its Jacobians are dropped at once."""
    job = problem.job
    stats = JobSettings.from_options(job.options).statistics
    lin = linearise(problem)
    n_obs = len(lin.residuals)
    n_unk = lin.layout.n_params
    dof = n_obs - n_unk
    vtpv = float(lin.residuals @ lin.residuals)
    sigma0 = math.sqrt(vtpv / dof) if dof > 0 else None
    warnings: list[str] = []
    if dof == 0:
        warnings.append("zero degrees of freedom: no a-posteriori variance; sigmas use sigma0 a priori")
    var_factor = (sigma0**2) if sigma0 is not None else stats.sigma0_apriori**2
    cov, parts = _covariance(lin, problem, warnings) if stats.covariance and outcome.usable else (None, None)
    linearised = Linearised(lin, parts, cov.images) if keep_linearised and cov is not None and parts is not None else None
    lin = lin.without_jacobians()  # the report reads residuals only: a million observations' Jacobians are ~0.5 GB
    if not lin.ok.all():
        warnings.append(f"{int((~lin.ok).sum())} projections did not converge at the solution")
    if not outcome.converged:
        warnings.append(f"the solver did not converge: {outcome.message}")
        creeping = creeping_warning(problem, cov)
        if creeping is not None:
            warnings.append(creeping)

    return ReportInputs(problem, outcome, lin, cov, n_obs, n_unk, dof, vtpv, sigma0, var_factor, stats, warnings), linearised
