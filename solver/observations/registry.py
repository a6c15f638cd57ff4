"""The observation families the adjustment walks: one line per family.

The core of the problem is not a family: image points (the collinearity of a ground point and
its image, :mod:`solver.kernels`) and control points (fixed, or weighted by their survey) are
assembled, solved, tested, removed and reported by the stages themselves (they carry the ground
points, the Schur-eliminated blocks). Everything else that observes the parameters is a family
here, implementing :class:`solver.observations.family.ObservationFamily`:

* validation (:mod:`solver.engine.validate`): ``check`` (problems and counts);
* the Ceres problem and the linearisation (:mod:`solver.engine.terms`, consumed by
  :mod:`solver.engine.backend` and :mod:`solver.engine.linalg`): ``terms``, ``refresh``;
* quality control (:mod:`solver.quality.reliability`, :mod:`solver.quality.outlier_tests`,
  :mod:`solver.quality.removal`, :mod:`solver.quality.flags`): ``groups`` (the tests of a
  term, labelled), ``without`` (the job without removed observations), ``removal_details``,
  ``flag``;
* the report (:mod:`solver.report.document`): ``report`` (the family's sections).

The order of :data:`FAMILIES` is the order of the terms handed to Ceres and to the covariance,
of the tests and of the flags (the ephemeris family starts the ``ephemeris`` flags that the
passes family adds to). The stages read ``registry.FAMILIES`` when they run, never a copy.

Adding a family (the checklist): its module in ``solver/observations/`` (the interface above,
with :class:`solver.observations.family.FamilyDefaults` for the parts it does not need), its
fields in ``solver/schema/job.py``, one line below; tests/solver/observations/test_observation_registry.py adds a
fake family this way and follows it through every stage.
"""

from __future__ import annotations

from solver.observations import attitude, dem_heights, interior, lines, passes, state_priors
from solver.observations.family import ObservationFamily

FAMILIES: tuple[ObservationFamily, ...] = (
    state_priors.FAMILY,  # weighted line-0 states (header, ephemeris) and RPC bias priors: "ephemeris"
    attitude.FAMILY,  # measured attitude: "attitude"
    lines.FAMILY,  # straight-line control: "lines"
    passes.FAMILY,  # weighted states of the pass-propagated models: "passes"
    interior.FAMILY,  # interior orientation priors: "cameras"
    dem_heights.FAMILY,  # DEM heights of the tie points (job.dem): "dem"
)
