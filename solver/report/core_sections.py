"""The report's sections of the adjustment's core (images, correlations, observations, tie and
control points): what each says is documented in docs/report-contract.md; they are listed, with
the others, in :mod:`solver.report.sections`."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from solver.blocks.platform import attitude_groups
from solver.engine.assemble import parameter_names
from solver.engine.linalg import Covariance
from solver.geometry.geodesy import ecef_to_geodetic
from solver.kernels import platform_state
from solver.kernels.rpc import RPC_START, rpc_image_to_ground
from solver.observations.ephemeris import line0_state_ecef
from solver.quality.parameter_checks import correlated_pairs
from solver.quality.precision import error_ellipses
from solver.schema.settings import JobSettings
from solver.state import AdjustmentState, rows_by_image


def _state_line0(problem: AdjustmentState, index: int) -> dict[str, list[float]]:
    """The adjusted perspective-centre position and velocity at line 0 (ECEF), every model."""
    r, v = line0_state_ecef(problem, index)
    return {"position_ecef_m": [float(x) for x in r], "velocity_ecef_m_s": [float(x) for x in v]}


def rpc_gsd_m(coef: np.ndarray, kc: np.ndarray, oc: np.ndarray) -> float | None:
    """Mean ground distance (m) between the RPC's ground points of adjacent columns at the RPC's
    mean height, over the observed pixels ``oc`` (an RPC image's ground sample distance)."""
    h = kc[RPC_START + 4]
    d = []
    for row in oc:
        ok1, p1 = rpc_image_to_ground(coef, kc, row[0], row[1], h)
        ok2, p2 = rpc_image_to_ground(coef, kc, row[0], row[1] + 1.0, h)
        if ok1 and ok2:
            d.append(float(np.linalg.norm(p2 - p1)))
    return float(np.mean(d)) if d else None


def images_report(problem: AdjustmentState, lin, cov: Covariance | None, var_factor: float):
    out = []
    gsds = []
    lay = lin.layout
    res = lin.res_obs.ravel()
    obs = problem.obs
    sel = lin.obs_sel
    groups = attitude_groups(problem)
    # each image's observations, once for all images (a mask per image is images x observations)
    sel_of = rows_by_image(obs.img[sel], len(problem.images))
    all_of = rows_by_image(obs.img, len(problem.images))
    sigma_sel = obs.oc[sel, 2]
    for img in problem.images:
        specs = img.model.parameters(img.options)
        c = img.coef()
        c0 = lay.img_col[img.index]
        block = None
        if cov is not None:
            block = cov.images[c0 : c0 + img.nfree, c0 : c0 + img.nfree] * var_factor
        scale = np.array([s.to_report for s in specs])
        params = []
        for k, s in enumerate(specs):
            sigma = float(math.sqrt(max(block[k, k], 0.0)) * abs(s.to_report)) if block is not None else None
            params.append(
                {"name": s.name, "value": float(c[s.index] * s.to_report), "sigma": sigma, "unit": s.unit, "estimated": True}
            )
        mine = sel_of[img.index]
        sig = sigma_sel[mine]
        rl = res[2 * mine] * sig
        rc = res[2 * mine + 1] * sig
        rms = lambda v: float(np.sqrt(np.mean(v**2))) if len(v) else None  # noqa: E731
        if img.camera is None:  # RPC image: bias parameters only, no camera or platform state
            px = None
            gsd = rpc_gsd_m(c, img.kc, obs.oc[all_of[img.index][:200]])
        else:
            held = img.model.held_values_rad(img.options, img.camera.mounting_pitch_deg)
            for e, val in held.items():
                params.append({"name": e, "value": math.degrees(val), "sigma": None, "unit": "deg", "estimated": False})
            px = img.camera.pixel_mm
            # ground sample distance: range to the observed points x pixel / focal length
            ranges = []
            for k in all_of[img.index][:200]:
                s = platform_state(img.kind, c, img.kc, obs.oc[k, 0] * obs.oc[k, 8])[0]
                ranges.append(np.linalg.norm(problem.points[obs.pt[k]].xyz - s))
            gsd = float(np.mean(ranges) * px / img.camera.focal_mm) if ranges else None
        if gsd:
            gsds.append(gsd)
        out.append(
            {
                "id": img.id,
                "camera": img.camera.id if img.camera else None,
                "model": img.model.name,
                "frame": img.model.frame,
                "time_variable": img.model.time_variable,
                "parameters": params,
                "covariance": None
                if block is None
                else {"names": [s.name for s in specs], "matrix": (block * np.outer(scale, scale)).tolist()},
                "residual_rmse": {
                    "line_px": rms(rl),
                    "column_px": rms(rc),
                    "x_mm": None if rms(rl) is None or px is None else rms(rl) * px,
                    "y_mm": None if rms(rc) is None or px is None else rms(rc) * px,
                },
                "n_observations": int(len(mine)),
                "state_line0": _state_line0(problem, img.index) if img.camera else None,
                "pass": problem.passes[img.pass_index].id if img.pass_index >= 0 else None,
                "attitude_shared_with": groups.get(img.index),
                "gsd_m": gsd,
                "lines": img.camera.lines if img.camera else None,
                "columns": img.camera.columns if img.camera else None,
                "sensor": _sensor_origin(problem, img.index),
            }
        )
    return out, gsds


def _sensor_origin(problem: AdjustmentState, index: int) -> dict[str, Any] | None:
    """The job image's ``sensor`` (vendor metadata and what its reading did), as given."""
    origin = problem.job.images[index].sensor
    return None if origin is None else origin.model_dump(mode="json")


NEAR_SINGULAR_RHO = 0.9999


def creeping_warning(problem: AdjustmentState, cov: Covariance | None) -> str | None:
    """Why a solve that ran out of iterations crept: the parameter pairs that are correlated to
    |rho| >= NEAR_SINGULAR_RHO are nearly undetermined together, and Gauss-Newton moves along
    that valley a little each iteration (e.g. a focal-length correction against the flying
    height of per-image models)."""
    if cov is None or cov.images.size == 0:
        return None
    ii, jj, vals = correlated_pairs(cov.images, NEAR_SINGULAR_RHO, inclusive=True)
    if not len(vals):
        return None
    names = parameter_names(problem)
    top = np.argsort(-np.abs(vals))[:3]
    pairs = ", ".join(f"{names[ii[k]]} ~ {names[jj[k]]} (rho {vals[k]:+.5f})" for k in top)
    return (
        f"{len(vals)} parameter pair(s) are correlated beyond {NEAR_SINGULAR_RHO} ({pairs}): they are "
        "nearly undetermined together and the solve creeps along that direction; hold or drop one "
        "of them (for example a self-calibration parameter) or add control that separates them"
    )


def correlations(problem: AdjustmentState, cov: Covariance | None, threshold: float, limit: int = 2000) -> dict[str, Any]:
    out: dict[str, Any] = {"threshold": threshold, "pairs": []}
    if cov is None or cov.images.size == 0:
        return out
    names = parameter_names(problem)
    ii, jj, vals = correlated_pairs(cov.images, threshold)
    big = np.argsort(-np.abs(vals))[:limit]
    def kind(name: str) -> str:
        return "IOP" if name.startswith("camera:") else "EOP"

    out["pairs"] = [
        {"a": names[ii[k]], "b": names[jj[k]], "rho": float(vals[k]), "kinds": f"{kind(names[ii[k]])}-{kind(names[jj[k]])}"}
        for k in big
    ]
    out["truncated"] = bool(len(vals) > limit)
    return out


OBSERVATION_CHUNK = 65536
"""Observations converted to Python values at a time by :func:`observations_report`: the
temporary lists of a whole million-observation block (the columns as lists, the standardized
pairs) were about 0.2 GB above the report itself."""


def observations_report(problem: AdjustmentState, lin, cov: Covariance | None) -> list[dict[str, Any]]:
    """One entry per adjusted image observation: measured pixels, residuals (px) and, with a
    covariance, the standardized residuals (None where the redundancy is ~0). Computed in array
    passes over chunks of :data:`OBSERVATION_CHUNK`; the per-observation loop only builds the
    dictionaries."""
    obs = problem.obs
    sel = np.asarray(lin.obs_sel, dtype=np.int64)
    if len(sel) == 0:
        return []
    res = lin.res_obs.reshape(-1, 2)
    s0 = JobSettings.of(problem.job).statistics.sigma0_apriori
    leverage = None if cov is None or cov.leverage is None else np.asarray(cov.leverage, dtype=float).reshape(-1, 2)
    image_ids = [im.id for im in problem.images]
    point_ids = [p.id for p in problem.points]
    roles = [p.role for p in problem.points]
    out: list[dict[str, Any]] = []
    for lo in range(0, len(sel), OBSERVATION_CHUNK):
        part = sel[lo : lo + OBSERVATION_CHUNK]
        res_c = res[lo : lo + OBSERVATION_CHUNK]
        sig = obs.oc[part, 2]
        standardized: list[list[Any]] = [[None, None]] * len(part)
        if leverage is not None:
            r = 1.0 - leverage[lo : lo + OBSERVATION_CHUNK]
            with np.errstate(invalid="ignore", divide="ignore"):
                z = res_c / (s0 * np.sqrt(np.where(r > 1e-9, r, 1.0)))
            standardized = [[a if ra > 1e-9 else None, b if rb > 1e-9 else None] for (a, b), (ra, rb) in zip(z.tolist(), r.tolist())]
        for img, pt, line, column, sigma, rl, rc, (zl, zc) in zip(
            obs.img[part].tolist(),
            obs.pt[part].tolist(),
            obs.oc[part, 0].tolist(),
            obs.oc[part, 1].tolist(),
            sig.tolist(),
            (res_c[:, 0] * sig).tolist(),
            (res_c[:, 1] * sig).tolist(),
            standardized,
        ):
            out.append(
                {
                    "image": image_ids[img],
                    "point": point_ids[pt],
                    "role": roles[pt],
                    "line": line,
                    "column": column,
                    "sigma_px": sigma,
                    "residual_line_px": rl,
                    "residual_column_px": rc,
                    "standardized_line": zl,
                    "standardized_column": zc,
                }
            )
    return out


def points_report(problem: AdjustmentState, cov: Covariance | None, var_factor: float, role: str) -> list[dict[str, Any]]:
    pts = [p for p in problem.points if p.estimated and p.role == role]
    if not pts:
        return []
    xyz = np.array([p.xyz for p in pts])
    ecef = problem.frame.to_ecef(xyz)
    geo = ecef_to_geodetic(ecef)
    with_cov = [q for q, p in enumerate(pts) if cov is not None and p.index in cov.points]
    ellipses: list[Any] = [None] * len(pts)
    sigmas: list[Any] = [None] * len(pts)
    if with_cov:
        c = np.array([cov.points[pts[q].index] for q in with_cov]).reshape(-1, 3, 3) * var_factor
        for q, e in zip(with_cov, error_ellipses(c[:, :2, :2])):
            ellipses[q] = e
        for q, s in zip(with_cov, np.sqrt(np.maximum(np.diagonal(c, axis1=1, axis2=2), 0.0)).tolist()):
            sigmas[q] = s
    # bulk conversions to Python floats (one per array, not one per value)
    lgs_l, ecef_l, geo_l = xyz.tolist(), ecef.tolist(), geo.tolist()
    corrections: list[Any] = [None] * len(pts)
    if role == "gcp":
        known = [q for q, p in enumerate(pts) if p.known_lgs is not None]
        if known:
            diff = (xyz[known] - np.array([pts[q].known_lgs for q in known])).tolist()
            for q, d in zip(known, diff):
                corrections[q] = d
    out = []
    for q, p in enumerate(pts):
        g = geo_l[q]
        item = {
            "id": p.id,
            "lgs_m": lgs_l[q],
            "sigma_m": sigmas[q],
            "ecef_m": ecef_l[q],
            "lon_deg": g[0],
            "lat_deg": g[1],
            "height_m": g[2],
            "error_ellipse": ellipses[q],
        }
        if corrections[q] is not None:
            item["correction_m"] = corrections[q]
        out.append(item)
    return out
