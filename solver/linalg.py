"""Linearised problem: weighted Jacobian, rank check, covariance and redundancy numbers.

The Jacobian is assembled from the same kernels as the residual blocks (one numba call for all
observations) plus the survey priors, independently of Ceres. Unknowns are ordered as all
images' free parameters (image order, model order), then the estimated points (3 each, LGS).

Covariance: N = J^T J of the whitened residuals (a-priori sigma0 = 1). The point blocks are
eliminated (Schur complement, 3x3 blocks), the reduced image system S is inverted densely, and
each point's 3x3 covariance is recovered; every block is then scaled by the a-posteriori
variance factor where the report asks for it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solver.kernels import observation_rows
from solver.problem import Problem


@dataclass
class Layout:
    img_col: np.ndarray  # (nimg,) first column of each image
    pt_col: np.ndarray  # (npt,) first column of each estimated point, -1 otherwise
    n_img_params: int
    n_params: int


def layout(problem: Problem) -> Layout:
    img_col = np.zeros(len(problem.images), dtype=np.int64)
    c = 0
    for img in problem.images:
        img_col[img.index] = c
        c += img.nfree
    n_img = c
    pt_col = -np.ones(len(problem.points), dtype=np.int64)
    for p in problem.points:
        if p.estimated:
            pt_col[p.index] = c
            c += 3
    return Layout(img_col, pt_col, n_img, c)


def _image_arrays(problem: Problem):
    nimg = len(problem.images)
    kinds = np.array([im.kind for im in problem.images], dtype=np.int64)
    coefs = np.ascontiguousarray([im.coef() for im in problem.images])
    kcs = np.ascontiguousarray([im.kc for im in problem.images])
    free = np.zeros((nimg, 24), dtype=np.int64)
    nfree = np.zeros(nimg, dtype=np.int64)
    for im in problem.images:
        free[im.index, : im.nfree] = im.free_idx
        nfree[im.index] = im.nfree
    return kinds, coefs, kcs, free, nfree


def evaluate_observations(problem: Problem, rows_mask: np.ndarray | None = None, want_jac: bool = True):
    """Whitened residuals (2n) and the sparse Jacobian of the selected observations."""
    lay = layout(problem)
    kinds, coefs, kcs, free, nfree = _image_arrays(problem)
    pts = np.ascontiguousarray([p.xyz for p in problem.points], dtype=float)
    obs = problem.obs
    sel = np.arange(len(obs.img)) if rows_mask is None else np.flatnonzero(rows_mask)
    res, r, c, v, ok = observation_rows(
        kinds, coefs, kcs, free, nfree, lay.img_col, pts, lay.pt_col,
        np.ascontiguousarray(obs.img[sel]), np.ascontiguousarray(obs.pt[sel]),
        np.ascontiguousarray(obs.oc[sel]), want_jac,
    )
    jac = sp.csr_matrix((v, (r, c)), shape=(2 * len(sel), lay.n_params)) if want_jac else None
    return res, jac, ok, sel, lay


def prior_rows(problem: Problem, lay: Layout):
    """Whitened residuals and Jacobian rows of the survey priors of weighted control points."""
    res, rows, cols, vals = [], [], [], []
    r = 0
    for p in problem.points:
        if p.estimated and p.role == "gcp" and p.sigma_m is not None and p.known_lgs is not None:
            for a in range(3):
                res.append((p.xyz[a] - p.known_lgs[a]) / p.sigma_m[a])
                rows.append(r)
                cols.append(lay.pt_col[p.index] + a)
                vals.append(1.0 / p.sigma_m[a])
                r += 1
    jac = sp.csr_matrix((vals, (rows, cols)), shape=(r, lay.n_params))
    return np.array(res), jac


@dataclass
class Linearisation:
    residuals: np.ndarray  # whitened, observations then priors
    jacobian: sp.csr_matrix
    n_obs_rows: int
    layout: Layout
    obs_sel: np.ndarray
    ok: np.ndarray


def linearise(problem: Problem) -> Linearisation:
    res, jac, ok, sel, lay = evaluate_observations(problem, problem.adjusted_mask)
    pres, pjac = prior_rows(problem, lay)
    return Linearisation(
        np.concatenate([res, pres]), sp.vstack([jac, pjac]).tocsr(), len(res), lay, sel, ok
    )


@dataclass
class SchurParts:
    s: np.ndarray  # reduced image normal matrix (dense)
    c_inv: np.ndarray  # (npt_est, 3, 3) inverse point blocks
    b: sp.csr_matrix  # image-point cross block N_ip (n_img x 3 npt)
    est_points: np.ndarray  # indices of estimated points in column order
    point_singular: np.ndarray  # (npt_est,) bool


def schur(lin: Linearisation, problem: Problem) -> SchurParts:
    lay = lin.layout
    n = lay.n_img_params
    jac = lin.jacobian
    normal = (jac.T @ jac).tocsr()
    a = normal[:n, :n].toarray()
    b = normal[:n, n:].tocsr()
    cdiag = normal[n:, n:]
    est = np.array([p.index for p in problem.points if p.estimated], dtype=np.int64)
    npt = len(est)
    blocks = np.zeros((npt, 3, 3))
    if npt:
        coo = cdiag.tocoo()
        bi = coo.row // 3
        same = bi == coo.col // 3
        blocks[bi[same], coo.row[same] % 3, coo.col[same] % 3] = coo.data[same]
    dets = np.linalg.det(blocks) if npt else np.zeros(0)
    scale = np.einsum("kii->k", blocks) ** 3 if npt else np.zeros(0)
    singular = np.abs(dets) <= 1e-14 * np.maximum(scale, 1e-300)
    c_inv = np.zeros_like(blocks)
    if npt:
        good = ~singular
        c_inv[good] = np.linalg.inv(blocks[good])
        cinv_sp = sp.block_diag(list(c_inv), format="csr")
        s = a - (b @ cinv_sp @ b.T).toarray()
    else:
        s = a
    return SchurParts(s, c_inv, b, est, singular)


@dataclass
class RankReport:
    deficient: bool
    condition: float
    null_parameters: list[tuple[str, float]]  # (image/param, weight in the null direction)


def check_rank(parts: SchurParts, names: list[str], tol: float = 1e-14) -> RankReport:
    """Eigen-analysis of the Jacobi-scaled reduced normal matrix S."""
    s = parts.s
    if s.size == 0:
        return RankReport(False, 1.0, [])
    d = np.sqrt(np.clip(np.diag(s), 1e-300, None))
    sn = s / np.outer(d, d)
    w, v = np.linalg.eigh(sn)
    wmax = max(w[-1], 1e-300)
    cond = float(wmax / max(w[0], 1e-300)) if w[0] > 0 else float("inf")
    bad = w <= tol * wmax
    null: list[tuple[str, float]] = []
    zero_diag = np.diag(s) <= 1e-300
    for k in np.flatnonzero(zero_diag):
        null.append((names[k], 1.0))
    if bad.any():
        vec = v[:, bad]
        weight = np.sqrt((vec**2).sum(axis=1))
        for k in np.argsort(-weight):
            if weight[k] < 0.3 or len(null) >= 8:
                break
            if names[k] not in [n for n, _ in null]:
                null.append((names[k], float(weight[k])))
    return RankReport(bool(bad.any() or zero_diag.any()), cond, null)


@dataclass
class Covariance:
    images: np.ndarray  # (n_img_params, n_img_params), a-priori scale (sigma0 = 1)
    points: dict[int, np.ndarray]  # point index -> 3x3, a-priori scale
    leverage: np.ndarray  # (n_obs_rows,) h_ii of the observation rows


def covariance(lin: Linearisation, parts: SchurParts, problem: Problem) -> Covariance:
    """Inverse normal-matrix blocks and observation leverages (a-priori sigma0 = 1)."""
    s_inv = np.linalg.inv(parts.s) if parts.s.size else parts.s
    lay = lin.layout
    n = lay.n_img_params
    pts_cov: dict[int, np.ndarray] = {}
    b = parts.b.tocsc()
    # per point: W = C^-1 B_p^T restricted to the images' columns that see it
    jac = lin.jacobian.tocsr()[: lin.n_obs_rows]
    lev = np.zeros(lin.n_obs_rows)
    # image-only part of the leverage, for rows without an estimated point
    ji = jac[:, :n]
    if n:
        tmp = ji @ s_inv
        lev_img = np.asarray(ji.multiply(tmp).sum(axis=1)).ravel()
    else:
        lev_img = np.zeros(lin.n_obs_rows)
    lev[:] = lev_img
    obs_pt = problem.obs.pt[lin.obs_sel]
    row_pt = np.repeat(obs_pt, 2)
    row_order = np.argsort(row_pt, kind="stable")
    row_bounds = np.searchsorted(row_pt[row_order], np.arange(len(problem.points) + 1))
    for q, pidx in enumerate(parts.est_points):
        col0 = lay.pt_col[pidx]
        cinv = parts.c_inv[q]
        bp = b[:, col0 : col0 + 3]  # n x 3 sparse
        idx = np.unique(bp.nonzero()[0])
        if len(idx):
            wb = bp[idx].toarray() @ cinv  # (m, 3) = B_p C^-1 restricted
            sub = s_inv[np.ix_(idx, idx)]
            cov = cinv + wb.T @ sub @ wb
        else:
            wb = np.zeros((0, 3))
            sub = np.zeros((0, 0))
            cov = cinv
        pts_cov[int(pidx)] = cov
        rows = row_order[row_bounds[pidx] : row_bounds[pidx + 1]]
        if len(rows):
            jr = jac[rows]
            jb = jr[:, col0 : col0 + 3].toarray()  # (r, 3)
            ja = jr[:, idx].toarray() if len(idx) else np.zeros((len(rows), 0))
            # h = u^T S^-1 u + b^T C^-1 b with u = a - B_p C^-1 b
            u = ja - jb @ wb.T
            lev[rows] = np.einsum("ij,jk,ik->i", u, sub, u) + np.einsum("ij,jk,ik->i", jb, cinv, jb)
    return Covariance(s_inv, pts_cov, lev)
