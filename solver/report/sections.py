"""The report's sections, registered in the order they are built (:data:`SECTIONS`): the one list
of what a report holds. A new section is a :class:`ReportSection` (its module) and one line
here; :func:`solver.report.document.assess` computes the adjustment's statistics and the
covariance once, then builds each section from :class:`ReportInputs` (a later section may read
an earlier one: the check points use the images' ground sample distances). The parameter-block
kinds (:mod:`solver.blocks.registry`) and the observation families
(:mod:`solver.observations.registry`) bring their own sections through one entry each.

The published order of the report's keys is :data:`SECTION_ORDER` (docs/report-contract.md);
sections not in it follow it, then ``quality`` and ``warnings``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from solver.blocks import registry as blocks
from solver.engine.assemble import parameter_names
from solver.engine.linalg import Covariance, Linearisation
from solver.observations import registry as families
from solver.observations.family import ReportContext
from solver.quality.leave_one_out import leave_one_out
from solver.quality.parameter_checks import high_correlations, implausible_sigmas
from solver.quality.precision import checkpoint_precision
from solver.report import core_sections
from solver.report.checkpoints import compute_checkpoints
from solver.report.statistics import chi2_test
from solver.schema.settings import StatisticsConfig
from solver.state import AdjustmentState

REPORT_SCHEMA_VERSION = "1.0"
# The order of the report's keys (docs/report-contract.md): the core's and the families'
# (ephemeris, attitude, lines, passes, cameras) as published; a new section follows them, then
# quality and warnings.
SECTION_ORDER = (
    "schema_version", "kind", "job_name", "frames", "adjustment", "images", "correlations", "cameras", "passes",
    "observations", "tie_points", "control_points", "checkpoints", "lines", "ephemeris", "attitude",
)
LAST = ("quality", "warnings")


@dataclass
class ReportInputs:
    """What a section may use: the problem at its solution, the solve's outcome, the residuals
    (``lin``, without the observations' Jacobians), the covariance (a-priori scale; None
    without), the statistics (observations, unknowns, degrees of freedom, v^T P v, sigma0 a
    posteriori and the variance factor that scales the covariance), the statistics options,
    the report's warnings (a section appends its own) and the sections built so far."""

    problem: AdjustmentState
    outcome: Any  # solver.engine.backend.SolveOutcome
    lin: Linearisation
    cov: Covariance | None
    n_observations: int
    n_unknowns: int
    dof: int
    vtpv: float
    sigma0: float | None
    var_factor: float
    stats: StatisticsConfig
    warnings: list[str]
    sections: dict[str, Any] = field(default_factory=dict)
    gsds: list[float] = field(default_factory=list)  # the images' ground sample distances (m)
    built: int = 0  # the registry's entries built so far (in its order)

    def context(self) -> ReportContext:
        """The blocks' and families' view of these inputs."""
        cov = self.cov.images if self.cov is not None else None
        return ReportContext(cov, self.lin.layout, self.var_factor, self.stats.sigma0_apriori, self.warnings)


class ReportSection(Protocol):
    """One entry of the registry: the sections it builds (name -> JSON-ready value)."""

    def build(self, inputs: ReportInputs) -> dict[str, Any]: ...


class _Header:
    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        problem = inputs.problem
        return {
            "schema_version": REPORT_SCHEMA_VERSION,
            "kind": "adjustment",
            "job_name": problem.job.name,
            "frames": {"lgs": problem.frame.to_dict(), "ecef": "EPSG:4978"},
        }


class _Adjustment:
    """The adjustment's statistics and the solve's outcome."""

    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        o, stats = inputs.outcome, inputs.stats
        return {"adjustment": {
            "n_observations": inputs.n_observations,
            "n_unknowns": inputs.n_unknowns,
            "dof": inputs.dof,
            "iterations": o.iterations,
            "converged": o.converged,
            "termination": o.termination,
            "message": o.message,
            "linear_solver": o.linear_solver,
            "sigma0_apriori": stats.sigma0_apriori,
            "sigma0_aposteriori": inputs.sigma0,
            "chi2": chi2_test(inputs.vtpv, inputs.dof, stats.alpha, stats.sigma0_apriori),
            "solve_time_s": o.time_s,
            "initial_cost": o.initial_cost,
            "final_cost": o.final_cost,
            "cost_history": o.history,
        }}


class _Images:
    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        images, inputs.gsds = core_sections.images_report(inputs.problem, inputs.lin, inputs.cov, inputs.var_factor)
        return {"images": images}


class _Correlations:
    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        return {"correlations": core_sections.correlations(inputs.problem, inputs.cov, inputs.stats.correlation_threshold)}


class _BlockKinds:
    """Each parameter-block kind's sections (cameras, passes, ...), in the kinds' registry order."""

    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        out: dict[str, Any] = {}
        ctx = inputs.context()
        for kind in blocks.BLOCK_KINDS:
            out.update(kind.report(inputs.problem, ctx))
        return out


class _Families:
    """Each observation family's sections, in the families' registry order (their warnings join the report's)."""

    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        out: dict[str, Any] = {}
        ctx = inputs.context()
        for family in families.FAMILIES:
            out.update(family.report(inputs.problem, ctx))
        return out


class _Observations:
    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        return {"observations": core_sections.observations_report(inputs.problem, inputs.lin, inputs.cov)}


class _Points:
    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        return {
            "tie_points": core_sections.points_report(inputs.problem, inputs.cov, inputs.var_factor, role="tie"),
            "control_points": core_sections.points_report(inputs.problem, inputs.cov, inputs.var_factor, role="gcp"),
        }


class _Checkpoints:
    """Check points: discrepancies, their tests and their predicted precision."""

    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        stats = inputs.stats
        gsd = float(np.mean(inputs.gsds)) if inputs.gsds else None
        checkpoints = compute_checkpoints(inputs.problem, stats.alpha, gsd)
        q_ff = inputs.cov.images if inputs.cov is not None else None
        checkpoint_precision(checkpoints, inputs.problem, inputs.lin.layout, q_ff, inputs.var_factor, stats.alpha)
        return {"checkpoints": checkpoints}


class _Quality:
    """Leave-one-out, the place of the parsimony analysis, the parameter warnings (the first ten
    also in the report's warnings)."""

    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        problem, stats, warnings = inputs.problem, inputs.stats, inputs.warnings
        q_ff = inputs.cov.images if inputs.cov is not None else None
        quality_warnings = implausible_sigmas(problem, inputs.sections["images"], stats.quality_warnings.attitude_sigma_deg)
        quality_warnings += high_correlations(q_ff, parameter_names(problem), stats.quality_warnings.correlation)
        warnings += [w["message"] for w in quality_warnings[:10]]
        if len(quality_warnings) > 10:
            warnings.append(f"{len(quality_warnings) - 10} more parameter warnings in quality.warnings")
        lay = inputs.lin.layout
        return {"quality": {
            "leave_one_out": leave_one_out(problem, lay, q_ff, inputs.var_factor, stats.alpha) if stats.leave_one_out else None,
            "parsimony": None,
            "warnings": quality_warnings,
        }}


class _Warnings:
    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        return {"warnings": inputs.warnings}


SECTIONS: tuple[ReportSection, ...] = (
    _Header(),  # schema_version, kind, job_name, frames
    _Adjustment(),  # adjustment
    _Images(),  # images (and the ground sample distances the check points use)
    _Correlations(),  # correlations
    _BlockKinds(),  # cameras, passes, ... (solver/blocks/)
    _Families(),  # ephemeris, attitude, lines, ... (solver/observations/)
    _Observations(),  # observations
    _Points(),  # tie_points, control_points
    _Checkpoints(),  # checkpoints
    _Quality(),  # quality
    _Warnings(),  # warnings: the last, every section's warnings in it
)


def build_through(inputs: ReportInputs, name: str | None = None) -> None:
    """Build the registry's entries in order, each once, until section ``name`` exists (None:
    all of them): a section asked for early (a procedure reading the check points) is built
    with everything before it, so the warnings keep the registry's order."""
    registry = SECTIONS
    while inputs.built < len(registry) and (name is None or name not in inputs.sections):
        inputs.sections.update(registry[inputs.built].build(inputs))
        inputs.built += 1


def ordered(sections: dict[str, Any]) -> dict[str, Any]:
    """The sections in the published key order: :data:`SECTION_ORDER`, the others, then :data:`LAST`."""
    report = dict(sections)
    first = {k: report.pop(k) for k in SECTION_ORDER if k in report}
    last = {k: report.pop(k) for k in LAST if k in report}
    return {**first, **report, **last}


def build_sections(inputs: ReportInputs) -> dict[str, Any]:
    """Every registered section, in the registry's order, then in the published key order."""
    build_through(inputs)
    return ordered(inputs.sections)
