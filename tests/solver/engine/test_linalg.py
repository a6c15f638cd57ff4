"""Covariance and leverages by Schur elimination against a direct dense inverse of J^T J."""

from __future__ import annotations

import numpy as np
import pytest
from tolerances import REDUNDANCY_SUM_ABS
from utils.scenes import block_job

from solver.adjust import prepare
from solver.engine.linalg import covariance, linearise, schur
from solver.schema.job import load_job

# covariances on the correlation scale: position-pitch coupling makes N ill-conditioned
# (cond ~5e11), so any route loses about that many digits (cond * eps ~ 1e-4)
CORRELATION_ABS = 1e-4
LEVERAGE_ABS = 1e-3  # leverages without state priors: the same conditioning
LEVERAGE_PRIOR_ABS = 1e-5  # with weighted states the normal matrix is better conditioned


@pytest.mark.parametrize("model,state_sigma", [("P2", None), ("K2", (20.0, 0.05))])
def test_schur_covariance_equals_direct_inverse(model, state_sigma):
    job, _ = block_job(model, n_triplets=1, n_tie=12, n_gcp=8, n_check=3, seed=4, gcp_sigma_m=0.5, state_sigma=state_sigma)
    problem = prepare(load_job(job))
    lin = linearise(problem)
    parts = schur(lin, problem)
    cov = covariance(lin, parts, problem)
    jac = lin.sparse_jacobian().toarray()
    assert jac.shape[0] == len(lin.residuals)
    # reference: SVD of the column-scaled Jacobian (the most accurate route)
    d = np.sqrt((jac**2).sum(axis=0))
    _u, sv, vt = np.linalg.svd(jac / d, full_matrices=False)
    q = (vt.T / sv**2) @ vt / np.outer(d, d)
    n = lin.layout.n_img_params

    def same(a, b):
        s = np.sqrt(np.outer(np.diag(b), np.diag(b)))
        assert np.max(np.abs(a - b) / s) < CORRELATION_ABS

    same(cov.images, q[:n, :n])
    for pidx, c in cov.points.items():
        c0 = lin.layout.pt_col[pidx]
        same(c, q[c0 : c0 + 3, c0 : c0 + 3])
    h = np.einsum("ij,jk,ik->i", jac[: lin.n_obs_rows], q, jac[: lin.n_obs_rows])
    np.testing.assert_allclose(cov.leverage, h, atol=LEVERAGE_ABS if state_sigma is None else LEVERAGE_PRIOR_ABS)
    # redundancy numbers add up to the degrees of freedom (with the prior rows)
    h_all = np.einsum("ij,jk,ik->i", jac, q, jac)
    assert (1 - h_all).sum() == pytest.approx(jac.shape[0] - jac.shape[1], abs=REDUNDANCY_SUM_ABS)



def _parts_of(s: np.ndarray):
    from solver.engine.linalg import SchurParts

    return SchurParts(s, np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool), np.zeros(0, dtype=np.int64), np.zeros(1, dtype=np.int64))


def _spd_with_condition(n: int, cond: float, seed: int, null: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    w = np.geomspace(1.0, 1.0 / cond, n)
    w[:null] = 0.0
    s = (q * w) @ q.T
    return 0.5 * (s + s.T)


@pytest.mark.parametrize("cond", [1e2, 1e6, 1e10])
def test_fast_rank_check_agrees_with_the_eigen_analysis_on_full_rank_matrices(cond):
    """The Cholesky + LAPACK condition estimate path says "full rank" where the eigen-analysis
    does, with a condition estimate within a factor 10 of the exact 2-norm condition of the
    Jacobi-scaled matrix (LAPACK's 1-norm estimate: independent evidence is numpy's cond)."""
    from solver.engine.linalg import check_rank

    s = _spd_with_condition(60, cond, seed=3)
    names = [f"p{i}" for i in range(60)]
    fast, exact = check_rank(_parts_of(s), names, fast=True), check_rank(_parts_of(s), names)
    assert not fast.deficient and not exact.deficient
    d = np.sqrt(np.diag(s))
    true = np.linalg.cond(s / np.outer(d, d))
    assert true / 10 <= fast.condition <= true * 60 * 10  # the 1-norm condition is at most n times the 2-norm one


def test_fast_rank_check_falls_back_to_naming_the_null_parameters():
    """A singular matrix fails the fast test; the eigen-analysis then names the parameters of
    the null direction (here: parameter 7 has no information at all except through 8)."""
    from solver.engine.linalg import check_rank

    s = _spd_with_condition(30, 1e3, seed=5)
    s[7, :] = s[8, :]
    s[:, 7] = s[:, 8]  # columns 7 and 8 identical: one null direction along e7 - e8
    names = [f"p{i}" for i in range(30)]
    report = check_rank(_parts_of(s), names, fast=True)
    assert report.deficient
    assert {"p7", "p8"} <= {n for n, _ in report.null_parameters}


def test_a_factor_that_consumed_a_singular_matrix_leaves_the_rank_check_unchanged():
    """With S computable again (the adjustment's rank stage), the factor is made in S's memory;
    on a singular S it fails, and the eigen-analysis runs on S computed again: the same null
    parameters and condition as with S kept."""
    from solver.engine.linalg import check_rank

    s = _spd_with_condition(30, 1e3, seed=5)
    s[7, :] = s[8, :]
    s[:, 7] = s[:, 8]
    names = [f"p{i}" for i in range(30)]
    kept = check_rank(_parts_of(s.copy()), names, fast=True)
    parts = _parts_of(s.copy())
    rebuilt = []
    parts._rebuild = lambda: rebuilt.append(1) or s.copy()
    assert parts.factor().lower is None and parts.s.size == 0  # failed, in S's own memory
    report = check_rank(parts, names, fast=True)
    assert rebuilt == [1]  # computed again once, for the eigen-analysis
    assert report.deficient and report.null_parameters == kept.null_parameters
    assert report.condition == pytest.approx(kept.condition, rel=1e-9)  # the same eigen-analysis of the same matrix


# The threaded passes split rows between threads: residuals, Jacobians, point covariances,
# leverages and intersections are computed row by row either way (equal to the bit); the reduced
# normal matrix adds the threads' shares in range order, i.e. in another order than one thread's
# running sum: equal to rounding of its largest entries.
REDUCED_REL = 1e-12


def test_threaded_passes_equal_one_thread(monkeypatch):
    import solver.engine.native as native
    from solver.engine.initialize import intersect_estimated_points

    job, _ = block_job("P2", n_triplets=2, n_tie=40, n_gcp=6, n_check=2, seed=7, state_sigma=(20.0, 0.05))
    real = native.ThreadPoolExecutor

    def passes(threads: int):
        monkeypatch.setenv(native.THREADS_ENV, str(threads))
        monkeypatch.setattr(native, "PARALLEL_MIN_ROWS", 7)  # several threads on a small block
        calls = []

        class Counting(real):
            def submit(self, fn, *args):
                calls.append(args)
                return super().submit(fn, *args)

        monkeypatch.setattr(native, "ThreadPoolExecutor", Counting)
        problem = prepare(load_job(job))  # intersects the tie points
        intersect_estimated_points(problem)  # again: the same rays
        lin = linearise(problem)
        parts = schur(lin, problem)
        s = parts.s.copy()
        cov = covariance(lin, parts, problem)
        xyz = np.array([p.xyz for p in problem.points])
        return lin, s, cov, xyz, calls

    one = passes(1)
    two = passes(2)
    assert one[4] == [] and len(two[4]) >= 8  # intersections, observations, reduction, covariances
    for name in ("res_obs", "jf", "fcol", "jpt", "ok"):
        np.testing.assert_array_equal(getattr(one[0], name), getattr(two[0], name), err_msg=name)
    np.testing.assert_allclose(two[1], one[1], rtol=0, atol=REDUCED_REL * np.abs(one[1]).max())
    np.testing.assert_array_equal(one[3], two[3])
    # the covariance starts from the reduced matrices above (last digits apart): compare on the
    # correlation scale as the Schur test above
    np.testing.assert_allclose(two[2].leverage, one[2].leverage, atol=LEVERAGE_PRIOR_ABS)
    for pidx, c in one[2].points.items():
        s = np.sqrt(np.outer(np.diag(c), np.diag(c)))
        assert np.max(np.abs(two[2].points[pidx] - c) / s) < CORRELATION_ABS


@pytest.mark.parametrize("shuffled", [False, True])
def test_threaded_elimination_into_bands_equals_one_thread(monkeypatch, shuffled):
    """Above PARALLEL_MAX_REDUCED parameters a thread eliminates its points into a copy of the
    band of S they touch (a connected strip's S is banded): the same S as one thread, to the
    rounding of the running sum. The limit is lowered so that the whole S is wider than it and
    the second range's band is not: the banded path is the one taken. ``shuffled``: the job
    lists its points (and observations) in random order, as matched tie points come; the points
    are still eliminated along the strip, so the band stays narrow."""
    from utils.scenes import connected_strip_job

    import solver.engine.linalg as linalg
    import solver.engine.native as native

    job, _ = connected_strip_job("P2", n_triplets=4, points_per_triplet=60, n_gcp=4, n_check=1, seed=3)
    if shuffled:
        rng = np.random.default_rng(5)
        job["points"] = [job["points"][k] for k in rng.permutation(len(job["points"]))]
        job["observations"] = [job["observations"][k] for k in rng.permutation(len(job["observations"]))]
    problem = prepare(load_job(job))
    lin = linearise(problem)
    monkeypatch.setattr(native, "PARALLEL_MIN_ROWS", 7)
    monkeypatch.setenv(native.THREADS_ENV, "1")
    one = schur(lin, problem).s.copy()
    monkeypatch.setenv(native.THREADS_ENV, "2")
    parts = schur(lin, problem)  # with the full-width limit: full copies (as before bands existed)
    ranges = native.thread_ranges(len(parts.est_points))
    assert len(ranges) == 3
    first, last = linalg._point_column_span(parts.order, parts.bounds, lin.fcol)
    seq = np.argsort(first, kind="stable")
    c0, c1 = linalg._column_band(first, last, seq, ranges[1], ranges[2])
    assert 0 < c1 - c0 < one.shape[0]  # the second half of the strip's points: a band, not all of S
    monkeypatch.setattr(linalg, "PARALLEL_MAX_REDUCED", c1 - c0)
    eliminated = []
    real = linalg._reduce_into

    def counting(q_lo, q_hi, s, *args):
        eliminated.append((q_lo, q_hi, s.shape[0]))
        return real(q_lo, q_hi, s, *args)

    monkeypatch.setattr(linalg, "_reduce_into", counting)
    banded = schur(lin, problem).s
    assert sorted(eliminated) == [(0, ranges[1], one.shape[0]), (ranges[1], ranges[2], c1 - c0)]
    np.testing.assert_allclose(banded, one, rtol=0, atol=REDUCED_REL * np.abs(one).max())


def test_b_times_is_the_normal_matrix_block_of_the_sparse_jacobian():
    """B V from the observation blocks (linalg.b_times, used by the datum analysis) equals
    J_f^T J_p V with J the full sparse Jacobian (independent assembly, image rows only: the
    priors do not couple images and points); 1e-9 relative protects against a dropped or
    transposed Jacobian block, far above rounding."""
    from solver.engine.linalg import b_times

    job, _ = block_job("P2", n_triplets=1, n_tie=12, n_gcp=8, n_check=3, seed=4, gcp_sigma_m=0.5)
    problem = prepare(load_job(job))
    lin = linearise(problem)
    parts = schur(lin, problem)
    jac = lin.sparse_jacobian().toarray()[: lin.n_obs_rows]
    n = lin.layout.n_img_params
    v = np.random.default_rng(3).standard_normal((len(parts.est_points), 3, 7))
    v_cols = np.zeros((jac.shape[1], 7))
    for q, p in enumerate(parts.est_points):
        c0 = lin.layout.pt_col[p]
        v_cols[c0 : c0 + 3] = v[q]
    expected = jac[:, :n].T @ (jac @ v_cols)
    got = b_times(lin, parts, v)
    assert np.max(np.abs(got - expected)) <= 1e-9 * np.max(np.abs(expected))
