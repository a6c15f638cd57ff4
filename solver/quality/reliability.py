"""Cofactors of the residuals, redundancy numbers, minimal detectable biases (internal
reliability) and their effect on the parameters (external reliability).

All quantities are for the *whitened* residuals of :class:`solver.engine.linalg.Linearisation`
(a-priori sigma0 = 1): ``v = J dx - r`` has the cofactor ``Q_vv = I - H`` with the hat matrix
``H = J N^-1 J^T``. The diagonal of ``Q_vv`` holds the redundancy numbers (they sum to the
degrees of freedom). ``Q_vv`` is never formed whole: it is computed block by block, one block
per set of rows that share a ground point (the rays of an estimated point and its survey prior;
the rays of a fixed control point) or one term of an observation family (ephemeris, attitude,
line, ...: its tests labelled by the family, :meth:`ObservationFamily.groups`), with the
points eliminated as in :mod:`solver.engine.linalg`:

    H_block = U S^-1 U^T + J_p C_p^-1 J_p^T,   U = J_img - J_p C_p^-1 B_p^T

(``S`` the reduced image normal matrix, ``C_p`` the point's 3 x 3 normal block, ``B_p`` its
coupling to the image parameters). Correlations between rows of different blocks (two points
seen in the same image) are not computed: tests are separated within a block only.

A test group is the set of rows of one observation (an image point: line and column; a
control point's survey prior: east, north, up; an attitude sample: roll, pitch, yaw; an
ephemeris sample: position and velocity; a straight-line image point). A bias ``b`` (whitened)
in a group's rows moves the residuals by ``-Q b``; the group's test statistic
``T = v^T Q_gg^+ v`` then has the non-centrality ``b^T Q_gg b``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solver.engine.linalg import Linearisation, SchurParts
from solver.quality.distributions import chi2_noncentrality, chi2_upper_quantile
from solver.state import AdjustmentState

# a redundancy component below this is "nothing checks it": no finite detectable bias. Not
# larger: a survey of 0.2 m seen in a 20-m-GSD image has r ~ 3e-4 and an MDB of ~50 m, weak but
# finite; not smaller: the Schur path computes Q_vv to ~1e-6 (tests/solver/quality/test_quality_snooping.py)
REDUNDANCY_NEAR_ZERO = 1e-5


@dataclass
class Block:
    """Rows that share parameters beyond the images': their residual cofactor and what the
    external reliability needs (U, J_p, C_p^-1, B_p and the image columns)."""

    rows: np.ndarray  # global rows of Linearisation.residuals
    q: np.ndarray  # (m, m) cofactor of the whitened residuals
    cols: np.ndarray  # image/camera/pass columns the rows touch
    u: np.ndarray  # (m, len(cols))
    jp: np.ndarray | None  # (m, 3) point Jacobian rows (None: no estimated point)
    c_inv: np.ndarray | None  # (3, 3)
    bt: np.ndarray | None  # (3, len(cols)) B_p^T
    point: int = -1  # point index (estimated or fixed), -1 for terms


@dataclass
class Group:
    """One observation's rows (a test) inside a block."""

    kind: str  # image_point | control_point, or a family's (line_point, ephemeris_sample, attitude_sample, ...)
    label: dict  # image, point, line, pass, time_s, ... (report fields)
    block: int
    local: np.ndarray  # row positions inside the block
    sigma: np.ndarray  # observation standard deviations of the rows (units below)
    units: str  # px | m | deg | m, m/s
    components: list[str]
    removal: tuple | None = None  # how to remove it from the job (None: cannot be removed)
    sign: float = 1.0  # residual = sign (observed - model): +1 image points, -1 priors
    family: Any = None  # the observation family of a term's group (None: image and control points)

    @property
    def dim(self) -> int:
        return len(self.local)

    @property
    def point(self) -> str | None:
        """The ground point of an image point or a survey (None for a family's observation without one)."""
        return self.label.get("point")

    @property
    def fixed(self) -> bool:
        """An observation of a fixed control point (its coordinates held; no sigma to reinstate it with)."""
        return bool(self.label.get("fixed"))


@dataclass
class Structure:
    blocks: list[Block] = field(default_factory=list)
    groups: list[Group] = field(default_factory=list)
    s_inv: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


def _hat_block(jimg: np.ndarray, jp: np.ndarray | None, c_inv: np.ndarray | None, s_inv_sub: np.ndarray):
    if jp is None:
        u = jimg
        bt = None
        h = u @ s_inv_sub @ u.T
    else:
        bt = jp.T @ jimg  # (3, K): B_p^T (prior rows have no image columns)
        u = jimg - jp @ c_inv @ bt
        h = u @ s_inv_sub @ u.T + jp @ c_inv @ jp.T
    return np.eye(len(h)) - h, u, bt


def _obs_rows(lin: Linearisation, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Global rows and dense image Jacobian (rows x union of columns) of observations ``idx``."""
    cols = np.unique(lin.fcol[idx][lin.fcol[idx] >= 0])
    where = {int(c): k for k, c in enumerate(cols)}
    jimg = np.zeros((2 * len(idx), len(cols)))
    for t, i in enumerate(idx):
        for j in range(lin.fcol.shape[1]):
            c = lin.fcol[i, j]
            if c >= 0:
                jimg[2 * t : 2 * t + 2, where[int(c)]] += lin.jf[i, :, j]
    rows = np.empty(2 * len(idx), dtype=np.int64)
    rows[0::2] = 2 * idx
    rows[1::2] = 2 * idx + 1
    return rows, cols, jimg


def structure(problem: AdjustmentState, lin: Linearisation, parts: SchurParts, s_inv: np.ndarray) -> Structure:
    """Blocks of residual cofactors and the test groups of the adjusted problem."""
    st = Structure(s_inv=s_inv)
    obs = problem.obs
    sel = lin.obs_sel
    sig_px = obs.oc[sel, 2]
    n_obs_rows = lin.n_obs_rows
    prior_row = {}
    r = n_obs_rows
    for pidx in lin.point_prior:
        prior_row[pidx] = r
        r += 3
    pt_q = {int(p): q for q, p in enumerate(parts.est_points)}
    by_point: dict[int, list[int]] = {}
    for i, p in enumerate(lin.obs_pt):
        by_point.setdefault(int(p), []).append(i)
    # the families' terms: their global rows; those on an estimated point join its block
    term_rows: list[np.ndarray] = []
    row = n_obs_rows + 3 * len(lin.point_prior)
    on_point: dict[int, list[int]] = {}
    for k, (labelled, (res, _jac)) in enumerate(zip(lin.terms, lin.term_eval)):
        term_rows.append(row + np.arange(len(res)))
        row += len(res)
        if labelled.block == "point" and labelled.index in pt_q:
            on_point.setdefault(labelled.index, []).append(k)
            by_point.setdefault(labelled.index, [])
    for p, idx_list in by_point.items():
        point = problem.points[p]
        idx = np.array(idx_list, dtype=np.int64)
        rows, cols, jimg = _obs_rows(lin, idx)
        jp = c_inv = None
        if p in pt_q:
            c_inv = parts.c_inv[pt_q[p]]
            jp = np.zeros((len(rows), 3))
            for t, i in enumerate(idx):
                jp[2 * t : 2 * t + 2] = lin.jpt[i]
            if p in lin.point_prior:
                _res, w = lin.point_prior[p]
                rows = np.concatenate([rows, prior_row[p] + np.arange(3)])
                jimg = np.vstack([jimg, np.zeros((3, len(cols)))])
                jp = np.vstack([jp, np.diag(w)])
            term_start = {}
            for k in on_point.get(p, []):  # terms on the point: rows of the point only
                jac = lin.term_eval[k][1]
                term_start[k] = len(rows)
                rows = np.concatenate([rows, term_rows[k]])
                jimg = np.vstack([jimg, np.zeros((len(jac), len(cols)))])
                jp = np.vstack([jp, jac])
        q, u, bt = _hat_block(jimg, jp, c_inv, s_inv[np.ix_(cols, cols)])
        b = len(st.blocks)
        st.blocks.append(Block(rows, q, cols, u, jp, c_inv, bt, p))
        for k in on_point.get(p, []):
            labelled = lin.terms[k]
            for g in labelled.family.groups(problem, labelled):
                st.groups.append(
                    Group(g.kind, g.label, b, term_start[k] + np.asarray(g.rows), np.asarray(g.sigma, dtype=float), g.units, g.components,
                          g.removal, g.sign, labelled.family)
                )
        for t, i in enumerate(idx):
            k = int(sel[i])
            st.groups.append(
                Group(
                    "image_point",
                    {"image": problem.images[obs.img[k]].id, "point": point.id, "role": point.role},
                    b,
                    np.array([2 * t, 2 * t + 1]),
                    np.array([sig_px[i], sig_px[i]]),
                    "px",
                    ["line", "column"],
                    ("observation", int(obs.source_index[k])),
                )
            )
        if p in lin.point_prior:
            st.groups.append(
                Group(
                    "control_point",
                    {"point": point.id},
                    b,
                    2 * len(idx) + np.arange(3),
                    np.asarray(point.sigma_m, dtype=float),
                    "m",
                    ["e", "n", "u"],
                    ("control", p),
                    -1.0,
                )
            )
    # the families' other terms: one block each, their tests as the family labels them
    for k, (labelled, c0, (res, jac)) in enumerate(zip(lin.terms, lin.term_col, lin.term_eval)):
        if labelled.block == "point":  # with their point's block above
            continue
        rows = term_rows[k]
        specs = labelled.family.groups(problem, labelled)
        if not specs:
            continue
        cols = c0 + np.arange(jac.shape[1])
        q, u, _bt = _hat_block(jac, None, None, s_inv[np.ix_(cols, cols)])
        b = len(st.blocks)
        st.blocks.append(Block(rows, q, cols, u, None, None, None))
        for g in specs:
            st.groups.append(
                Group(g.kind, g.label, b, g.rows, np.asarray(g.sigma, dtype=float), g.units, g.components, g.removal, g.sign, labelled.family)
            )
    return st


def noncentrality(alpha0: float, beta: float, dim: int) -> float:
    """lambda0: the non-centrality of a chi-square(dim) test at level alpha0 with power beta
    (dim = 1: (3.29 + 0.84)^2 = 17.07 for alpha0 = 0.001, beta = 0.8)."""
    return chi2_noncentrality(chi2_upper_quantile(alpha0, dim), dim, beta)


def group_cofactor(st: Structure, g: Group) -> np.ndarray:
    """Q_gg: cofactor of the group's whitened residuals."""
    q = st.blocks[g.block].q
    return q[np.ix_(g.local, g.local)]


def redundancy(st: Structure, g: Group) -> np.ndarray:
    """Redundancy numbers of the group's rows (diagonal of Q_vv, 0..1)."""
    return np.clip(np.diag(group_cofactor(st, g)), 0.0, 1.0)


def minimal_detectable_bias(st: Structure, g: Group, lam0: float) -> list[float | None]:
    """Internal reliability: per component, the smallest bias in that component alone (in the
    observation's units, sigma0 a priori) that the group's test detects with power beta."""
    r = redundancy(st, g)
    return [float(g.sigma[k] * np.sqrt(lam0 / r[k])) if r[k] > REDUNDANCY_NEAR_ZERO else None for k in range(g.dim)]


def weakest_direction(st: Structure, g: Group, lam0: float) -> dict[str, Any] | None:
    """Internal reliability over every direction of the group, not component by component: a
    bias ``m u`` (``u`` a unit vector in the observation's units) has the non-centrality
    ``m^2 u^T S^-1 Q_gg S^-1 u`` (``S`` the sigmas), so the largest MDB of the group is
    ``sqrt(lam0 / mu)`` along the eigenvector of the smallest eigenvalue ``mu`` of
    ``S^-1 Q_gg S^-1``, over the components that something checks (redundancy above
    ``REDUNDANCY_NEAR_ZERO``). It exceeds every per-component MDB when the components'
    redundancies are correlated: a control point's survey on one image can hide an error
    along a combination of east and north that the orientation absorbs. None for one
    component or none checked."""
    r = redundancy(st, g)
    keep = [k for k in range(g.dim) if r[k] > REDUNDANCY_NEAR_ZERO]
    if len(keep) < 2:
        return None
    sig = np.asarray(g.sigma, dtype=float)[keep]
    m = group_cofactor(st, g)[np.ix_(keep, keep)] / np.outer(sig, sig)
    mu, vec = np.linalg.eigh(m)
    v = vec[:, 0]
    if v[np.argmax(np.abs(v))] < 0:  # the sign is arbitrary: largest component positive
        v = -v
    u = np.zeros(g.dim)
    u[keep] = v
    value = float(np.sqrt(lam0 / mu[0])) if mu[0] > 0 else None
    return {"value": value, "direction": [float(x) for x in u]}


def bias_effect(st: Structure, g: Group, bias_whitened: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """External reliability: the change of the image/camera/pass parameters (full vector,
    parameter units) and of the block's own point (3, LGS metres; None for terms) that a bias
    in the group's rows (whitened) causes."""
    blk = st.blocks[g.block]
    b = np.zeros(len(blk.rows))
    b[g.local] = bias_whitened
    dx_img = st.s_inv[:, blk.cols] @ (blk.u.T @ b)
    dx_pt = None
    if blk.jp is not None:
        dx_pt = blk.c_inv @ (blk.jp.T @ b - blk.bt @ dx_img[blk.cols])
    return dx_img, dx_pt


def bias_to_noise(st: Structure, g: Group, lam0: float) -> float | None:
    """Baarda's external reliability: the largest effect of a component's minimal detectable
    bias on any function of the parameters, in units of that function's standard deviation,
    sqrt(lambda0 (1 - r) / r) maximised over the group's components."""
    r = redundancy(st, g)
    if not len(r) or r.min() <= REDUNDANCY_NEAR_ZERO:
        return None
    return float(np.sqrt(lam0 * (1.0 - r) / r).max())
