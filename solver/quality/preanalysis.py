"""Pre-analysis (network design): predicted precision of a planned block before anything is
measured.

Input: a job whose points carry planned coordinates (control ``gcp``, ``check`` and ``tie``
points alike) and whose images carry their approximate orientation (``approx_state`` or an
``ephemeris``, ``first_line_time_s``, the model and its options). Image observations are not
needed (any given are ignored): every planned point is projected into every image with the
initial orientation, and the projections that fall inside the image (lines 0..lines-1 when the
camera gives ``lines``, columns 0..columns-1) become the planned observations, each with
``options.preanalysis.sigma_px``. The adjustment's normal matrix is then formed at those
(consistent, zero-residual) values and inverted: the a-priori precision of the orientation,
the tie and weighted control points and, by :mod:`solver.quality.precision`, the check points
(variance factor ``sigma0_apriori^2``: nothing is measured, nothing estimates it).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from solver.engine.assemble import build_problem, parameter_names
from solver.engine.initialize import initialise
from solver.engine.linalg import check_rank, covariance, linearise, schur
from solver.engine.tables import current_tables, records
from solver.engine.validate import require_valid
from solver.errors import JobError
from solver.errors import Problem as JobProblem
from solver.kernels import all_observation_blocks
from solver.quality.parsimony import high_correlations
from solver.quality.precision import (
    block_width,
    error_ellipse,
    intersection_cofactor,
    ray_blocks,
    rmse_summary,
    sigmas_enu,
    survey_covariance,
)
from solver.schema.job import Job

PROJECTION_PASSES = 3  # re-project from the last projection (the line search starts at the observed line)


def _all_pairs(job: Job, placement: dict[tuple[str, str], tuple[float, float]]) -> list[dict[str, Any]]:
    cams = {c.id: c for c in job.cameras}
    out = []
    for im in job.images:
        cam = cams[im.camera]
        for p in job.points:
            line, col = placement.get((im.id, p.id), ((cam.lines or 1) / 2.0, (cam.columns or 1) / 2.0))
            out.append({"image": im.id, "point": p.id, "line": line, "column": col, "sigma_px": 1.0})
    return out


def plan_observations(job: Job) -> list[dict[str, Any]]:
    """The image observations of the planned points: their projections with the initial
    orientation that fall inside the images (JSON-ready, ``sigma_px`` of ``options.preanalysis``)."""
    missing = [
        JobProblem("planned_point_without_coordinates", f"point {p.id!r}: a pre-analysis needs the planned coordinates of every point", ("points", i, "coordinates"))
        for i, p in enumerate(job.points)
        if p.coordinates is None
    ]
    if missing:
        raise JobError(missing)
    sigma = job.options.preanalysis.sigma_px if job.options.preanalysis is not None else 0.5
    # orientation from the approximate states alone: every point as a check point (no control
    # resection, nothing estimated)
    points = [p.model_copy(update={"role": "check"}) for p in job.points]
    placement: dict[tuple[str, str], tuple[float, float]] = {}
    inside: dict[tuple[str, str], bool] = {}
    for _ in range(PROJECTION_PASSES):
        doc = job.model_copy(update={"points": points, "observations": [], "lines": []})
        doc = Job.model_validate({**doc.model_dump(), "observations": _all_pairs(job, placement)})
        problem = build_problem(doc)
        initialise(problem)
        obs = problem.obs
        rows = np.arange(len(obs.pt))
        img_tab, cam_tab, img_p, cam_p = current_tables(problem)
        pts = np.ascontiguousarray(np.array([p.known_lgs for p in problem.points], dtype=float))
        zeros_col = np.zeros(len(problem.images), dtype=np.int64)
        res, _jf, _fc, _jp, ok = all_observation_blocks(
            records(problem, rows), img_tab, cam_tab, img_p, cam_p, pts, obs.pt, np.zeros(len(pts), dtype=np.bool_),
            zeros_col, np.zeros(max(len(problem.cameras), 1), dtype=np.int64),
            np.zeros(max(len(problem.passes), 1), dtype=np.int64), block_width(problem),
        )
        for k in rows:
            im = problem.images[obs.img[k]]
            cam = im.camera
            line = float(obs.oc[k, 0] - res[k, 0] * obs.oc[k, 2])
            col = float(obs.oc[k, 1] - res[k, 1] * obs.oc[k, 2])
            key = (im.id, problem.points[obs.pt[k]].id)
            placement[key] = (line, col)
            inside[key] = bool(
                ok[k]
                and math.isfinite(line)
                and math.isfinite(col)
                and 0.0 <= col <= (cam.columns - 1 if cam.columns else math.inf)
                and (0.0 <= line <= cam.lines - 1 if cam.lines else True)
            )
    return [
        {"image": im_id, "point": pid, "line": placement[(im_id, pid)][0], "column": placement[(im_id, pid)][1], "sigma_px": sigma}
        for (im_id, pid), good in inside.items()
        if good
    ]


def preanalyse(job: Job) -> dict[str, Any]:
    """The pre-analysis report (docs/report-contract.md, ``kind: "preanalysis"``)."""
    planned = plan_observations(job)
    doc = Job.model_validate({**job.model_dump(), "observations": planned})
    require_valid(doc)
    problem = build_problem(doc)
    initialise(problem)
    for p in problem.points:  # at the planned positions (the intersection of consistent rays)
        if p.estimated and p.known_lgs is not None and p.sigma_m is None:
            p.xyz = p.known_lgs.copy()
    lin = linearise(problem)
    parts = schur(lin, problem)
    names = parameter_names(problem)
    rank = check_rank(parts, names)
    if rank.deficient or parts.point_singular.any():
        raise JobError(
            JobProblem(
                "rank_deficient",
                "the planned control layout leaves these parameters undetermined: "
                + (", ".join(n for n, _ in rank.null_parameters) or "(points seen in one image only)"),
                ("points",),
                {"parameters": [n for n, _ in rank.null_parameters]},
            )
        )
    cov = covariance(lin, parts, problem)
    var = job.options.sigma0_apriori**2
    n_obs = len(lin.residuals)
    lay = lin.layout
    tables = current_tables(problem)
    obs = problem.obs
    checks, covs, axes_of, discs = [], [], [], []
    ground = []
    for p in problem.points:
        rows = np.flatnonzero(obs.pt == p.index)
        images = [problem.images[i].id for i in obs.img[rows]]
        if p.role == "check" and p.known_lgs is not None:
            axes = (0, 1, 2) if len(rows) > 1 else (0, 1)
            if len(rows) == 0:
                checks.append({"id": p.id, "images": [], "planned_lgs_m": [float(x) for x in p.known_lgs], "sigma_m": None, "error_ellipse": None})
                continue
            blocks = ray_blocks(problem, lay, rows, p.known_lgs, tables)
            q = intersection_cofactor(blocks, cov.images, axes)
            c = None if q is None else var * q + survey_covariance(p.sigma_m, blocks, axes)
            checks.append(
                {
                    "id": p.id,
                    "images": images,
                    "method": "intersection" if len(axes) == 3 else "mono",
                    "planned_lgs_m": [float(x) for x in p.known_lgs],
                    "sigma_m": None if c is None else {**sigmas_enu(c), **({"u": None} if 2 not in axes else {})},
                    "error_ellipse": None if c is None else error_ellipse(c[:2, :2]),
                }
            )
            if c is not None:
                covs.append(c)
                axes_of.append(axes)
                discs.append(np.zeros(3))
        elif p.estimated:
            c = var * cov.points[p.index]
            ground.append(
                {
                    "id": p.id,
                    "role": p.role,
                    "images": images,
                    "planned_lgs_m": [float(x) for x in p.xyz],
                    "sigma_m": sigmas_enu(c),
                    "error_ellipse": error_ellipse(c[:2, :2]),
                }
            )
        else:
            ground.append({"id": p.id, "role": p.role, "images": images, "planned_lgs_m": [float(x) for x in p.known_lgs], "sigma_m": None, "error_ellipse": None})
    predicted = rmse_summary(discs, covs, axes_of)["predicted_rmse_m"] if covs else None
    s_img = np.sqrt(np.clip(np.diag(cov.images), 0.0, None) * var)
    return {
        "kind": "preanalysis",
        "job_name": job.name,
        "frames": {"lgs": problem.frame.to_dict(), "ecef": "EPSG:4978"},
        "adjustment": {
            "n_observations": n_obs,
            "n_unknowns": lay.n_params,
            "dof": n_obs - lay.n_params,
            "sigma0_apriori": job.options.sigma0_apriori,
            "n_planned_image_points": len(planned),
            "condition": rank.condition if np.isfinite(rank.condition) else None,
        },
        "images": [{"id": im.id, "model": im.model.name, "n_observations": int(np.sum(obs.img == im.index))} for im in problem.images],
        "parameters": [{"name": n, "sigma": float(s)} for n, s in zip(names, s_img)],
        "checkpoints": {"n": len(checks), "points": checks, "predicted_rmse_m": predicted},
        "points": ground,
        "quality": {"warnings": high_correlations(cov.images, names, job.options.quality_warnings.correlation)},
        "observations": planned,
    }
