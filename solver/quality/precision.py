"""Predicted precision of points computed from the adjusted orientation (check points, withheld
control points, planned points of a pre-analysis).

A point computed by intersection (or, seen in one image, by the ray through its known height)
from rays whose orientation ``f`` comes out of the adjustment has two independent error
sources: the noise of its own image coordinates (they never entered the adjustment) and the
error of the orientation. Linearised at the point (whitened residuals ``r`` of its rays,
Jacobians ``J_x`` wrt the point's free axes and ``F`` wrt the orientation parameters, both
of the whitened residuals)::

    N = J_x^T J_x,   G = N^-1 J_x^T
    Q_x = N^-1 + G F Q_ff F^T G^T           (cofactor, a-priori sigma0 = 1)
    Sigma_x = var_factor Q_x (+ the survey covariance of the known coordinates, for a
              discrepancy estimated - known)

``Q_ff`` is the orientation block of the inverse normal matrix (tie points eliminated:
:class:`solver.engine.linalg.Covariance` ``images``). Frames: the LGS of the report (east,
north, up at the centroid of the control points), metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from solver.engine.linalg import Layout
from solver.engine.packed_tables import current_tables, records
from solver.kernels import all_observation_blocks
from solver.quality.distributions import chi2_upper_quantile
from solver.state import AdjustmentState


@dataclass
class RayBlocks:
    """Whitened residuals and Jacobians of one point's rays (k rays, 2k rows)."""

    res: np.ndarray  # (2k,) whitened residuals (line, column interleaved)
    jx: np.ndarray  # (2k, 3) wrt the point's LGS coordinates
    f_cols: np.ndarray  # (m,) global orientation columns the rays touch
    jf: np.ndarray  # (2k, m) wrt those columns
    ok: bool


def block_width(problem: AdjustmentState) -> int:
    """Columns per observation row in the Jacobian blocks (as :func:`solver.engine.linalg.linearise`)."""
    return (
        max(im.nfree for im in problem.images)
        + max([c.nfree for c in problem.cameras] + [0])
        + (6 if problem.passes else 0)
    )


def ray_blocks(problem: AdjustmentState, lay: Layout, rows: np.ndarray, xyz_lgs_m: np.ndarray, tables=None) -> RayBlocks:
    """Residuals and Jacobians of the observations ``rows`` (indices in ``problem.obs``) of one
    point placed at ``xyz_lgs_m``, at the current orientation."""
    rows = np.asarray(rows, dtype=np.int64)
    img_tab, cam_tab, img_p, cam_p = tables if tables is not None else current_tables(problem)
    rec = records(problem, rows)
    zeros = np.zeros(len(rows), dtype=np.int64)
    pts = np.ascontiguousarray(np.asarray(xyz_lgs_m, dtype=float).reshape(1, 3))
    res, jf, fcol, jpt, ok = all_observation_blocks(
        rec, img_tab, cam_tab, img_p, cam_p, pts, zeros, np.ones(1, dtype=np.bool_),
        lay.img_col, lay.cam_col, lay.pass_col, block_width(problem),
    )
    cols = np.unique(fcol[fcol >= 0])
    where = {int(c): k for k, c in enumerate(cols)}
    dense = np.zeros((2 * len(rows), len(cols)))
    for i in range(len(rows)):
        for j in range(fcol.shape[1]):
            c = fcol[i, j]
            if c >= 0:
                dense[2 * i, where[int(c)]] += jf[i, 0, j]
                dense[2 * i + 1, where[int(c)]] += jf[i, 1, j]
    return RayBlocks(res.ravel(), jpt.reshape(-1, 3), cols, dense, bool(ok.all()))


def intersection_cofactor(blocks: RayBlocks, q_ff: np.ndarray | None, axes: tuple[int, ...] = (0, 1, 2)) -> np.ndarray | None:
    """Cofactor (a-priori sigma0 = 1, LGS, 3 x 3) of the point computed from its rays on the
    ``axes`` it is free along (mono: east, north; the up axis then has zero cofactor), the
    orientation with cofactor ``q_ff`` (full orientation matrix; None: orientation exact).
    None when the rays do not determine the point."""
    ax = list(axes)
    a = blocks.jx[:, ax]
    n = a.T @ a
    if np.linalg.matrix_rank(n, tol=1e-10 * max(np.abs(n).max(), 1e-300)) < len(ax):
        return None
    n_inv = np.linalg.inv(n)
    q = n_inv.copy()
    if q_ff is not None and len(blocks.f_cols):
        g = n_inv @ a.T
        gf = g @ blocks.jf
        q = q + gf @ q_ff[np.ix_(blocks.f_cols, blocks.f_cols)] @ gf.T
    out = np.zeros((3, 3))
    out[np.ix_(ax, ax)] = 0.5 * (q + q.T)
    return out


def error_ellipse(cov_en: np.ndarray) -> dict[str, float]:
    """Horizontal standard error ellipse of a 2 x 2 (east, north) covariance, m: semi-axes and
    the azimuth of the major axis (degrees clockwise from north)."""
    return error_ellipses(np.asarray(cov_en)[None])[0]


def error_ellipses(cov_en: np.ndarray) -> list[dict[str, float]]:
    """:func:`error_ellipse` of a stack (n, 2, 2) of covariances in one LAPACK call."""
    c = np.asarray(cov_en, dtype=float)
    if len(c) == 0:
        return []
    w, v = np.linalg.eigh(0.5 * (c + np.swapaxes(c, 1, 2)))
    az = np.degrees(np.arctan2(v[:, 0, 1], v[:, 1, 1])) % 180.0  # the major axis: column 1
    major = np.sqrt(np.maximum(w[:, 1], 0.0))
    minor = np.sqrt(np.maximum(w[:, 0], 0.0))
    return [  # Python floats from one conversion per array, not one per value
        {"semi_major_m": a, "semi_minor_m": b, "azimuth_deg": z} for a, b, z in zip(major.tolist(), minor.tolist(), az.tolist())
    ]


def sigmas_enu(cov: np.ndarray) -> dict[str, float]:
    """Standard deviations along east, north, up of a 3 x 3 LGS covariance, m."""
    d = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return {"e": float(d[0]), "n": float(d[1]), "u": float(d[2])}


def discrepancy_test(d: np.ndarray, cov: np.ndarray, axes: tuple[int, ...], alpha: float) -> dict[str, Any] | None:
    """Test of a discrepancy vector against its predicted covariance: ``T = d^T Sigma^-1 d`` on
    the point's free axes, chi-square with ``len(axes)`` degrees of freedom, rejected above the
    1 - alpha quantile."""
    ax = list(axes)
    s = cov[np.ix_(ax, ax)]
    try:
        t = float(d[ax] @ np.linalg.solve(s, d[ax]))
    except np.linalg.LinAlgError:
        return None
    crit = chi2_upper_quantile(alpha, len(ax))
    return {"statistic": t, "dof": len(ax), "critical": crit, "alpha": alpha, "passed": bool(t <= crit)}


def normalised(d: np.ndarray, cov: np.ndarray, axes: tuple[int, ...]) -> dict[str, float | None]:
    """Each axis' discrepancy divided by its predicted standard deviation (None off ``axes``)."""
    out: dict[str, float | None] = {}
    for k, name in enumerate(("e", "n", "u")):
        s = math.sqrt(max(cov[k, k], 0.0))
        out[name] = float(d[k] / s) if k in axes and s > 0 else None
    return out


def rmse_summary(disc: list[np.ndarray], covs: list[np.ndarray], axes_of: list[tuple[int, ...]]) -> dict[str, Any]:
    """Empirical RMSE, predicted RMSE (root mean of the predicted variances) and their ratio per
    axis, planimetric and 3-D (3-D over the points with all three axes), metres."""

    def rms(v: list[float]) -> float | None:
        return float(math.sqrt(np.mean(np.square(v)))) if v else None

    emp: dict[str, float | None] = {}
    pred: dict[str, float | None] = {}
    for k, name in enumerate(("e", "n", "u")):
        sel = [i for i, ax in enumerate(axes_of) if k in ax]
        emp[name] = rms([disc[i][k] for i in sel])
        pred[name] = float(math.sqrt(np.mean([covs[i][k, k] for i in sel]))) if sel else None
    full = [i for i, ax in enumerate(axes_of) if len(ax) == 3]
    for name, sel, ks in (("planimetric", list(range(len(disc))), (0, 1)), ("3d", full, (0, 1, 2))):
        emp[name] = float(math.sqrt(np.mean([sum(disc[i][k] ** 2 for k in ks) for i in sel]))) if sel else None
        pred[name] = float(math.sqrt(np.mean([sum(covs[i][k, k] for k in ks) for i in sel]))) if sel else None
    ratio = {k: (emp[k] / pred[k] if emp[k] is not None and pred[k] else None) for k in emp}
    return {"rmse_m": emp, "predicted_rmse_m": pred, "ratio": ratio}


def survey_covariance(sigma_m: np.ndarray | None, blocks: RayBlocks, axes: tuple[int, ...]) -> np.ndarray:
    """Covariance (LGS) that the known coordinates' survey errors add to a discrepancy
    estimated - known. On a free axis the survey variance adds directly; a mono point's known
    height moves it along its ray: its height error shifts east, north by the ray's horizontal
    slope (direction d: d_e / d_u, d_n / d_u per metre of height)."""
    out = np.zeros((3, 3))
    if sigma_m is None:
        return out
    var = np.asarray(sigma_m, dtype=float) ** 2
    for k in axes:
        out[k, k] += var[k]
    if 2 not in axes:
        # the ray direction is the null direction of the 2 x 3 Jacobian of a single ray
        _u, _s, vt = np.linalg.svd(blocks.jx[:2])
        d = vt[-1]
        if abs(d[2]) > 1e-12:
            slope = d[:2] / d[2]
            out[:2, :2] += np.outer(slope, slope) * var[2]
    return out


def checkpoint_precision(
    checkpoints: dict[str, Any], problem: AdjustmentState, lay: Layout, q_ff: np.ndarray | None, var_factor: float, alpha: float
) -> None:
    """Add to each check point of ``checkpoints`` (:func:`solver.report.checkpoints.compute_checkpoints`)
    its predicted standard deviations, error ellipse, normalised discrepancy and chi-square test,
    and to the section the predicted RMSE and the ratio empirical / predicted (in place)."""
    obs = problem.obs
    by_id = {p.id: p for p in problem.points}
    tables = current_tables(problem)
    discs, covs, axes_of = [], [], []
    for item in checkpoints["points"]:
        p = by_id[item["id"]]
        rows = np.flatnonzero(obs.pt == p.index)
        axes = (0, 1) if item["method"] == "mono" else (0, 1, 2)
        blocks = ray_blocks(problem, lay, rows, np.array(item["estimated_lgs_m"]), tables)
        q = intersection_cofactor(blocks, q_ff, axes) if q_ff is not None else None
        if q is None:
            item.update({"sigma_m": None, "error_ellipse": None, "normalised_discrepancy": None, "discrepancy_test": None})
            continue
        cov = var_factor * q + survey_covariance(p.sigma_m, blocks, axes)
        d = np.array(item["estimated_lgs_m"]) - np.array(item["known_lgs_m"])
        item["sigma_m"] = {**sigmas_enu(cov), **({"u": None} if 2 not in axes else {})}
        item["error_ellipse"] = error_ellipse(cov[:2, :2])
        item["normalised_discrepancy"] = normalised(d, cov, axes)
        item["discrepancy_test"] = discrepancy_test(d, cov, axes, alpha)
        discs.append(d)
        covs.append(cov)
        axes_of.append(axes)
    summary = rmse_summary(discs, covs, axes_of) if discs else None
    checkpoints["rmse_m"]["3d"] = summary["rmse_m"]["3d"] if summary else None
    checkpoints["predicted_rmse_m"] = summary["predicted_rmse_m"] if summary else None
    checkpoints["rmse_ratio"] = summary["ratio"] if summary else None
    tests = [it["discrepancy_test"] for it in checkpoints["points"] if it.get("discrepancy_test")]
    checkpoints["n_discrepancy_test_failed"] = sum(not t["passed"] for t in tests)


def ground_point_precision(item: dict[str, Any], cov_lgs: np.ndarray | None) -> None:
    """Add the horizontal error ellipse of an adjusted point (tie or weighted control) whose
    scaled covariance is ``cov_lgs`` (in place; None without covariance)."""
    item["error_ellipse"] = None if cov_lgs is None else error_ellipse(cov_lgs[:2, :2])
