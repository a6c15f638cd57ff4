"""The reduced normal matrix as a band: its Cholesky factor, condition estimate and inverse.

The reduced matrix S of a strip (images listed along it, each point seen by neighbouring
images) is banded: an image's parameters couple only with those of the images that share its
points. A 1,515-image strip's S is 21,200 columns square with a half-bandwidth of about 130.
Its dense Cholesky factor costs n^3/3 flops (43 s on one core) and the dense inverse twice
that again; the band factor costs n b^2 (LAPACK's ``dpbtrf``, a fraction of a second) and the
full inverse from it about n^2 b (:func:`inverse_from_band`, in blocks of BLAS-3 products).

Images listed in another order than along the strip, or several strips side by side, give a
matrix that is a band only in another order: :func:`use_band` then tries the reverse
Cuthill-McKee order of its nonzero pattern, the band is taken in that order and the inverse put
back in the matrix's (:func:`permute_back`).

Used by :class:`solver.engine.linalg.ReducedFactor` and
:func:`solver.engine.linalg.positive_definite_inverse` when :func:`use_band` says so (a matrix
of at least :data:`BAND_MIN_ROWS` rows whose band is at most :data:`BAND_MAX_SHARE` of its
width, in either order); every other matrix keeps the dense path. All matrices here are the Jacobi-scaled S
(unit diagonal); the band is stored as LAPACK's lower band storage: ``ab[k, j] = A[j + k, j]``
for ``0 <= k <= b``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack, solve_triangular

BAND_MIN_ROWS = 1500
"""Rows from which the band is looked for (below, the dense factor and inverse take
milliseconds and the band's bookkeeping gains nothing)."""

BAND_MAX_SHARE = 0.2
"""The half-bandwidth, as a share of the rows, up to which the band path is taken (the band
inverse's n^2 b against the dense n^3: a clear gain below a fifth)."""

ROW_STRIP = 512  # rows per strip of the bandwidth scan (a strip's comparison is 512 n bytes)


def lower_bandwidth(s: np.ndarray) -> int:
    """The largest ``i - j`` with ``s[i, j] != 0`` (``s`` square and symmetric: its half-bandwidth),
    from the first nonzero entry of every row; in row strips, so no full-size temporary."""
    n = s.shape[0]
    b = 0
    for k in range(0, n, ROW_STRIP):
        rows = s[k : k + ROW_STRIP, : min(n, k + ROW_STRIP)]
        nonzero = rows != 0.0
        first = np.where(nonzero.any(axis=1), nonzero.argmax(axis=1), np.arange(k, k + rows.shape[0]))
        b = max(b, int((np.arange(k, k + rows.shape[0]) - first).max(initial=0)))
    return b


@dataclass(frozen=True)
class Band:
    """How to see a matrix as a band: its half-bandwidth ``b`` in the order ``perm`` (row and
    column ``j`` of the band are ``perm[j]`` of the matrix; None: the matrix's own order)."""

    b: int
    perm: np.ndarray | None = None


def use_band(s: np.ndarray) -> Band | None:
    """The band of ``s`` when the band path is worth taking (see the module), else None: in the
    matrix's own order when that band is narrow enough (a strip's images listed along it), else
    in the reverse Cuthill-McKee order of its nonzero pattern when that one is (images listed in
    any order, several strips side by side)."""
    n = s.shape[0]
    if n < BAND_MIN_ROWS:
        return None
    limit = int(BAND_MAX_SHARE * n)
    b = lower_bandwidth(s)
    if b <= limit:
        return Band(b)
    return _reordered_band(s, limit)


PATTERN_MAX_NONZEROS = 50_000_000
"""Nonzeros of a pattern the reordering reads at most (400 MB of indices; a 1,515-image strip's
S has 5.5 million, a block of 1,500 images 40 wide about 25 million)."""


def _reordered_band(s: np.ndarray, limit: int) -> Band | None:
    """The reverse Cuthill-McKee order of the nonzero pattern of ``s`` and its half-bandwidth,
    when that is at most ``limit``. The pattern is read in row strips and given up at the first
    row with more nonzeros than a band of half-width ``limit`` holds (a dense matrix costs one
    strip), or beyond :data:`PATTERN_MAX_NONZEROS`."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    n = s.shape[0]
    rows, cols, nnz = [], [], 0
    for k in range(0, n, ROW_STRIP):
        nonzero = s[k : k + ROW_STRIP] != 0.0
        if nonzero.sum(axis=1).max(initial=0) > 2 * limit + 1:
            return None
        r, c = np.nonzero(nonzero)
        nnz += len(r)
        if nnz > PATTERN_MAX_NONZEROS:
            return None
        rows.append((r + k).astype(np.int32))
        cols.append(c.astype(np.int32))
    r, c = np.concatenate(rows), np.concatenate(cols)
    pattern = sp.csr_matrix((np.ones(len(r), dtype=np.int8), (r, c)), shape=(n, n))
    perm = reverse_cuthill_mckee(pattern, symmetric_mode=True).astype(np.int64)
    position = np.empty(n, dtype=np.int64)
    position[perm] = np.arange(n)
    b = int(np.abs(position[r] - position[c]).max(initial=0))
    return Band(b, perm) if b <= limit else None


def scaled_band(s: np.ndarray, d: np.ndarray, band: Band) -> np.ndarray:
    """The lower band of ``s / outer(d, d)`` in the band's order, in LAPACK's band storage, (b + 1, n)."""
    n = s.shape[0]
    ab = np.zeros((band.b + 1, n))
    if band.perm is None:
        for k in range(band.b + 1):
            ab[k, : n - k] = np.diagonal(s, -k) / (d[k:] * d[: n - k])
        return ab
    p = band.perm
    for k in range(band.b + 1):
        ab[k, : n - k] = s[p[k:], p[: n - k]] / (d[p[k:]] * d[p[: n - k]])
    return ab


def to_band_order(band: Band, u: np.ndarray) -> np.ndarray:
    """The rows of ``u`` in the band's order."""
    return u if band.perm is None else u[band.perm]


def from_band_order(band: Band, x: np.ndarray) -> np.ndarray:
    """The rows of ``x`` (in the band's order) back in the matrix's order."""
    if band.perm is None:
        return x
    out = np.empty_like(x)
    out[band.perm] = x
    return out


def permute_back(band: Band, z: np.ndarray) -> np.ndarray:
    """A symmetric ``z`` computed in the band's order put back in the matrix's order, in place:
    ``z[perm[i], perm[j]]`` becomes what ``z[i, j]`` was (the rows moved along the cycles of the
    permutation with two spare rows, then each row's columns gathered)."""
    if band.perm is None:
        return z
    p = band.perm
    n = len(p)
    held, displaced = np.empty(n), np.empty(n)  # the row on its way, the row it replaces
    done = np.zeros(n, dtype=bool)
    for start in range(n):  # row i goes to row p[i]: follow each cycle once
        if done[start] or p[start] == start:
            done[start] = True
            continue
        held[:] = z[start]
        i = start
        while not done[i]:
            done[i] = True
            target = p[i]
            displaced[:] = z[target]
            z[target] = held
            held, displaced = displaced, held
            i = target
    position = np.empty(n, dtype=np.int64)
    position[p] = np.arange(n)
    for i in range(n):  # column j of the new row is column position[j] of the moved one
        z[i] = z[i, position]
    return z


def band_norm1(ab: np.ndarray) -> float:
    """The 1-norm (largest column sum of absolute values) of the symmetric matrix whose lower band is ``ab``."""
    b1, n = ab.shape
    col = np.abs(ab).sum(axis=0)  # the diagonal and below, per column j
    for k in range(1, b1):  # above the diagonal of column j: row j's entries left of it, A[j, j - k]
        col[k:] += np.abs(ab[k, : n - k])
    return float(col.max(initial=0.0))


def band_factor(ab: np.ndarray) -> np.ndarray | None:
    """The lower Cholesky factor in band storage (``dpbtrf``), or None when the matrix is not
    positive definite to working precision. ``ab`` is left unchanged."""
    factor, info = lapack.dpbtrf(ab, lower=1)
    return factor if info == 0 else None


def band_solve(factor: np.ndarray, u: np.ndarray) -> np.ndarray:
    """A^-1 u from the band factor (``u``: (n,) or (n, k))."""
    x, info = lapack.dpbtrs(factor, u, lower=1)
    if info != 0:
        raise ValueError(f"dpbtrs: illegal argument {-info}")
    return x


HAGER_STEPS = 5  # LAPACK's dlacn2 stops after five steps of the search as well


def band_inverse_norm1(factor: np.ndarray) -> float:
    """An estimate of ||A^-1||_1 from the band factor: Hager's method as LAPACK's ``dlacn2``
    (which ``dpocon`` uses) runs it, on the solves with the factor (A^-1 is symmetric, so its
    transpose's solves are the same). Deterministic, with no random start: the same matrix gives
    the same estimate, and no random state is touched. Like LAPACK's it is a lower bound, in
    practice within a small factor."""
    n = factor.shape[1]
    x = np.full(n, 1.0 / n)
    y = band_solve(factor, x)
    estimate = float(np.abs(y).sum())
    if n == 1:
        return estimate
    sign = np.where(y >= 0.0, 1.0, -1.0)
    z = band_solve(factor, sign)
    j = int(np.argmax(np.abs(z)))
    for _ in range(HAGER_STEPS - 1):
        e = np.zeros(n)
        e[j] = 1.0
        y = band_solve(factor, e)
        new = float(np.abs(y).sum())
        new_sign = np.where(y >= 0.0, 1.0, -1.0)
        if new <= estimate or np.array_equal(new_sign, sign):
            estimate = max(estimate, new)
            break
        estimate, sign = new, new_sign
        z = band_solve(factor, sign)
        j_last, j = j, int(np.argmax(np.abs(z)))
        if abs(z[j_last]) == abs(z[j]):
            break
    # LAPACK's last test: an alternating vector of growing entries, for matrices the search misses
    alt = np.where(np.arange(n) % 2 == 0, 1.0, -1.0) * (1.0 + np.arange(n) / (n - 1))
    return max(estimate, 2.0 * float(np.abs(band_solve(factor, alt)).sum()) / (3.0 * n))


def _block_of_factor(factor: np.ndarray, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """``L[r0:r1, c0:c1]`` as a dense array, L the lower factor in band storage."""
    b = factor.shape[0] - 1
    rows = np.arange(r0, r1)[:, None]
    cols = np.arange(c0, c1)[None, :]
    k = rows - cols
    inside = (k >= 0) & (k <= b)
    return np.where(inside, factor[np.clip(k, 0, b), cols], 0.0)


def inverse_from_band(factor: np.ndarray, out: np.ndarray) -> np.ndarray:
    """The lower triangle of the inverse Z = L^-T L^-1 of A = L L^T (L in band storage,
    half-bandwidth b) into ``out`` (n x n, C-ordered; its previous content is never read, its
    upper triangle is left as it was except in the diagonal blocks: the caller mirrors it).

    From Z L = L^-T, whose part below the diagonal is zero: for a block of columns J with the
    columns K = [end of J, end of J + b) after it (the only ones L couples to J), the rows R
    below J satisfy Z[R, J] L[J, J] = -Z[R, K] L[K, J], and the diagonal block
    Z[J, J] = (L[J, J]^-T - Z[J, K] L[K, J]) L[J, J]^-1 (the diagonal blocks of L^-1 are the
    inverses of L's). Taken from the last block to the first, Z[R, K] is known each time (K
    lies in the next block, whose diagonal block is full and whose rows below are filled).
    Work: about n^2 (b + block) flops in one matrix product per block, against the dense
    inverse's n^3."""
    b = factor.shape[0] - 1
    n = factor.shape[1]
    nb = max(b, 64)
    for j0 in reversed(range(0, n, nb)):
        j1 = min(j0 + nb, n)
        k1 = min(n, j1 + b)
        lower = _block_of_factor(factor, j0, k1, j0, j1)
        l_jj, l_kj = lower[: j1 - j0], lower[j1 - j0 :]
        inv_jj = solve_triangular(l_jj, np.eye(j1 - j0), lower=True, check_finite=False)
        if j1 < n:
            z_rj = out[j1:, j1:k1] @ (-(l_kj @ inv_jj))  # Z[R, J]
            out[j1:, j0:j1] = z_rj
            z_jj = (inv_jj.T - z_rj[: k1 - j1].T @ l_kj) @ inv_jj
        else:
            z_jj = inv_jj.T @ inv_jj
        out[j0:j1, j0:j1] = 0.5 * (z_jj + z_jj.T)
    return out
