"""The report: :func:`solver.report.document.assess` (statistics, covariance) and the registry of
its sections (:mod:`solver.report.sections`; the core's in :mod:`solver.report.core_sections`,
check points, statistics)."""
