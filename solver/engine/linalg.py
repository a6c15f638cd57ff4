"""Linearised problem: rank check, covariance and redundancy numbers (numba, independent of Ceres).

The Jacobian is evaluated with the same kernels as the residual blocks, observation by
observation as small dense blocks (2 x n_image_parameters and 2 x 3), plus the survey priors
of weighted control points and the terms of the observation families
(:func:`solver.engine.terms.family_terms`, in the registry's order). Unknowns are ordered as all
images' free parameters (image order, model order), the cameras' free interior orientation,
the passes' states (6 each, ECEF), then the estimated points (3 each, LGS).

Normal matrix N = J^T J of the whitened residuals (a-priori sigma0 = 1) in block form
[[A, B], [B^T, C]] with C block-diagonal (3 x 3 per point). The points are eliminated
(S = A - B C^-1 B^T), S is inverted (densely, or from its band's factor when it is a long
strip's banded matrix: :mod:`solver.engine.banded`), and per point the 3 x 3 covariance
C^-1 + C^-1 B_p^T S^-1 B_p C^-1 and the leverages h = u^T S^-1 u + b^T C^-1 b
(u = a - B_p C^-1 b) of its observation rows are recovered. Scale by the a-posteriori variance
factor where a report needs it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from numba import njit
from scipy.linalg import lapack

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @njit)
from solver.blocks import registry as blocks
from solver.engine import banded, dense_threads
from solver.engine.native import in_threads, thread_ranges
from solver.engine.packed_tables import current_tables, records
from solver.engine.terms import block_owner, family_terms
from solver.kernels import all_observation_blocks
from solver.observations.family import Labelled
from solver.state import AdjustmentState, grouped

if TYPE_CHECKING:
    import scipy.sparse as sp

_JIT = dict(cache=True, nogil=True, error_model="numpy")


@dataclass
class Layout:
    """The columns of the unknowns: the blocks of every kind of :mod:`solver.blocks.registry`
    in its order, the eliminated kind (the ground points) last. ``cols[kind]``: the first column
    of the block each index of that kind names (as a term's label does; -1: not laid out, no
    free parameters); ``img_col``, ``cam_col``, ``pass_col`` and ``pt_col`` are those of the
    kinds the image-observation kernels read."""

    img_col: np.ndarray  # (nimg,) first column of each image's platform block
    pt_col: np.ndarray  # (npt,) first column of each estimated point, -1 otherwise
    n_img_params: int  # every block before the points: all columns of the reduced system
    n_params: int
    cam_col: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # (ncam,)
    pass_col: np.ndarray = field(default_factory=lambda: np.zeros(1, dtype=np.int64))  # (npass,)
    cols: dict[str, np.ndarray] = field(default_factory=dict)

    def column(self, kind: str, index: int) -> int:
        """The first column of the block that ``index`` of kind ``kind`` names (-1: none)."""
        return int(self.cols[kind][index])


def _kind_columns(problem: AdjustmentState, kind, c: int) -> tuple[np.ndarray, int]:
    """First columns of ``kind``'s blocks from column ``c`` on (indexed as its terms address them), and the next free column."""
    first: dict[int, int] = {}
    for block in kind.blocks(problem):
        if block.nfree:
            first[block.index] = c
            c += block.nfree
    addressed = kind.addressed(problem)
    cols = np.array([first.get(b.index, -1) for b in addressed], dtype=np.int64)
    return (cols if len(cols) else -np.ones(1, dtype=np.int64)), c


def layout(problem: AdjustmentState) -> Layout:
    """The columns of every kind's blocks (:mod:`solver.blocks.registry`): the reduced kinds in
    the registry's order, then the eliminated one (the ground points)."""
    c = 0
    cols: dict[str, np.ndarray] = {}
    for kind in [k for k in blocks.BLOCK_KINDS if not k.eliminated]:
        cols[kind.name], c = _kind_columns(problem, kind, c)
    n_f = c
    for kind in [k for k in blocks.BLOCK_KINDS if k.eliminated]:
        cols[kind.name], c = _kind_columns(problem, kind, c)
    pt_col = cols["point"][: len(problem.points)]
    img_col = cols["image"][: len(problem.images)] if problem.images else np.zeros(0, dtype=np.int64)
    return Layout(img_col, pt_col, n_f, c, cols["camera"], cols["pass"], cols)


def first_column(lay: Layout, labelled: Labelled) -> int:
    """The first column of the parameter block a family's term acts on."""
    return lay.column(labelled.block, labelled.index)


@dataclass
class Linearisation:
    """Residuals and Jacobian blocks at the current parameters."""

    layout: Layout
    obs_sel: np.ndarray  # indices of the observations that enter the adjustment
    res_obs: np.ndarray  # (n, 2) whitened
    jf: np.ndarray  # (n, 2, W) wrt image and camera parameters, columns in fcol
    fcol: np.ndarray  # (n, W) global columns, -1 padding
    jpt: np.ndarray  # (n, 2, 3)
    ok: np.ndarray  # (n,)
    point_prior: dict[int, tuple[np.ndarray, np.ndarray]]  # point -> (whitened residual, 1/sigma)
    terms: list[Labelled]  # the families' terms (solver.engine.terms.family_terms)
    term_eval: list[tuple[np.ndarray, np.ndarray]]  # (residuals, jacobian) of each term
    term_col: list[int]  # first column of each term's block
    obs_pt: np.ndarray

    @property
    def n_obs_rows(self) -> int:
        return 2 * len(self.obs_sel)

    @property
    def residuals(self) -> np.ndarray:
        """All whitened residuals: observations (line, column interleaved), then priors."""
        parts = [self.res_obs.ravel()]
        parts += [r for r, _ in self.point_prior.values()]
        parts += [r for r, _ in self.term_eval]
        return np.concatenate(parts) if parts else np.zeros(0)

    def without_jacobians(self) -> "Linearisation":
        """The same residuals without the observations' Jacobian blocks (emptied), for readers
        of residuals only; the largest arrays of a big block."""
        def empty(a: np.ndarray) -> np.ndarray:
            return np.empty((0, *a.shape[1:]), dtype=a.dtype)  # not a view: a view keeps the buffer

        return replace(self, jf=empty(self.jf), fcol=empty(self.fcol), jpt=empty(self.jpt))

    def sparse_jacobian(self) -> sp.csr_matrix:
        """The full weighted Jacobian (rows as :attr:`residuals`), for tests and diagnostics."""
        import scipy.sparse as sp  # here, not at import: a new process's first solve would pay 0.1 s for it

        rows, cols, vals = [], [], []
        lay = self.layout
        for q in range(len(self.obs_sel)):
            pt = self.obs_pt[q]
            for r in range(2):
                for j in range(self.fcol.shape[1]):
                    if self.fcol[q, j] >= 0:
                        rows.append(2 * q + r)
                        cols.append(self.fcol[q, j])
                        vals.append(self.jf[q, r, j])
                if lay.pt_col[pt] >= 0:
                    for j in range(3):
                        rows.append(2 * q + r)
                        cols.append(lay.pt_col[pt] + j)
                        vals.append(self.jpt[q, r, j])
        row = self.n_obs_rows
        for pidx, (_res, w) in self.point_prior.items():
            for a in range(3):
                rows.append(row)
                cols.append(lay.pt_col[pidx] + a)
                vals.append(w[a])
                row += 1
        for c0, (_r, jac) in zip(self.term_col, self.term_eval):
            for q in range(jac.shape[0]):
                for c in np.flatnonzero(jac[q]):
                    rows.append(row)
                    cols.append(c0 + c)
                    vals.append(jac[q, c])
                row += 1
        return sp.csr_matrix((vals, (rows, cols)), shape=(row, lay.n_params))


def linearise(problem: AdjustmentState) -> Linearisation:
    lay = layout(problem)
    obs = problem.obs
    sel = np.flatnonzero(problem.adjusted_mask)
    img_tab, cam_tab, img_p, cam_p = current_tables(problem)
    width = max(im.nfree for im in problem.images) + max([c.nfree for c in problem.cameras] + [0]) + (6 if problem.passes else 0)
    pts = np.ascontiguousarray(np.array([p.xyz for p in problem.points], dtype=float).reshape(-1, 3))  # (0, 3) without points
    est = np.array([p.estimated for p in problem.points], dtype=np.bool_)
    rec = records(problem, sel)
    op = np.ascontiguousarray(obs.pt[sel])
    res, jf, fcol, jpt, ok = all_observation_blocks(rec, img_tab, cam_tab, img_p, cam_p, pts, op, est, lay.img_col, lay.cam_col,
                                                    lay.pass_col, width, run=in_threads)
    point_prior = {}
    for p in problem.points:
        if p.estimated and p.role == "gcp" and p.sigma_m is not None and p.known_lgs is not None:
            point_prior[p.index] = ((p.xyz - p.known_lgs) / p.sigma_m, 1.0 / p.sigma_m)
    terms = family_terms(problem)
    term_col = [first_column(lay, t) for t in terms]
    term_eval = [t.term.evaluate(block_owner(problem, t).params) for t in terms]
    return Linearisation(lay, sel, res, jf, fcol, jpt, ok, point_prior, terms, term_eval, term_col, op)


@njit(**_JIT)
def _accumulate(n_f, fcol, jf, obs_pt, jpt, pt_q, npt_est):
    """A (image/camera normal block) and C (3x3 point blocks)."""
    a = np.zeros((n_f, n_f))
    c = np.zeros((npt_est, 3, 3))
    w = fcol.shape[1]
    for i in range(fcol.shape[0]):
        for r in range(2):
            for j in range(w):
                cj = fcol[i, j]
                vj = jf[i, r, j]
                if cj < 0 or vj == 0.0:
                    continue
                for k in range(w):
                    ck = fcol[i, k]
                    if ck >= 0:
                        a[cj, ck] += vj * jf[i, r, k]
            q = pt_q[obs_pt[i]]
            if q >= 0:
                for j in range(3):
                    for k in range(3):
                        c[q, j, k] += jpt[i, r, j] * jpt[i, r, k]
    return a, c


@njit(**_JIT)
def _b_times_into(fcol, jf, jpt, q_of, v, u):
    """u += B V: for each observation row i of an estimated point q (``q_of[i]`` >= 0) the
    image columns' J_f^T (J_p V_q), V_q = ``v[q]`` (3 x k)."""
    w = fcol.shape[1]
    k_n = v.shape[2]
    for i in range(fcol.shape[0]):
        q = q_of[i]
        if q < 0:
            continue
        for r in range(2):
            for k in range(k_n):
                t = jpt[i, r, 0] * v[q, 0, k] + jpt[i, r, 1] * v[q, 1, k] + jpt[i, r, 2] * v[q, 2, k]
                if t == 0.0:
                    continue
                for j in range(w):
                    c = fcol[i, j]
                    if c >= 0:
                        u[c, k] += jf[i, r, j] * t


def b_times(lin: Linearisation, parts: SchurParts, v: np.ndarray) -> np.ndarray:
    """B V (reduced columns x k) for point-space vectors ``v`` (n_est, 3, k) in the estimated
    points' order (B: the normal matrix's block between the reduced parameters and the points)."""
    u = np.zeros((parts.n_reduced, v.shape[2]))
    if len(lin.obs_pt) and len(parts.est_points):
        pt_q = -np.ones(int(max(lin.obs_pt.max(), parts.est_points.max())) + 1, dtype=np.int64)
        pt_q[parts.est_points] = np.arange(len(parts.est_points))
        _b_times_into(lin.fcol, lin.jf, lin.jpt, pt_q[lin.obs_pt], np.ascontiguousarray(v, dtype=np.float64), u)
    return u


@njit(**_JIT)
def _point_b(lo, hi, order, fcol, jf, jpt, cols, bp):
    """The point's image columns (concatenated over its observations, duplicates allowed) into
    ``cols`` and its B_p rows into ``bp`` (work buffers of at least (hi - lo) x width rows);
    returns their number m."""
    w = fcol.shape[1]
    m = 0
    for t in range(lo, hi):
        i = order[t]
        for j in range(w):
            if fcol[i, j] < 0:
                continue
            cols[m] = fcol[i, j]
            for k in range(3):
                bp[m, k] = jf[i, 0, j] * jpt[i, 0, k] + jf[i, 1, j] * jpt[i, 1, k]
            m += 1
    return m


@njit(**_JIT)
def _times_3x3(a, m, c, q, out):
    """``out[:m] = a[:m] @ c[q]`` for 3 x 3 blocks ``c`` (indexed in place: no temporary and no
    view, whose reference count threads would share)."""
    for x in range(m):
        for k in range(3):
            out[x, k] = a[x, 0] * c[q, 0, k] + a[x, 1] * c[q, 1, k] + a[x, 2] * c[q, 2, k]


def _most_rows(fcol: np.ndarray, bounds: np.ndarray) -> int:
    """Work-buffer rows for any point: its observations times the block width."""
    return max(int(np.diff(bounds).max(initial=0)) * fcol.shape[1], 1)


@njit(**_JIT)
def _reduce_into(t_lo, t_hi, s, c0, fcol, jf, jpt, order, bounds, c_inv, rows, seq):
    """S -= B_p C_p^-1 B_p^T for the points ``seq[t_lo:t_hi]`` (observations grouped by
    ``order``/``bounds``; ``rows``: :func:`_most_rows`); ``s`` holds S's rows and columns from
    ``c0`` on (a band of it)."""
    cols = np.empty(rows, dtype=np.int64)
    bp = np.empty((rows, 3))
    wm = np.empty((rows, 3))
    for t in range(t_lo, t_hi):
        q = seq[t]
        lo, hi = bounds[q], bounds[q + 1]
        if hi == lo:
            continue
        m = _point_b(lo, hi, order, fcol, jf, jpt, cols, bp)
        _times_3x3(bp, m, c_inv, q, wm)
        for x in range(m):
            for y in range(m):
                s[cols[x] - c0, cols[y] - c0] -= wm[x, 0] * bp[y, 0] + wm[x, 1] * bp[y, 1] + wm[x, 2] * bp[y, 2]


PARALLEL_MAX_REDUCED = 3_000
"""Largest band of the reduced normal matrix (parameters of images, cameras and passes) a
thread eliminates its points into as a copy of its own (3,000 parameters: 72 MB a copy; the
second half of a 303-image connected strip touches about 2,150 of its 4,242)."""


def _point_column_span(order: np.ndarray, bounds: np.ndarray, fcol: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per point (in ``bounds``' order) the first and last column of S its observations touch
    (first > last for a point that touches none)."""
    big = np.iinfo(np.int64).max
    rows = fcol[order]
    first_row = np.where(rows >= 0, rows, big).min(axis=1) if rows.size else np.zeros(0, dtype=np.int64)
    last_row = rows.max(axis=1) if rows.size else np.zeros(0, dtype=np.int64)
    n = bounds.shape[0] - 1
    first = np.full(n, big, dtype=np.int64)
    last = np.full(n, -1, dtype=np.int64)
    has = np.flatnonzero(np.diff(bounds) > 0)
    if len(has):
        first[has] = np.minimum.reduceat(first_row, bounds[has])
        last[has] = np.maximum.reduceat(last_row, bounds[has])
    return first, last


def _column_band(first: np.ndarray, last: np.ndarray, seq: np.ndarray, lo: int, hi: int) -> tuple[int, int]:
    """The columns ``[first, last + 1)`` of S that the points ``seq[lo:hi]`` touch (their
    images' parameters): a strip's points, in order along it, touch a band of its banded S."""
    f, la = first[seq[lo:hi]], last[seq[lo:hi]]
    touching = la >= 0
    return (int(f[touching].min()), int(la[touching].max()) + 1) if touching.any() else (0, 0)


def _reduce(a, fcol, jf, jpt, order, bounds, c_inv) -> np.ndarray:
    """S = A - sum_p B_p C_p^-1 B_p^T (``a`` is overwritten): on the solve's threads, the points
    taken in the order of the first column of S they touch (along a strip, whatever the job's
    order of its points), the first range eliminated into ``a`` itself and each other range into
    a copy of the band of S its points touch, the copies added in range order (the same sum on
    every run with the same threads); on one thread, in the job's order, when there is one range
    or some band is wider than :data:`PARALLEL_MAX_REDUCED`."""
    n_points = bounds.shape[0] - 1
    rows = _most_rows(fcol, bounds)
    ranges = thread_ranges(n_points)
    in_job_order = np.arange(n_points, dtype=np.int64)
    if len(ranges) <= 2:
        _reduce_into(0, n_points, a, 0, fcol, jf, jpt, order, bounds, c_inv, rows, in_job_order)
        return a
    first, last = _point_column_span(order, bounds, fcol)
    seq = np.argsort(first, kind="stable").astype(np.int64)
    bands = {lo: _column_band(first, last, seq, lo, hi) for lo, hi in zip(ranges[1:-1], ranges[2:])}
    if any(c1 - c0 > PARALLEL_MAX_REDUCED for c0, c1 in bands.values()):
        _reduce_into(0, n_points, a, 0, fcol, jf, jpt, order, bounds, c_inv, rows, in_job_order)
        return a
    shares: dict[int, np.ndarray] = {}

    def fill(lo: int, hi: int) -> None:
        if lo == 0:
            _reduce_into(lo, hi, a, 0, fcol, jf, jpt, order, bounds, c_inv, rows, seq)
            return
        c0, c1 = bands[lo]
        share = np.zeros((c1 - c0, c1 - c0))
        _reduce_into(lo, hi, share, c0, fcol, jf, jpt, order, bounds, c_inv, rows, seq)
        shares[lo] = share

    in_threads(fill, n_points)
    for lo in sorted(shares):
        c0, c1 = bands[lo]
        a[c0:c1, c0:c1] += shares[lo]
    return a


@njit(**_JIT)
def _point_covariances_into(q_lo, q_hi, s_inv, fcol, jf, jpt, order, bounds, c_inv, cov, lev, rows):
    """Points ``q_lo:q_hi``: 3x3 covariance (into ``cov``) and the leverages of their
    observation rows (into ``lev``); ``rows``: :func:`_most_rows`.

    With W = B_p C^-1 (m x 3 over the point's m image columns), Q the images' covariance on
    those columns, Z = Q W and G = W^T Z: the point's covariance is C^-1 + G, and a row with
    image part e (its own image's columns only) and point part b has the leverage
    (e - W b)^T Q (e - W b) + b^T C^-1 b = e^T Q e - 2 e^T Z b + b^T (G + C^-1) b: the m x m
    products of the expanded form are done once per point, not once per row, and nothing is
    allocated per point (numba's allocations serialise threads)."""
    w = fcol.shape[1]
    cols = np.empty(rows, dtype=np.int64)
    bp = np.empty((rows, 3))
    wb = np.empty((rows, 3))
    z = np.empty((rows, 3))
    for q in range(q_lo, q_hi):
        lo, hi = bounds[q], bounds[q + 1]
        m = _point_b(lo, hi, order, fcol, jf, jpt, cols, bp)
        _times_3x3(bp, m, c_inv, q, wb)
        for x in range(m):  # Z = Q W, Q read in place from the images' covariance
            z0 = z1 = z2 = 0.0
            for y in range(m):
                qxy = s_inv[cols[x], cols[y]]
                z0 += qxy * wb[y, 0]
                z1 += qxy * wb[y, 1]
                z2 += qxy * wb[y, 2]
            z[x, 0], z[x, 1], z[x, 2] = z0, z1, z2
        for a in range(3):
            for c in range(3):
                g = 0.0
                for x in range(m):
                    g += wb[x, a] * z[x, c]
                cov[q, a, c] = c_inv[q, a, c] + g
        off = 0
        for t in range(lo, hi):
            i = order[t]
            nown = 0
            for j in range(w):
                if fcol[i, j] >= 0:
                    nown += 1
            for r in range(2):
                b0, b1, b2 = jpt[i, r, 0], jpt[i, r, 1], jpt[i, r, 2]
                h = 0.0
                jj = 0
                for j in range(w):
                    if fcol[i, j] < 0:
                        continue
                    e = jf[i, r, j]
                    cj = fcol[i, j]
                    for k in range(w):
                        if fcol[i, k] >= 0:
                            h += e * s_inv[cj, fcol[i, k]] * jf[i, r, k]
                    h -= 2.0 * e * (z[off + jj, 0] * b0 + z[off + jj, 1] * b1 + z[off + jj, 2] * b2)
                    jj += 1
                for x, bx in enumerate((b0, b1, b2)):
                    h += bx * (cov[q, x, 0] * b0 + cov[q, x, 1] * b1 + cov[q, x, 2] * b2)
                lev[2 * i + r] = h
            off += nown


def _point_covariances(s_inv, fcol, jf, jpt, order, bounds, c_inv, lev) -> np.ndarray:
    """Per point: 3x3 covariance and the leverages of its observation rows (written into lev),
    on the solve's threads (:func:`in_threads`)."""
    cov = np.zeros((bounds.shape[0] - 1, 3, 3))
    rows = _most_rows(fcol, bounds)

    def fill(lo: int, hi: int) -> None:
        _point_covariances_into(lo, hi, s_inv, fcol, jf, jpt, order, bounds, c_inv, cov, lev, rows)

    in_threads(fill, len(cov))
    return cov


@njit(**_JIT)
def _image_only_leverage(s_inv, fcol, jf, rows, lev):
    w = fcol.shape[1]
    for t in range(rows.shape[0]):
        i = rows[t]
        for r in range(2):
            h = 0.0
            for j in range(w):
                cj = fcol[i, j]
                if cj < 0:
                    continue
                for k in range(w):
                    ck = fcol[i, k]
                    if ck >= 0:
                        h += jf[i, r, j] * s_inv[cj, ck] * jf[i, r, k]
            lev[2 * i + r] = h


@dataclass
class SchurParts:
    s: np.ndarray  # reduced image normal matrix (dense); empty once consumed (see factor, covariance)
    c_inv: np.ndarray  # (npt_est, 3, 3) inverse point blocks
    est_points: np.ndarray  # point indices in column order
    point_singular: np.ndarray  # (npt_est,) bool
    order: np.ndarray  # observation rows grouped by estimated point
    bounds: np.ndarray
    n_reduced: int = -1  # S's size, kept when S is consumed (-1: S's own)
    _factor: ReducedFactor | None = field(default=None, repr=False, compare=False)
    _rebuild: Callable[[], np.ndarray] | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.n_reduced < 0:
            self.n_reduced = self.s.shape[0]

    def factor(self) -> "ReducedFactor":
        """The Cholesky factor of the Jacobi-scaled S, computed once and shared by the rank
        check and the datum analysis (both need it before the solve). Where S can be computed
        again (:func:`schur` with ``rebuildable``) the factor is made in S's own memory: the
        dense S of 1,500 images is 3.5 GB, and S beside its factor was the peak of the largest
        blocks; :meth:`reduced` gives S again on the rare paths that need it after."""
        if self._factor is None:
            consume = self._rebuild is not None and self.s.flags.c_contiguous
            self._factor = ReducedFactor.of(self.s, overwrite=consume)
            if consume:
                self.s = np.zeros((0, 0))
        return self._factor

    def reduced(self) -> np.ndarray:
        """S, computed again (the same sums in the same order) when the factor consumed it."""
        if self.s.shape[0] != self.n_reduced:
            assert self._rebuild is not None, "S was consumed without a way to compute it again"
            self.s = self._rebuild()
        return self.s


@dataclass
class ReducedFactor:
    """The Jacobi-scaled reduced matrix Sn = S / outer(d, d) (d = sqrt(diag S)) and its lower
    Cholesky factor, or None when Sn is not positive definite to working precision. ``band``:
    the factor is of Sn in that band's order, in LAPACK's band storage (:mod:`solver.engine.banded`:
    a banded S of at least ``BAND_MIN_ROWS`` rows), else None and the factor is dense."""

    d: np.ndarray
    lower: np.ndarray | None
    norm1: float  # the 1-norm of Sn, for the condition estimate
    band: banded.Band | None = None

    @classmethod
    def of(cls, s: np.ndarray, overwrite: bool = False) -> "ReducedFactor":
        """``overwrite``: the dense path scales and factors in ``s``'s own memory (``s``
        C-contiguous; garbage afterwards, also when the factor fails). The band path leaves
        ``s`` unchanged."""
        d = np.sqrt(np.clip(np.diag(s), 1e-300, None))
        if s.size == 0 or (np.diag(s) <= 1e-300).any():
            return cls(d, None, 0.0)
        band = banded.use_band(s)
        if band is not None:
            ab = banded.scaled_band(s, d, band)
            return cls(d, banded.band_factor(ab), banded.band_norm1(ab), band=band)
        sn = _jacobi_scaled(s, d, overwrite)
        norm1 = max(float(np.abs(sn[:, k : k + STRIP]).sum(axis=0).max()) for k in range(0, sn.shape[1], STRIP))
        with dense_threads.for_matrix(len(d)):
            factor, info = lapack.dpotrf(sn.T, lower=1, clean=1, overwrite_a=1)  # in place (sn is symmetric)
        return cls(d, factor if info == 0 else None, norm1)

    def condition(self) -> float | None:
        """An estimate of the 1-norm condition of Sn from the factor (LAPACK's dpocon, or for a
        band the same estimator on its solves), O(n^2) or O(n b); None when Sn is not positive
        definite."""
        if self.lower is None:
            return None
        if self.band is not None:
            inverse_norm = banded.band_inverse_norm1(self.lower)
            return float("inf") if not np.isfinite(inverse_norm) or inverse_norm <= 0.0 else self.norm1 * inverse_norm
        rcond, info = lapack.dpocon(self.lower, self.norm1, uplo="L")
        return float("inf") if info != 0 or rcond <= 0.0 else 1.0 / float(rcond)

    def solve(self, u: np.ndarray) -> np.ndarray:
        """S^-1 u (``u``: (n, k)); only when the factor exists."""
        assert self.lower is not None
        if self.band is not None:
            x = banded.band_solve(self.lower, banded.to_band_order(self.band, u / self.d[:, None]))
            return banded.from_band_order(self.band, x) / self.d[:, None]
        x, _ = lapack.dpotrs(self.lower, u / self.d[:, None], lower=1)
        return x / self.d[:, None]


def schur(lin: Linearisation, problem: AdjustmentState, rebuildable: bool = False) -> SchurParts:
    """The points eliminated from the normal equations (:class:`SchurParts`). ``rebuildable``:
    S may be consumed by its factor and computed again from ``lin`` when needed
    (:meth:`SchurParts.factor`; ``lin`` and ``problem`` are then kept with the parts)."""
    lay = lin.layout
    est = np.array([p.index for p in problem.points if p.estimated], dtype=np.int64)
    pt_q = -np.ones(len(problem.points), dtype=np.int64)
    pt_q[est] = np.arange(len(est))
    a, c = _accumulate(lay.n_img_params, lin.fcol, lin.jf, lin.obs_pt, lin.jpt, pt_q, len(est))
    for pidx, (_r, w) in lin.point_prior.items():
        c[pt_q[pidx]] += np.diag(w**2)
    for labelled, c0, (_r, j) in zip(lin.terms, lin.term_col, lin.term_eval):
        if c0 < 0:  # a block without free parameters
            continue
        if labelled.block == "point":  # a term on a ground point: its 3 x 3 normal block
            c[pt_q[labelled.index]] += j.T @ j
            continue
        n = j.shape[1]
        a[c0 : c0 + n, c0 : c0 + n] += j.T @ j
    dets = np.linalg.det(c) if len(est) else np.zeros(0)
    scale = np.einsum("kii->k", c) ** 3 if len(est) else np.zeros(0)
    singular = np.abs(dets) <= 1e-14 * np.maximum(scale, 1e-300)
    c_inv = np.zeros_like(c)
    if len(est):
        c_inv[~singular] = np.linalg.inv(c[~singular])
    # observations grouped by estimated point (in the order of est)
    q_of_obs = pt_q[lin.obs_pt]
    has = np.flatnonzero(q_of_obs >= 0)
    order, bounds = grouped(q_of_obs[has], len(est))
    order = has[order]
    s = _reduce(a, lin.fcol, lin.jf, lin.jpt, order, bounds, c_inv) if len(est) else a
    parts = SchurParts(s, c_inv, est, singular, order, bounds)
    if rebuildable:
        parts._rebuild = lambda: schur(lin, problem).s
    return parts


@dataclass
class RankReport:
    deficient: bool
    condition: float
    null_parameters: list[tuple[str, float]]  # (image/param, weight in the null direction)


FAST_RANK_MARGIN = 1e-2  # the fast test accepts a condition estimate below this fraction of 1/tol


def check_rank(parts: SchurParts, names: list[str], tol: float = 1e-15, fast: bool = False) -> RankReport:
    """Eigen-analysis of the Jacobi-scaled reduced normal matrix S.

    ``fast``: first a Cholesky factorisation with LAPACK's condition estimate; when it succeeds
    with an estimated condition below ``FAST_RANK_MARGIN / tol`` the matrix is of full rank and
    that estimate is returned. (The 1-norm condition bounds the 2-norm one from above; LAPACK's
    estimate of it is a lower bound, in practice within a factor of a few, which the margin of
    100 covers.) Otherwise, and always without ``fast``, the eigen-analysis decides and names the
    parameters of the null directions; a block of 300 images takes seconds instead of minutes
    in the usual case."""
    if parts.n_reduced == 0:
        return RankReport(False, 1.0, [])
    if fast:
        estimate = parts.factor().condition()
        if estimate is not None and estimate < FAST_RANK_MARGIN / tol:
            return RankReport(False, estimate, [])
    s = parts.reduced()
    d = np.sqrt(np.clip(np.diag(s), 1e-300, None))
    sn = _jacobi_scaled(s, d)
    with dense_threads.for_matrix(len(d)):
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


STRIP = 512  # rows per strip of the dense matrices' scaling and completion


def _divide_by_outer(src: np.ndarray, d: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out = src / outer(d, d)`` in row strips: no full-size temporary (the outer product of a
    5,400-parameter block alone is 233 MB), and exactly symmetric for a symmetric ``src``
    (each entry divided by the one product d_i d_j); ``out`` may be ``src``."""
    for k in range(0, len(d), STRIP):
        out[k : k + STRIP] = src[k : k + STRIP] / np.outer(d[k : k + STRIP], d)
    return out


def _jacobi_scaled(s: np.ndarray, d: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """``s / outer(d, d)`` in one new array, or with ``overwrite`` in ``s`` itself (C-contiguous)."""
    return _divide_by_outer(s, d, s if overwrite else np.empty_like(s))


def _mirror_lower(a: np.ndarray) -> None:
    """Copy the lower triangle of the square ``a`` onto its upper one, in place (column strips,
    so no full-size temporary)."""
    n = a.shape[0]
    for k in range(0, n, STRIP):
        e = min(k + STRIP, n)
        a[k:e, e:] = a[e:, k:e].T
        upper = np.triu_indices(e - k, 1)
        a[k:e, k:e][upper] = a[k:e, k:e].T[upper]


def positive_definite_inverse(s: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """The inverse of a symmetric positive-definite matrix, as the Gram matrix ``G^T G`` of
    ``G = L^-1`` (Cholesky factor of the Jacobi-scaled matrix, LAPACK's dpotri): positive
    semi-definite by construction, so every correlation derived from it lies in [-1, 1].

    One matrix beside ``s``: the scaling, the factor, the inverse and its symmetric completion
    happen in place (a 300-image block's 5,400-square matrix is 233 MB a copy). With
    ``overwrite`` (``s`` C-contiguous) not even that: the inverse is computed in ``s``'s own
    memory, which holds the inverse afterwards (garbage when the matrix was not positive
    definite); a 1,500-image block's reduced matrix is 3.5 GB.

    Raises :class:`numpy.linalg.LinAlgError` when ``s`` is not positive definite (a singular
    or indefinite normal matrix has no covariance).
    """
    if s.size == 0:
        return s
    diag = np.diag(s)
    if not np.all(np.isfinite(s)) or np.any(diag <= 0.0):
        raise np.linalg.LinAlgError("the normal matrix is not positive definite")
    d = np.sqrt(diag)
    band = banded.use_band(s)
    if band is not None:
        return _inverse_from_band(s, d, band, overwrite)
    # the transpose of the symmetric, C-ordered scaled matrix is the same matrix in Fortran
    # order: LAPACK then works in place instead of on a copy
    work = _jacobi_scaled(s, d, overwrite and s.flags.c_contiguous).T
    with dense_threads.for_matrix(len(d)):
        factor, info = lapack.dpotrf(work, lower=1, clean=0, overwrite_a=1)
        if info != 0:
            raise np.linalg.LinAlgError("the normal matrix is not positive definite")
        # LAPACK's dpotri: L^-T L^-1 from the factor (the triangular inverse, then its product with
        # its transpose exploiting the triangles): n^3 flops instead of 3.3 n^3 for a triangular
        # solve against the identity and a full product
        inv, info = lapack.dpotri(factor, lower=1, overwrite_c=1)
    if info != 0:
        raise np.linalg.LinAlgError("the normal matrix is not positive definite")
    _mirror_lower(inv)
    inv = inv.T  # symmetric: the C-ordered view of the same array
    return _divide_by_outer(inv, d, inv)


def _inverse_from_band(s: np.ndarray, d: np.ndarray, band: banded.Band, overwrite: bool) -> np.ndarray:
    """:func:`positive_definite_inverse` of a banded ``s``: the band's Cholesky factor and the
    inverse from it (:mod:`solver.engine.banded`), put back in ``s``'s order, in ``s``'s own
    memory with ``overwrite``. Symmetric exactly; positive semi-definite to rounding (the dense
    path's Gram form is so by construction)."""
    factor = banded.band_factor(banded.scaled_band(s, d, band))
    if factor is None:
        raise np.linalg.LinAlgError("the normal matrix is not positive definite")
    if overwrite and s.flags.c_contiguous:
        out = s
    else:
        out = np.empty_like(s, order="C")
        out.fill(0.0)  # touched in order: first touches in the inverse's column strips cost seconds
    with dense_threads.for_matrix(len(d)):
        banded.inverse_from_band(factor, out)
    _mirror_lower(out)
    banded.permute_back(band, out)
    return _divide_by_outer(out, d, out)


def covariance(lin: Linearisation, parts: SchurParts, problem: AdjustmentState) -> Covariance:
    """Inverse normal-matrix blocks and observation leverages (a-priori sigma0 = 1); raises
    :class:`numpy.linalg.LinAlgError` when the reduced normal matrix is not positive definite.
    The reduced matrix is inverted in its own memory: ``parts.s`` is empty afterwards (nothing
    reads it after the covariance, and a second matrix of its size was the peak of large blocks)."""
    s, parts.s = parts.s, np.zeros((0, 0))
    s_inv = positive_definite_inverse(s, overwrite=True)
    del s
    lev = np.zeros(lin.n_obs_rows)
    points: dict[int, np.ndarray] = {}
    lay = lin.layout
    if len(parts.est_points):
        cov = _point_covariances(s_inv, lin.fcol, lin.jf, lin.jpt, parts.order, parts.bounds, parts.c_inv, lev)
        points = {int(p): cov[q] for q, p in enumerate(parts.est_points)}
    fixed_rows = np.flatnonzero(lay.pt_col[lin.obs_pt] < 0)
    if len(fixed_rows) and s_inv.size:
        _image_only_leverage(s_inv, lin.fcol, lin.jf, fixed_rows, lev)
    return Covariance(s_inv, points, lev)
