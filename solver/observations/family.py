"""The interface of an observation family (listed in :mod:`solver.observations.registry`) and of
the image-only residual terms the families hand to the engine (:mod:`solver.engine.terms`)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from solver.errors import Problem
    from solver.schema.job import Job
    from solver.state import AdjustmentState


class ImageTerm(Protocol):
    """Whitened residuals r(p) of one image's free parameters p, with dr/dp."""

    image_index: int
    n_residuals: int

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(residuals (m,), jacobian (m, nfree)) at ``params``."""
        ...


class ObservationFamily(Protocol):
    """One kind of observation: what validation, the Ceres problem and the report need of it.

    ``name`` is the key of the family's section in the report. ``direct_datum``: the family's
    observations, with weighted platform states, define the datum without ground control
    (direct georeferencing, :mod:`solver.engine.validate`).
    """

    name: str
    direct_datum: bool

    def problems(self, job: Job) -> list[Problem]:
        """What in the job cannot be used as asked (located problems); empty when usable."""
        ...

    def n_observations(self, job: Job) -> int:
        """Observation equations the family adds (validation's degrees of freedom)."""
        ...

    def terms(self, problem: AdjustmentState) -> list[ImageTerm]:
        """The family's residual terms, in a fixed order."""
        ...

    def refresh(self, problem: AdjustmentState) -> float:
        """Re-linearise at the current parameters; the largest whitened-residual change (0: none)."""
        ...

    def report(self, problem: AdjustmentState) -> Any:
        """The family's report section (JSON-ready) at the current parameters."""
        ...
