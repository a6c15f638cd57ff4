"""The interface of an observation family (listed in :mod:`solver.observations.registry`), of
the residual terms it hands to the engine and of the labels its observations carry through the
quality control (tests, reliability, removal, report flags).

A family's terms act on one parameter block each, of a kind of :mod:`solver.blocks.registry`
(an image's platform parameters, a pass's state, a camera's interior orientation, a ground
point, or a kind a family brings). Every stage walks the families in
the registry's order and their terms in the order the family gives them, so a term is known
by its :class:`Labelled` entry (family, block, the family's own tag) and never by position.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from solver.errors import Problem
    from solver.schema.job import Job
    from solver.state import AdjustmentState

REFRESH_TOL = 0.01  # largest change of a whitened residual (in sigmas) that ends the refreshes
MAX_REFRESHES = 20  # solves after the first one, at most, while some family's refresh changes a residual

class Term(Protocol):
    """Whitened residuals r(p) of one parameter block's free parameters p, with dr/dp."""

    n_residuals: int

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(residuals (m,), jacobian (m, nfree)) at ``params``."""
        ...

    def linear_form(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(A (m, nfree), b (m,)) when the residuals are the constant linear form ``A p - b``
        (whitened), else None: a linear term is evaluated without Python on the compiled path.
        Optional: a term without it is treated as nonlinear."""
        ...

    def compiled_form(self) -> tuple[str, np.ndarray, tuple[np.ndarray, ...]]:
        """Optional: (the name of its C callback in :mod:`solver.kernels.callbacks`, the
        callback's descriptor, the arrays the descriptor points into) for the compiled path; a
        term without it is evaluated in Python there."""
        ...


ImageTerm = Term  # the name the first families used


@dataclass(frozen=True)
class Labelled:
    """A family's term with what every stage needs to place it: the parameter block it acts on
    (``block``: the name of a kind of :mod:`solver.blocks.registry`, or ``point``; ``index``: the
    kind's index, for ``image`` the image's and for ``point`` the point's) and ``tag``, the
    family's own note for its tests (e.g. an attitude block's image indices)."""

    family: "ObservationFamily"
    term: Term
    block: str
    index: int
    tag: Any = None


@dataclass
class GroupSpec:
    """One testable observation inside a term: ``rows`` (the term's rows that belong to it), its
    report label (image, line, pass, time_s, ...), its standard deviations in ``units`` per row,
    the names of its components, ``sign`` (+1: residual = observed - model, -1: model -
    observed) and how to remove it from the job (a tuple the family's ``without`` understands;
    None: cannot be removed)."""

    kind: str
    rows: np.ndarray
    label: dict[str, Any]
    sigma: np.ndarray
    units: str
    components: list[str]
    sign: float = 1.0
    removal: tuple | None = None


@dataclass
class Count:
    """What a family adds to validation's counts.

    ``per_image``: observations that tie an image (an image with none from any family and no
    image point is refused). ``datum``: how the family's observations define the datum without
    ground control: ``"states"`` (weighted platform states), ``"attitude"`` (measured attitude:
    with weighted states, direct georeferencing), ``"control"`` (on their own: observed control
    lines, a-priori RPC bias values)."""

    n_observations: int = 0
    n_unknowns: int = 0
    per_image: dict[str, int] = field(default_factory=dict)
    datum: frozenset[str] = frozenset()


@dataclass
class ReportContext:
    """What a family's report sections may use: the covariance of the image, camera and pass
    parameters (a-priori scale, sigma0 = 1; None without one), the column layout
    (:class:`solver.engine.linalg.Layout`), the variance factor that scales it, sigma0 a priori,
    and the report's warnings (a family appends its own)."""

    covariance: np.ndarray | None
    layout: Any
    var_factor: float
    sigma0_apriori: float
    warnings: list[str] = field(default_factory=list)

    def block(self, kind: str, index: int, size: int) -> np.ndarray | None:
        """The covariance block (a-priori scale) of parameter block ``kind`` ``index`` (as a
        term's label names it) with ``size`` free parameters; None without a covariance or
        without free parameters (not for the eliminated points)."""
        if self.covariance is None or size == 0:
            return None
        c0 = self.layout.column(kind, index)
        return self.covariance[c0 : c0 + size, c0 : c0 + size]


class ObservationFamily(Protocol):
    """One kind of observation: what validation, the Ceres problem, the quality control and the
    report need of it.

    ``name``: the family's name (its report section, when it has one, is named by ``report``).
    """

    name: str

    def check(self, job: Job) -> tuple[list[Problem], Count]:
        """What in the job cannot be used as asked (located problems) and what the family adds
        to the counts (nothing that its problems make uncountable)."""
        ...

    def terms(self, problem: AdjustmentState) -> list[Labelled]:
        """The family's residual terms, in a fixed order."""
        ...

    def initialise(self, problem: AdjustmentState) -> None:
        """Refine the initial parameters from the family's observations (in place), after the
        platform states and before the tie points are intersected (default: nothing)."""
        ...

    def refresh(self, problem: AdjustmentState) -> float:
        """Re-linearise at the current parameters; the largest whitened-residual change (0: none)."""
        ...

    def groups(self, problem: AdjustmentState, labelled: Labelled) -> list[GroupSpec]:
        """The testable observations of one of the family's terms (empty: not tested)."""
        ...

    def report(self, problem: AdjustmentState, ctx: ReportContext) -> dict[str, Any]:
        """The family's report sections (name -> JSON-ready value) at the current parameters."""
        ...

    def without(self, job: Job, removals: list[tuple]) -> tuple[Job, list[dict[str, Any]]]:
        """``job`` without the removals of this family among ``removals`` (others are ignored),
        and the observations that had to go with them (``collateral``: report entries with
        kind, label, units and components)."""
        ...

    def removal_details(self, job: Job, removal: tuple) -> dict[str, Any]:
        """Extra fields of a removed observation's ``quality.rejected`` entry, read from ``job``
        (the job at the time of the removal)."""
        ...

    def flag(self, report: dict[str, Any], removed: list[dict[str, Any]]) -> None:
        """Mark, in the family's own report sections, the removed observations among ``removed``
        (``quality.rejected`` and non-identifiable entries; others are ignored)."""
        ...


class FamilyDefaults:
    """Defaults for the optional parts of :class:`ObservationFamily`: no initial values, nothing
    to re-linearise, nothing tested, no report section, nothing removable, nothing to flag."""

    def initialise(self, problem: AdjustmentState) -> None:
        return None

    def refresh(self, problem: AdjustmentState) -> float:
        return 0.0

    def groups(self, problem: AdjustmentState, labelled: Labelled) -> list[GroupSpec]:
        return []

    def report(self, problem: AdjustmentState, ctx: ReportContext) -> dict[str, Any]:
        return {}

    def without(self, job: Job, removals: list[tuple]) -> tuple[Job, list[dict[str, Any]]]:
        return job, []

    def removal_details(self, job: Job, removal: tuple) -> dict[str, Any]:
        return {}

    def flag(self, report: dict[str, Any], removed: list[dict[str, Any]]) -> None:
        return None


def per_row_groups(
    kind: str, n_rows: int, per: int, label: dict[str, Any], each: list[dict[str, Any]] | None, sigma: np.ndarray,
    units: str, components: list[str], sign: float, removal=None,
) -> list[GroupSpec]:
    """``n_rows // per`` groups of ``per`` consecutive rows, each labelled ``label`` updated by
    ``each[g]``; ``removal(label)`` gives a group's removal (None: not removable)."""
    out = []
    for g in range(n_rows // per):
        rows = g * per + np.arange(per)
        lab = dict(label)
        if each is not None and g < len(each):
            lab.update(each[g])
        out.append(GroupSpec(kind, rows, lab, np.asarray(sigma)[rows] if len(sigma) == n_rows else np.ones(per),
                             units, components, sign, None if removal is None else removal(lab)))
    return out
