"""The ground points as parameter blocks (kind ``point``, eliminated).

The points are the core of the adjustment (:mod:`solver.engine.assemble` builds them with the
images; the report's ``tie_points`` and ``control_points`` describe them): an estimated point
(a tie point, or a control point weighted by its survey, :class:`solver.schema.settings.BlockConfig`
``control``) is a 3-parameter block of LGS coordinates (m), eliminated (Schur) before the
reduced system is solved and laid out after every other kind. Terms may act on a point (a
family labels them ``point`` with the point's index): its normal block takes them, and their
tests share the point's reliability block with its rays.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from solver.blocks.kind import BlockDefaults

if TYPE_CHECKING:  # pragma: no cover
    from solver.schema.settings import BlockConfig
    from solver.state import AdjustmentState, PointState


class PointKind(BlockDefaults):
    """Every ground point, in point order (a fixed point has no free parameter)."""

    name = "point"
    eliminated = True

    def build(self, problem: "AdjustmentState", config: "BlockConfig") -> list["PointState"]:
        return problem.points

    def blocks(self, problem: "AdjustmentState") -> list["PointState"]:
        return problem.points


KIND = PointKind()
