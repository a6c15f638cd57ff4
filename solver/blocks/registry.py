"""The parameter-block kinds, in the order of the columns (:mod:`solver.blocks.kind`): the one
place where block kinds are enumerated. A new kind is its module (a :class:`BlockKind`) and one
line here; its observations are a family of :mod:`solver.observations.registry` whose terms
are labelled with the kind's name.

The stages walk :data:`BLOCK_KINDS`: validation counts and checks (``check``), assembly builds
(``build``) into ``problem.blocks``, initialisation (``initialise``), the tables and the solve
refresh (``refresh``), the layout, the Ceres problem and the covariance lay out the blocks, the
report names (``names``) and reports them (``report``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from solver.blocks import cameras, passes, platform, points
from solver.blocks.kind import BlockKind

if TYPE_CHECKING:  # pragma: no cover
    from solver.schema.settings import BlockConfig
    from solver.state import AdjustmentState

BLOCK_KINDS: tuple[BlockKind, ...] = (
    platform.KIND,  # image: the images' platform parameters (one block per image or shared attitude)
    cameras.KIND,  # camera: the cameras' free interior orientation
    passes.KIND,  # pass: the passes' orbit states
    points.KIND,  # point: the ground points (eliminated; laid out last)
)


def kind(name: str) -> BlockKind:
    """The registered kind called ``name``."""
    for k in BLOCK_KINDS:
        if k.name == name:
            return k
    raise KeyError(f"no parameter-block kind {name!r}")


def block_of(problem: AdjustmentState, name: str, index: int) -> Any:
    """The block that index ``index`` of kind ``name`` names (a term's label: :meth:`BlockKind.addressed`)."""
    return kind(name).addressed(problem)[index]


def build(problem: AdjustmentState, config: BlockConfig) -> None:
    """Every kind's blocks into ``problem.blocks``, in the registry's order."""
    for k in BLOCK_KINDS:
        problem.blocks[k.name] = k.build(problem, config)


def refresh(problem: AdjustmentState) -> None:
    """What every kind derives from its parameters, brought up to date (the pass trajectories)."""
    for k in BLOCK_KINDS:
        k.refresh(problem)


def names(problem: AdjustmentState) -> list[str]:
    """The names of the free parameters of every block laid out before the eliminated ones
    (``owner/name``), in column order."""
    return [n for k in BLOCK_KINDS if not k.eliminated for n in k.names(problem)]
