"""Initial values: every block kind's (:mod:`solver.blocks.registry`), the images' platform
blocks first (:mod:`solver.blocks.platform_values`: platform state from the header/ephemeris,
attitude by a closed-form resection), then what builds on them (the pass states).

1.-2. The images' platform blocks, then the pass states (the block kinds' ``initialise``).
   Then each observation family refines what its observations determine
   (:meth:`solver.observations.family.ObservationFamily.initialise`): measured attitude fits the
   angles' polynomials to the weighted samples (an agile satellite looks 10-30 degrees off the
   orbital frame, and tie rays started from the nominal attitude miss each other by kilometres).
3. ``initial`` values given in the job override everything (report units).
4. Tie points: least-squares intersection of their rays.
"""

from __future__ import annotations

import numpy as np

from solver.blocks import registry as blocks
from solver.blocks.platform_values import angles_from_matrix, apply_initial, nominal_attitude, rotating_frame_acceleration
from solver.engine.native import in_threads
from solver.errors import JobError, Problem
from solver.kernels import intersect_all
from solver.observations import registry
from solver.observations.ephemeris import image_state
from solver.schema.settings import JobSettings
from solver.state import AdjustmentState, grouped

# kept importable from here (tests, bench/ceres_reference): the platform blocks' initial values
__all__ = ["angles_from_matrix", "initialise", "intersect_estimated_points", "nominal_attitude", "rotating_frame_acceleration"]
_nominal_attitude = nominal_attitude
_rotating_frame_acceleration = rotating_frame_acceleration


def initialise(problem: AdjustmentState) -> None:
    """Fill every block's parameters and every estimated point's coordinates (in place): the
    block kinds in the registry's order (the images' platform blocks, then what builds on them:
    the pass states), the families' refinements, the job's own initial values, the tie points."""
    job = problem.job
    ephemeris = JobSettings.of(job).blocks.ephemeris
    states = {img.index: image_state(doc, ephemeris) for img, doc in zip(problem.images, job.images)}  # header or ephemeris
    issues: list[Problem] = []
    for kind in blocks.BLOCK_KINDS:  # the platform blocks, then e.g. the pass states from the image states nearest their epochs
        issues += kind.initialise(problem, states)
    if issues:
        raise JobError(issues)
    for family in registry.FAMILIES:  # e.g. the attitude polynomials fitted to measured attitude
        family.initialise(problem)
    for img in problem.images:  # the job's own initial values win
        if img.initial:
            apply_initial(img)
            img.params[:] = img.base[img.free_idx]
    intersect_estimated_points(problem)


def intersect_estimated_points(problem: AdjustmentState) -> None:
    """Tie points (estimated points without survey) by least-squares intersection of their rays."""
    obs = problem.obs
    which = np.array([p.index for p in problem.points if p.estimated and p.known_lgs is None], dtype=np.int64)
    if len(which) == 0:
        return
    kinds = np.array([im.kind for im in problem.images], dtype=np.int64)
    coefs = np.ascontiguousarray([im.coef() for im in problem.images])
    kcs = np.zeros((len(problem.images), max(len(im.kc) for im in problem.images)))
    for im in problem.images:  # pass images carry longer kc (their trajectory segment)
        kcs[im.index, : len(im.kc)] = im.kc
    order, bounds = grouped(obs.pt, len(problem.points))
    xyz = np.empty((len(which), 3))

    def fill(lo: int, hi: int) -> None:
        xyz[lo:hi] = intersect_all(kinds, coefs, kcs, obs.img, obs.oc, order, bounds, which[lo:hi])

    in_threads(fill, len(which))
    xyz = np.nan_to_num(xyz)  # NaN (fewer than two rays) is reported by validation; keep a finite start
    for q, i in enumerate(which):
        problem.points[i].xyz = xyz[q].copy()  # its own contiguous array: a Ceres parameter block
