"""The job's ``options`` as the solver's own settings: Options / Config / Summary kept apart,
as COLMAP's bundle adjustment does (../shared/STYLE.md).

The job document keeps its one ``options`` object (:class:`solver.schema.job.SolverOptions`,
the wire format users write and openapi.yaml publishes); :meth:`JobSettings.from_options` maps it,
at the boundary, onto four objects whose names collide with nothing of pyceres':

* :class:`SolveSettings`: how to solve (Ceres: iterations, tolerances, robust loss), read by
  :mod:`solver.engine.backend` only;
* :class:`BlockConfig`: which parameter blocks are estimated and how the datum is fixed
  (control points weighted or fixed, interior orientation, weighted platform observations,
  the line model);
* :class:`StatisticsConfig`: which statistics the report computes and at which levels;
* :class:`ProcedureConfig`: the procedures that adjust more than once or plan
  (:mod:`solver.procedures`, pre-analysis, model comparison).

The outcome of a solve is the library's own Summary (:class:`solver.engine.backend.SolveOutcome`).
Every field of ``options`` maps to exactly one of the four (tests/solver/schema/test_settings.py), except the
deprecated ``kernel``, which nothing reads.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from solver.schema.job import (
    AttitudeOptions,
    BlunderDetection,
    DatumOptions,
    EphemerisOptions,
    Job,
    Parsimony,
    PreanalysisOptions,
    QualityWarnings,
    SelfCalibration,
    SolverOptions,
)


@dataclass(frozen=True)
class SolveSettings:
    """How to solve: Ceres' iteration limit and tolerances (dimensionless, relative), and the
    robust loss (``none``, ``huber``, ``cauchy``) with its scale (whitened residual units)."""

    max_iterations: int
    function_tolerance: float
    parameter_tolerance: float
    loss: str
    loss_scale: float


@dataclass(frozen=True)
class BlockConfig:
    """Which blocks are estimated and how the datum is fixed."""

    control: str  # weighted | fixed (control point coordinates)
    self_calibration: SelfCalibration | None  # the cameras' free interior orientation
    ephemeris: EphemerisOptions | None  # weighted ephemeris states
    attitude: AttitudeOptions | None  # weighted attitude samples
    line_model: str  # rigorous | equivalent_planes
    line_correction: str  # iterated | initial | none
    datum: DatumOptions = field(default_factory=DatumOptions)  # the datum analysis: refuse or report an undetermined direction


@dataclass(frozen=True)
class StatisticsConfig:
    """Which statistics the report computes: sigma0 a priori, the level of its tests, the
    correlation threshold of the listed pairs, the covariance, leave-one-out, the warnings."""

    sigma0_apriori: float
    alpha: float
    correlation_threshold: float
    covariance: bool
    leave_one_out: bool
    quality_warnings: QualityWarnings


@dataclass(frozen=True)
class ProcedureConfig:
    """The procedures around one adjustment (each None or False: off)."""

    blunder_detection: BlunderDetection | None  # data snooping
    parsimony: Parsimony | None  # significance of the platform terms
    significance_analysis: bool  # of the interior orientation (options.self_calibration)
    models: tuple[str, ...]  # model comparison
    preanalysis: PreanalysisOptions | None  # planning
    weak_control: str = "act"  # the rule when the control does not determine an attitude term
    control_check: str = "refuse"  # control that does not fit the delivered orientation (solver.quality.control_fit)


@dataclass(frozen=True)
class JobSettings:
    """The four groups of a job's ``options``."""

    solve: SolveSettings
    blocks: BlockConfig
    statistics: StatisticsConfig
    procedures: ProcedureConfig

    @classmethod
    def of(cls, job: Job) -> "JobSettings":
        """The settings of a job (:meth:`from_options` of its ``options``)."""
        return cls.from_options(job.options)

    @classmethod
    def from_options(cls, o: SolverOptions) -> "JobSettings":
        """The settings of the job document's ``options`` (the wire format, unchanged)."""
        sc = o.self_calibration
        return cls(
            SolveSettings(o.max_iterations, o.function_tolerance, o.parameter_tolerance, o.loss, o.loss_scale),
            BlockConfig(o.control, sc, o.ephemeris, o.attitude, o.line_model, o.line_correction, o.datum),
            StatisticsConfig(o.sigma0_apriori, o.alpha, o.correlation_threshold, o.covariance, o.leave_one_out, o.quality_warnings),
            ProcedureConfig(o.blunder_detection, o.parsimony, bool(sc is not None and sc.significance_analysis), tuple(o.models),
                            o.preanalysis, o.weak_control, o.control_check),
        )
