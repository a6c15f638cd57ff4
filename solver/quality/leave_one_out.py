"""Leave-one-out on the control points: each control point withheld in turn, from the solution.

Withholding control point p means adjusting without any of its observations (its survey
prior, when weighted, and its image coordinates) and then computing it as a check point from
the new orientation. Nothing is re-adjusted: the orientation without p follows from the
solution by downdating the reduced normal matrix (points eliminated, orientation columns
``f``, whitened residuals ``r``, Jacobians of the residuals ``F`` wrt f and ``J_x`` wrt p)::

    K   = I - J_x C_p^-1 J_x^T      (C_p = J_x^T J_x + prior weights; K = I for fixed control)
    M_p = F^T K F                  p's contribution to the reduced normal matrix
    Q_-p = (S - M_p)^-1 = Q + Q U (I - U^T Q U)^-1 U^T Q,   U = F^T L,  L L^T = K
    df   = Q_-p F^T r               (at the solution the reduced gradient without p is -F^T r)

and p is intersected from its rays with the orientation f + df (one Gauss-Newton step from
its adjusted, or known, position). Its predicted covariance is that of a check point
(:mod:`solver.quality.precision`) with ``Q_-p`` in place of ``Q``. The cross-validation RMSE
over the control points is the honest accuracy figure when the few control points are all
there is. Linearised at the solution: tests/solver/quality/test_quality_precision.py compares it with
re-adjustments from scratch.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from solver.engine.linalg import Layout
from solver.engine.packed_tables import current_tables
from solver.quality.precision import (
    discrepancy_test,
    error_ellipse,
    intersection_cofactor,
    normalised,
    ray_blocks,
    rmse_summary,
    sigmas_enu,
    survey_covariance,
)
from solver.state import AdjustmentState

SINGULAR = 1e-9  # I - U^T Q U below this (relative): without p the orientation is undetermined


def _downdated(q_sub: np.ndarray, u: np.ndarray) -> np.ndarray | None:
    """The block of (S - U U^T)^-1 on the point's orientation columns, by Woodbury from the same
    block of Q = S^-1 (``q_sub``; U has its rows on those columns); None if singular. Nothing
    outside the block is needed: the point is intersected from its own images only."""
    if u.shape[1] == 0:
        return q_sub
    qu = q_sub @ u
    core = np.eye(u.shape[1]) - u.T @ qu
    w = np.linalg.eigvalsh(0.5 * (core + core.T))
    if w[0] <= SINGULAR * max(w[-1], 1.0):
        return None
    return q_sub + qu @ np.linalg.solve(core, qu.T)


def withhold(problem: AdjustmentState, lay: Layout, q_ff: np.ndarray, point_index: int, tables=None) -> dict[str, Any] | None:
    """The point computed from the orientation adjusted without it: position (LGS), cofactor
    (a-priori scale) and its free axes; None when p's rays or the remaining control do not
    determine it."""
    p = problem.points[point_index]
    obs = problem.obs
    rows = np.flatnonzero(obs.pt == point_index)
    if len(rows) == 0:
        return None
    blocks = ray_blocks(problem, lay, rows, p.xyz, tables)
    jx, f, r = blocks.jx, blocks.jf, blocks.res
    k = np.eye(len(r))
    if p.estimated:
        c = jx.T @ jx
        if p.sigma_m is not None:
            c = c + np.diag(1.0 / np.asarray(p.sigma_m, dtype=float) ** 2)
        k = k - jx @ np.linalg.solve(c, jx.T)
    w, v = np.linalg.eigh(0.5 * (k + k.T))
    keep = w > 1e-12
    u = f.T @ (v[:, keep] * np.sqrt(w[keep]))
    q_minus = _downdated(q_ff[np.ix_(blocks.f_cols, blocks.f_cols)], u)
    if q_minus is None:
        return None
    df = q_minus @ (f.T @ r)
    axes = (0, 1, 2) if len(rows) > 1 else (0, 1)
    local = replace(blocks, f_cols=np.arange(len(blocks.f_cols)))  # q_minus is on the point's columns only
    q = intersection_cofactor(local, q_minus, axes)
    if q is None:
        return None
    ax = list(axes)
    a = jx[:, ax]
    x0, r0 = p.xyz.copy(), r
    if len(ax) == 2 and p.known_lgs is not None:
        # mono: the point stays at its known height (linear shift of the residuals to it)
        x0[2] = p.known_lgs[2]
        r0 = r + jx[:, 2] * (p.known_lgs[2] - p.xyz[2])
    dx = np.zeros(3)
    dx[ax] = -np.linalg.solve(a.T @ a, a.T @ (r0 + f @ df))
    return {"xyz": x0 + dx, "cofactor": q, "axes": axes, "blocks": blocks, "rows": rows}


def leave_one_out(problem: AdjustmentState, lay: Layout, q_ff: np.ndarray | None, var_factor: float, alpha: float) -> dict[str, Any] | None:
    """The ``quality.leave_one_out`` section (docs/report-contract.md): every control point with
    known coordinates withheld in turn; None without a covariance."""
    if q_ff is None:
        return None
    tables = current_tables(problem)
    points, discs, covs, axes_of = [], [], [], []
    for p in problem.points:
        if p.role != "gcp" or p.known_lgs is None:
            continue
        out = withhold(problem, lay, q_ff, p.index, tables)
        item: dict[str, Any] = {
            "id": p.id,
            "images": [problem.images[i].id for i in problem.obs.img[problem.obs.pt == p.index]],
            "known_lgs_m": [float(x) for x in p.known_lgs],
            "determined": out is not None,
        }
        if out is None:
            points.append(item)
            continue
        axes = out["axes"]
        cov = var_factor * out["cofactor"] + survey_covariance(p.sigma_m, out["blocks"], axes)
        d = out["xyz"] - p.known_lgs
        item.update(
            {
                "method": "intersection" if len(axes) == 3 else "mono",
                "estimated_lgs_m": [float(x) for x in out["xyz"]],
                "discrepancy_m": {
                    "e": float(d[0]),
                    "n": float(d[1]),
                    "u": float(d[2]) if 2 in axes else None,
                    "planimetric": float(np.hypot(d[0], d[1])),
                },
                "sigma_m": {**sigmas_enu(cov), **({"u": None} if 2 not in axes else {})},
                "error_ellipse": error_ellipse(cov[:2, :2]),
                "normalised_discrepancy": normalised(d, cov, axes),
                "discrepancy_test": discrepancy_test(d, cov, axes, alpha),
            }
        )
        points.append(item)
        discs.append(d if 2 in axes else np.array([d[0], d[1], 0.0]))
        covs.append(cov)
        axes_of.append(axes)
    summary = rmse_summary(discs, covs, axes_of) if discs else {"rmse_m": None, "predicted_rmse_m": None, "ratio": None}
    tests = [it["discrepancy_test"] for it in points if it.get("discrepancy_test")]
    return {
        "method": "downdating of the reduced normal matrix at the solution (no re-adjustment)",
        "n": len(points),
        "n_determined": len(discs),
        "points": points,
        "rmse_m": summary["rmse_m"],
        "predicted_rmse_m": summary["predicted_rmse_m"],
        "ratio": summary["ratio"],
        "n_discrepancy_test_failed": sum(not t["passed"] for t in tests),
    }
