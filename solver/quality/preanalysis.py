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
from solver.engine.initialize import initialise, nominal_attitude
from solver.engine.linalg import check_rank, covariance, linearise, schur
from solver.engine.packed_tables import current_tables, records
from solver.engine.validate import planning_problems, require_valid
from solver.errors import JobError, Problem
from solver.geometry.geodesy import ecef_to_geodetic
from solver.geometry.rpc import RPC
from solver.kernels import all_observation_blocks
from solver.observations.ephemeris import image_state
from solver.observations.line_data import lines_ecef
from solver.platforms import ANGLES, ELEMENTS, HELD, coef_index
from solver.quality.parameter_checks import high_correlations
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
from solver.schema.settings import JobSettings
from solver.state import AdjustmentState

PROJECTION_PASSES = 3  # re-project from the last projection (the line search starts at the observed line)


def _extent(job: Job, image_id: str) -> tuple[float | None, float | None]:
    """(lines, columns) of an image: its camera's, or for an RPC image the RPC's domain
    (line_off + line_scale, samp_off + samp_scale, our pixel convention, plus one)."""
    im = next(i for i in job.images if i.id == image_id)
    if im.rpc is not None:
        rpc = RPC.from_job(im.rpc.model_dump(mode="json"))
        return rpc.line_off + rpc.line_scale + 1.0, rpc.samp_off + rpc.samp_scale + 1.0
    cam = next(c for c in job.cameras if c.id == im.camera)
    return cam.lines, cam.columns


def _all_pairs(job: Job, placement: dict[tuple[str, str], tuple[float, float]]) -> list[dict[str, Any]]:
    out = []
    for im in job.images:
        lines, columns = _extent(job, im.id)
        for p in job.points:
            line, col = placement.get((im.id, p.id), ((lines or 1) / 2.0, (columns or 1) / 2.0))
            out.append({"image": im.id, "point": p.id, "line": line, "column": col, "sigma_px": 1.0})
    return out


def lgs_vertical_attitudes(problem: AdjustmentState, images: list[int]) -> None:
    """Set the nominal attitude of position-rotation models on ``images`` along the LGS vertical
    of the scene centre (in place), instead of the platform's own vertical that the initial
    values take (:func:`solver.blocks.platform_values.nominal_attitude`): a plan may have been
    drawn either way, and the variant that sees more planned points is kept per image
    (:func:`plan_observations`). Orbit-attitude and pass models are relative to the orbital frame
    already; images with ``initial`` or ``approx_state.attitude_deg`` angles, and models that
    hold an angle (which keep the LGS vertical anyway), are left alone."""
    for i in images:
        img = problem.images[i]
        im_doc = problem.job.images[i]
        if img.model.kind.attitude_in_orbital_frame:
            continue
        state = image_state(im_doc, JobSettings.of(problem.job).blocks.ephemeris)
        if state is None or state.attitude_deg is not None or set(im_doc.initial) & {"omega", "phi", "kappa"}:
            continue
        orders = img.model.effective_orders(img.options)
        if any(orders[ELEMENTS.index(e)] == HELD for e in ANGLES):
            continue
        angles = nominal_attitude(img, problem.frame, np.array(state.velocity_ecef_m_s, dtype=float))
        for e, v in zip(ANGLES, angles):
            img.base[coef_index(e, 0)] = v
        img.params[:] = img.base[img.free_idx]


def _projections(job: Job, level: bool) -> tuple[dict[tuple[str, str], tuple[float, float]], dict[tuple[str, str], bool]]:
    """Projections of every planned point into every image with the initial orientation (LGS
    nominal attitude, or levelled to the platform's vertical), and whether each is inside."""
    # orientation from the approximate states alone: every point as a check point (no control
    # resection, nothing estimated)
    points = [p.model_copy(update={"role": "check"}) for p in job.points]
    placement: dict[tuple[str, str], tuple[float, float]] = {}
    inside: dict[tuple[str, str], bool] = {}
    for _ in range(PROJECTION_PASSES):
        doc = job.model_copy(update={"points": points, "observations": [], "lines": []})
        doc = Job.model_validate({**doc.model_dump(), "observations": _all_pairs(job, placement)})
        problem = build_problem(doc)
        initialise(problem)  # levelled nominal attitudes (no control here: every point a check point)
        if not level:
            lgs_vertical_attitudes(problem, list(range(len(problem.images))))
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
            lines, columns = _extent(job, im.id)
            line = float(obs.oc[k, 0] - res[k, 0] * obs.oc[k, 2])
            col = float(obs.oc[k, 1] - res[k, 1] * obs.oc[k, 2])
            key = (im.id, problem.points[obs.pt[k]].id)
            placement[key] = (line, col)
            inside[key] = bool(
                ok[k]
                and math.isfinite(line)
                and math.isfinite(col)
                and 0.0 <= col <= (columns - 1 if columns else math.inf)
                and (0.0 <= line <= lines - 1 if lines else True)
            )
    return placement, inside


def _line_samples(job: Job, n: int) -> tuple[list[dict[str, Any]], dict[str, list[str]]]:
    """``n`` ground points evenly spaced between the endpoints of every control line (ECEF
    straight segment; geodetic EPSG:4979 coordinates), as temporary check points to project,
    and their ids per line."""
    ecef = lines_ecef(job)
    points: list[dict[str, Any]] = []
    ids: dict[str, list[str]] = {}
    for k, gl in enumerate(job.lines):
        if gl.role != "control" or gl.id not in ecef:
            continue
        e = ecef[gl.id]
        xyz = e[0] + np.linspace(0.0, 1.0, n)[:, None] * (e[1] - e[0])
        ids[gl.id] = [f"line {k} sample {j}" for j in range(n)]
        for pid, g in zip(ids[gl.id], ecef_to_geodetic(xyz)):
            points.append({"id": pid, "role": "check", "coordinates": [float(x) for x in g], "crs": "EPSG:4979"})
    return points, ids


def plan_observations(job: Job) -> tuple[list[dict[str, Any]], set[str], dict[str, list[dict[str, Any]]]]:
    """The image observations of the planned points: their projections with the initial
    orientation that fall inside the images (JSON-ready, ``sigma_px`` of ``options.preanalysis``),
    the images whose nominal attitude stays levelled to the platform's vertical (per image, the
    variant that sees more planned points; the others take :func:`lgs_vertical_attitudes`), and
    per control line its planned image
    observations (``options.preanalysis.line_points`` points evenly spaced between its
    endpoints, projected; an image sees the line where at least two of them fall inside)."""
    missing = planning_problems(job)
    if missing:
        raise JobError(missing)
    pre = JobSettings.of(job).procedures.preanalysis
    sigma = pre.sigma_px if pre is not None else 0.5
    samples, sample_ids = _line_samples(job, pre.line_points if pre is not None else 8)
    ext = job
    if samples:
        ext = Job.model_validate({**job.model_dump(), "points": [*job.model_dump()["points"], *samples]})
    flat = _projections(ext, level=False)
    tilted = _projections(ext, level=True)
    levelled: set[str] = set()
    out = []
    lines: dict[str, list[dict[str, Any]]] = {}
    for im in job.images:
        n_flat = sum(v for (i, _p), v in flat[1].items() if i == im.id)
        n_tilted = sum(v for (i, _p), v in tilted[1].items() if i == im.id)
        placement, inside = tilted if n_tilted >= n_flat else flat
        if n_tilted >= n_flat:
            levelled.add(im.id)
        for p in job.points:
            if inside[(im.id, p.id)]:
                line, col = placement[(im.id, p.id)]
                out.append({"image": im.id, "point": p.id, "line": line, "column": col, "sigma_px": sigma})
        for line_id, ids in sample_ids.items():
            seen = [placement[(im.id, pid)] for pid in ids if inside[(im.id, pid)]]
            if len(seen) >= 2:
                lines.setdefault(line_id, []).append(
                    {"image": im.id, "points": [{"line": a, "column": b} for a, b in seen], "sigma_px": sigma}
                )
    return out, levelled, lines


def preanalyse(job: Job) -> dict[str, Any]:
    """The pre-analysis report (docs/report-contract.md, ``kind: "preanalysis"``)."""
    planned, levelled, planned_lines = plan_observations(job)
    dump = job.model_dump()
    for gl in dump["lines"]:
        gl["observations"] = planned_lines.get(gl["id"], []) if gl["role"] == "control" else []
    doc = Job.model_validate({**dump, "observations": planned})
    require_valid(doc)
    problem = build_problem(doc)
    initialise(problem)
    gcp = np.array([problem.points[k].role == "gcp" for k in problem.obs.pt], dtype=bool)
    flat = [
        im.index for im in problem.images if im.id not in levelled and not np.any(gcp & (problem.obs.img == im.index))
    ]
    lgs_vertical_attitudes(problem, flat)
    if flat:
        from solver.engine.initialize import intersect_estimated_points

        intersect_estimated_points(problem)
    for p in problem.points:  # at the planned positions (the intersection of consistent rays)
        if p.estimated and p.known_lgs is not None and p.sigma_m is None:
            p.xyz = p.known_lgs.copy()
    lin = linearise(problem)
    parts = schur(lin, problem)
    names = parameter_names(problem)
    rank = check_rank(parts, names)
    if rank.deficient or parts.point_singular.any():
        raise JobError(
            Problem(
                "rank_deficient",
                "the planned control layout leaves these parameters undetermined: "
                + (", ".join(n for n, _ in rank.null_parameters) or "(points seen in one image only)"),
                ("points",),
                {"parameters": [n for n, _ in rank.null_parameters]},
            )
        )
    cov = covariance(lin, parts, problem)
    var = JobSettings.of(job).statistics.sigma0_apriori**2
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
            "sigma0_apriori": JobSettings.of(job).statistics.sigma0_apriori,
            "n_planned_image_points": len(planned),
            "n_planned_line_points": sum(len(o["points"]) for obs in planned_lines.values() for o in obs),
            "condition": rank.condition if np.isfinite(rank.condition) else None,
        },
        "images": [{"id": im.id, "model": im.model.name, "n_observations": int(np.sum(obs.img == im.index))} for im in problem.images],
        "parameters": [{"name": n, "sigma": float(s)} for n, s in zip(names, s_img)],
        "checkpoints": {"n": len(checks), "points": checks, "predicted_rmse_m": predicted},
        "points": ground,
        "quality": {"warnings": high_correlations(cov.images, names, JobSettings.of(job).statistics.quality_warnings.correlation)},
        "observations": planned,
        "lines": [
            {"id": gl.id, "images": [o["image"] for o in planned_lines.get(gl.id, [])],
             "n_points": sum(len(o["points"]) for o in planned_lines.get(gl.id, []))}
            for gl in job.lines if gl.role == "control"
        ],
    }
