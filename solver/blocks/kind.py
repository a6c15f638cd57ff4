"""The interface of a parameter-block kind (listed in :mod:`solver.blocks.registry`).

A parameter block is one array of unknowns that Ceres moves as a whole (an image's platform
parameters, a pass's orbit state, a camera's interior orientation, a ground point, ...). A
*kind* of block says, in one module, how its blocks are

* counted and checked at validation (:meth:`BlockKind.check`: problems and unknowns),
* assembled from the job (:meth:`BlockKind.build`, reading :class:`solver.schema.settings.BlockConfig`),
* initialised (:meth:`BlockKind.initialise`), refreshed after their parameters moved
  (:meth:`BlockKind.refresh`), named (:meth:`BlockKind.names`) and
* reported (:meth:`BlockKind.report`).

The adjustment state holds the blocks by kind (``problem.blocks[kind.name]``); the layout of
the unknowns (:func:`solver.engine.linalg.layout`), the Ceres problem
(:mod:`solver.engine.backend`), the residual blocks and the report walk the registry, in its
order: that order is the order of the columns. A block shared by several owners (one attitude
block for the images of one camera on a pass) is one block object that lists them; nothing
recognises sharing by the identity of arrays.

The observation families' terms act on blocks: a term is labelled with a kind's name and an
index (:class:`solver.observations.family.Labelled`), which the kind turns into the block
(:meth:`BlockKind.addressed`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from solver.errors import Problem
    from solver.schema.job import Job
    from solver.schema.settings import BlockConfig
    from solver.state import AdjustmentState


class ParameterBlock(Protocol):
    """One block: its position in its kind's list and the array Ceres moves (C-contiguous,
    ``nfree`` values, in the block's internal units)."""

    index: int
    params: np.ndarray

    @property
    def nfree(self) -> int: ...


class BlockKind(Protocol):
    """One kind of parameter block.

    ``name``: the key of ``problem.blocks`` and of the terms' labels. ``eliminated``: the
    kind's blocks are eliminated (Schur) before the others are solved for, and laid out after
    them (the ground points); every other kind is in the reduced system, in registry order.
    """

    name: str
    eliminated: bool

    def check(self, job: Job) -> tuple[list[Problem], int]:
        """Validation: what about the kind's blocks cannot be used as asked (located problems)
        and how many unknowns its blocks add (nothing that its problems make uncountable)."""
        ...

    def build(self, problem: AdjustmentState, config: BlockConfig) -> list[Any]:
        """The kind's blocks for an assembled problem (its images, points and observations
        built), with zero or the job's values; ``config`` says which are estimated."""
        ...

    def blocks(self, problem: AdjustmentState) -> list[Any]:
        """The kind's blocks, in column order (default: ``problem.blocks[name]``)."""
        ...

    def addressed(self, problem: AdjustmentState) -> list[Any]:
        """The block that each index of the kind's term labels names (default: :meth:`blocks`;
        the image kind: each image's platform block, shared blocks repeated)."""
        ...

    def initialise(self, problem: AdjustmentState, states: dict[int, Any]) -> list[Problem]:
        """Initial values, after the images' platform parameters (``states``: each image's
        approximate state, image index -> ApproxState or None); the problems that stop it."""
        ...

    def refresh(self, problem: AdjustmentState) -> None:
        """Bring what the kind derives from its parameters up to date after they moved (the
        pass trajectories); called before the tables are built and after a solve."""
        ...

    def names(self, problem: AdjustmentState) -> list[str]:
        """The names of the free parameters of all its blocks, in column order (``owner/name``)."""
        ...

    def report(self, problem: AdjustmentState, ctx: Any) -> dict[str, Any]:
        """The kind's report sections (name -> JSON-ready value) at the current parameters;
        ``ctx``: :class:`solver.observations.family.ReportContext` (covariance, layout, variance factor)."""
        ...


class BlockDefaults:
    """Defaults for the optional parts of :class:`BlockKind`: nothing to check or count, the
    blocks as stored, nothing to initialise or refresh, no names, no report section."""

    eliminated = False

    def check(self, job: Job) -> tuple[list[Problem], int]:
        return [], 0

    def blocks(self, problem: AdjustmentState) -> list[Any]:
        return problem.blocks.get(self.name, [])  # type: ignore[attr-defined]

    def addressed(self, problem: AdjustmentState) -> list[Any]:
        return self.blocks(problem)

    def initialise(self, problem: AdjustmentState, states: dict[int, Any]) -> list[Problem]:
        return []

    def refresh(self, problem: AdjustmentState) -> None:
        return None

    def names(self, problem: AdjustmentState) -> list[str]:
        return []

    def report(self, problem: AdjustmentState, ctx: Any) -> dict[str, Any]:
        return {}
