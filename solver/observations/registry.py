"""The observation families the engine loops over: one line per family.

Each entry implements :class:`solver.observations.family.ObservationFamily`. The stages use
the registry instead of naming families: :mod:`solver.engine.validate` (problems, counts),
:mod:`solver.engine.terms` (Ceres terms and their refresh) and the report in
:mod:`solver.adjust` (one section per family, under the family's name). The order here is the
order of the terms handed to Ceres and of the report's sections.

Families not yet in this shape (points, state priors, ephemeris, lines, passes, interior
orientation) are still named by the stages themselves (issue 14, continued).
"""

from __future__ import annotations

from solver.observations import attitude
from solver.observations.family import ObservationFamily

FAMILIES: tuple[ObservationFamily, ...] = (attitude.FAMILY,)
