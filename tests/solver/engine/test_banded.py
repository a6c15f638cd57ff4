"""The reduced matrix as a band (solver/engine/banded.py) against dense LAPACK and numpy.

Independent evidence: numpy's dense inverse, solve and exact 1-norms of the same matrices, and on
a connected strip the whole covariance (images, points, leverages) and the rank check of the
dense path, which shares nothing with the band path but the elimination that builds S.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import pytest
from test_report_fixtures import assert_reports_close
from utils.scenes import connected_strip_job

import solver.engine.banded as banded
from solver.adjust import prepare
from solver.engine.linalg import (
    ReducedFactor,
    SchurParts,
    _mirror_lower,
    check_rank,
    covariance,
    linearise,
    positive_definite_inverse,
    schur,
)
from solver.schema.job import load_job

# The test matrices are well conditioned (condition below 1e4 after scaling): two routes to the
# inverse agree to a few hundred ulps of its largest entry; a wrong coupling term or block
# boundary is off by the size of the entries.
INVERSE_REL = 1e-11
# The connected strip's S is ill-conditioned (pitch against along-track position, about 1e9 on
# the correlation scale): the two routes agree on the correlation scale to cond * eps.
STRIP_CORRELATION_ABS = 1e-6
STRIP_LEVERAGE_ABS = 1e-6


def _banded_spd(n: int, b: int, seed: int) -> np.ndarray:
    """A random symmetric positive-definite matrix of half-bandwidth exactly ``b``, unequal scales."""
    rng = np.random.default_rng(seed)
    a = np.zeros((n, n))
    for k in range(b + 1):
        a[np.arange(k, n), np.arange(n - k)] = rng.normal(size=n - k) * (0.3 if k else 1.0)
    s = a @ a.T + 0.5 * np.eye(n)
    scale = np.exp(rng.uniform(-3, 3, n))  # parameters of unequal units: the Jacobi scaling matters
    return s * np.outer(scale, scale)


@pytest.mark.parametrize("n,b", [(40, 0), (200, 1), (300, 7), (257, 64), (300, 65), (500, 130), (150, 149)])
def test_inverse_from_the_band_equals_the_dense_inverse(n, b):
    """Block boundaries (the block is max(b, 64) columns), a last block shorter than the others,
    a diagonal matrix and a band as wide as the matrix."""
    s = _banded_spd(n, b, seed=n + b)
    assert banded.lower_bandwidth(s) == b
    d = np.sqrt(np.diag(s))
    factor = banded.band_factor(banded.scaled_band(s, d, banded.Band(b)))
    z = banded.inverse_from_band(factor, np.full((n, n), np.nan))  # the previous content is never read
    _mirror_lower(z)
    ref = np.linalg.inv(s / np.outer(d, d))
    assert np.abs(z - ref).max() <= INVERSE_REL * np.abs(ref).max()
    assert np.array_equal(z, z.T)


def test_bandwidth_of_a_matrix_with_empty_rows_and_one_far_entry():
    s = np.diag(np.arange(1.0, 11.0))
    s[3, 3] = 0.0  # a row without any entry
    s[6, 4] = s[4, 6] = 0.1
    assert banded.lower_bandwidth(s) == 2
    s[9, 0] = s[0, 9] = 0.1
    assert banded.lower_bandwidth(s) == 9


def test_band_is_taken_only_when_narrow_and_large(monkeypatch):
    s = _banded_spd(100, 5, seed=1)
    assert banded.use_band(s) is None  # below BAND_MIN_ROWS
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 50)
    assert banded.use_band(s) == banded.Band(5)
    s[99, 0] = s[0, 99] = 1e-3  # one coupling across the matrix: a band again in another order
    band = banded.use_band(s)
    assert band is not None and band.perm is not None and band.b <= banded.BAND_MAX_SHARE * 100
    dense = _banded_spd(100, 99, seed=2)  # every entry nonzero: no order makes it a band
    assert banded.use_band(dense) is None


def _shuffled(s: np.ndarray, seed: int) -> np.ndarray:
    p = np.random.default_rng(seed).permutation(s.shape[0])
    return s[np.ix_(p, p)]


def test_a_shuffled_band_is_found_again():
    """A banded matrix with its rows and columns in random order (images listed in any order):
    reverse Cuthill-McKee finds a band of at most twice the original half-width."""
    s = _shuffled(_banded_spd(600, 10, seed=7), seed=8)
    assert banded.lower_bandwidth(s) > 300
    band = banded._reordered_band(s, limit=120)
    assert band is not None and band.b <= 20
    assert sorted(band.perm) == list(range(600))


def test_reordering_gives_up_on_a_coupled_column_and_on_a_large_pattern(monkeypatch):
    """A camera calibrated across every image couples one column with all (an arrow): no order
    makes that a narrow band, and the pattern is given up at its first strip; a pattern larger
    than PATTERN_MAX_NONZEROS is not read to its end."""
    s = _shuffled(_banded_spd(600, 10, seed=7), seed=8)
    assert banded._reordered_band(s, limit=120) is not None
    arrow = s.copy()
    arrow[:, 5] = arrow[5, :] = 0.01
    arrow[5, 5] = 1e3
    assert banded._reordered_band(arrow, limit=120) is None
    monkeypatch.setattr(banded, "PATTERN_MAX_NONZEROS", 1000)
    assert banded._reordered_band(s, limit=120) is None


def test_permute_back_puts_every_entry_in_its_place():
    rng = np.random.default_rng(9)
    n = 257
    z = rng.normal(size=(n, n))
    z = z + z.T
    band = banded.Band(3, rng.permutation(n))
    in_band_order = z[np.ix_(band.perm, band.perm)].copy()
    assert np.array_equal(banded.permute_back(band, in_band_order), z)
    u = rng.normal(size=(n, 2))
    assert np.array_equal(banded.from_band_order(band, banded.to_band_order(band, u)), u)


def test_shuffled_band_inverse_factor_and_solve(monkeypatch):
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 50)
    s = _shuffled(_banded_spd(400, 12, seed=10), seed=11)
    f = ReducedFactor.of(s.copy())
    assert f.band is not None and f.band.perm is not None and f.lower is not None
    u = np.random.default_rng(12).normal(size=(400, 2))
    ref = np.linalg.solve(s, u)
    assert np.abs(f.solve(u) - ref).max() <= INVERSE_REL * np.abs(ref).max()
    inv = positive_definite_inverse(s.copy(), overwrite=True)
    ref = np.linalg.inv(s)
    d = np.sqrt(np.diag(ref))
    assert np.abs((inv - ref) / np.outer(d, d)).max() <= INVERSE_REL


def test_band_norm1_is_the_dense_norm1():
    s = _banded_spd(120, 9, seed=2)
    s[5, 7] = s[7, 5] = -s[5, 7]  # negative entries count by their absolute value
    d = np.sqrt(np.diag(s))
    sn = s / np.outer(d, d)
    assert banded.band_norm1(banded.scaled_band(s, d, banded.Band(9))) == pytest.approx(np.abs(sn).sum(axis=0).max(), rel=1e-13)


def test_band_factor_solves_and_estimates_the_condition_as_the_dense_one(monkeypatch):
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 50)
    s = _banded_spd(400, 20, seed=3)
    band = ReducedFactor.of(s.copy())
    assert band.band is not None and band.lower is not None
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 10**9)
    dense = ReducedFactor.of(s.copy())
    assert dense.band is None
    u = np.random.default_rng(4).normal(size=(400, 3))
    ref = np.linalg.solve(s, u)
    assert np.abs(band.solve(u) - ref).max() <= INVERSE_REL * np.abs(ref).max()
    d = np.sqrt(np.diag(s))
    sn = s / np.outer(d, d)
    exact = np.abs(sn).sum(axis=0).max() * np.abs(np.linalg.inv(sn)).sum(axis=0).max()
    # both estimators are lower bounds of the exact 1-norm condition, in practice within a factor of a few
    for est in (band.condition(), dense.condition()):
        assert exact / 3 <= est <= exact * (1 + 1e-9)


@pytest.mark.parametrize("cond", [1e2, 1e6, 1e10])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_band_condition_estimate_is_a_close_lower_bound_and_deterministic(cond, seed):
    """Hager's estimate of ||A^-1||_1 on the band's solves against the exact norm of numpy's
    inverse, for conditions up to the rank check's range: a lower bound (to rounding), within a
    factor 3 (LAPACK's dpocon, the same method, is known to be within a few); the same number on
    every call, and numpy's global random state untouched (a library must not draw from it)."""
    rng = np.random.default_rng(seed)
    n, b = 300, 9
    a = _banded_spd(n, b, seed=seed)
    d = np.sqrt(np.diag(a))
    sn = a / np.outer(d, d)
    w = np.linalg.eigvalsh(sn)
    sn = sn + (w[-1] / cond - w[0] * (1 - 1e-12)) * np.eye(n)  # a shift keeps the band: condition about cond
    sn = sn * rng.uniform(0.5, 2.0)  # a seed-dependent scale
    factor = banded.band_factor(banded.scaled_band(sn, np.ones(n), banded.Band(b)))
    assert factor is not None
    exact = np.abs(np.linalg.inv(sn)).sum(axis=0).max()
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    estimates = [banded.band_inverse_norm1(factor) for _ in range(2)]
    assert np.array_equal(np.random.get_state()[1], before)
    assert estimates[0] == estimates[1]
    # measured: 0.96 to 1 + 6e-8 of the exact norm; above it only by the solves' rounding (cond * eps)
    assert exact / 3 <= estimates[0] <= exact * (1 + 1e-15 * cond)


def test_band_factor_of_an_indefinite_matrix_is_none(monkeypatch):
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 50)
    s = _banded_spd(100, 4, seed=5)
    s[40, 41] = s[41, 40] = 1.5 * np.sqrt(s[40, 40] * s[41, 41])  # a 2 x 2 minor with |rho| > 1
    f = ReducedFactor.of(s)
    assert f.band is not None and f.lower is None and f.condition() is None
    with pytest.raises(np.linalg.LinAlgError):
        positive_definite_inverse(s)


@pytest.mark.parametrize("overwrite", [False, True])
def test_positive_definite_inverse_from_the_band(monkeypatch, overwrite):
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 50)
    s = _banded_spd(300, 12, seed=6)
    ref = np.linalg.inv(s)
    inv = positive_definite_inverse(s if overwrite else s.copy(), overwrite=overwrite)
    assert inv.flags.c_contiguous
    d = np.sqrt(np.diag(ref))  # compared on the correlation scale: the parameters' units differ by e^12
    assert np.abs(inv / np.outer(d, d) - ref / np.outer(d, d)).max() <= INVERSE_REL
    if overwrite:
        assert np.shares_memory(inv, s)


def _strip_job(shuffled: bool, n_check: int) -> dict[str, Any]:
    job, _ = connected_strip_job("P2", n_triplets=12, points_per_triplet=40, n_gcp=4, n_check=n_check, seed=8)
    if shuffled:  # the images listed in random order: S is banded only in another order
        job["images"] = [job["images"][k] for k in np.random.default_rng(13).permutation(len(job["images"]))]
    return job


@functools.cache
def _strip(shuffled: bool):
    """The strip prepared and linearised (read only by the tests: each makes its own S)."""
    problem = prepare(load_job(_strip_job(shuffled, n_check=1)))
    return problem, linearise(problem)


@pytest.mark.parametrize("shuffled", [False, True])
def test_strip_covariance_from_the_band_equals_the_dense_one(monkeypatch, shuffled):
    """The whole covariance of a connected strip (its 36 images' S is banded): images, points and
    leverages through the band path equal the dense path's on the correlation scale; with the
    images listed in random order, through the band of the reordered S."""
    problem, lin = _strip(shuffled)
    calls = []
    real = banded.inverse_from_band
    monkeypatch.setattr(banded, "inverse_from_band", lambda f, out: calls.append(f.shape) or real(f, out))
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 10**9)
    dense = covariance(lin, schur(lin, problem), problem)
    assert calls == []
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 1)
    parts = schur(lin, problem)
    n = parts.s.shape[0]
    found = banded.use_band(parts.s)
    assert found is not None and 0 < found.b <= banded.BAND_MAX_SHARE * n  # a strip: banded, and narrow enough
    assert (found.perm is not None) == shuffled
    band = covariance(lin, parts, problem)
    assert calls == [(found.b + 1, n)]
    sd = np.sqrt(np.diag(dense.images))
    assert band.images.shape == dense.images.shape
    assert np.abs((band.images - dense.images) / np.outer(sd, sd)).max() < STRIP_CORRELATION_ABS
    for p, c in dense.points.items():
        sp = np.sqrt(np.diag(c))
        assert np.abs((band.points[p] - c) / np.outer(sp, sp)).max() < STRIP_CORRELATION_ABS
    np.testing.assert_allclose(band.leverage, dense.leverage, rtol=0, atol=STRIP_LEVERAGE_ABS)


def test_strip_rank_check_from_the_band(monkeypatch):
    """The fast rank check on the band factor: full rank, with a condition estimate within a
    factor 3 of the dense LAPACK estimate. Made singular (a parameter's row and column copied
    onto its neighbour's, inside the band), the band path fails the fast test as the dense one
    does, and the eigen-analysis names the same two parameters."""
    problem, lin = _strip(shuffled=False)
    from solver.procedures.single import parameter_names

    names = parameter_names(problem)
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 10**9)
    dense = check_rank(schur(lin, problem), names, fast=True)
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 1)
    parts = schur(lin, problem)
    assert parts.factor().band is not None
    band = check_rank(parts, names, fast=True)
    assert not dense.deficient and not band.deficient
    assert dense.condition / 3 <= band.condition <= dense.condition * 3

    s = schur(lin, problem).s
    s[20, :] = s[21, :]
    s[:, 20] = s[:, 21]
    singular = [SchurParts(s.copy(), np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool),
                           np.zeros(0, dtype=np.int64), np.zeros(1, dtype=np.int64)) for _ in range(2)]
    assert singular[0].factor().band is not None
    reports = [check_rank(singular[0], names, fast=True)]
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 10**9)
    reports.append(check_rank(singular[1], names, fast=True))
    for report in reports:
        assert report.deficient
        assert {names[20], names[21]} <= {n for n, _ in report.null_parameters}


def test_whole_report_through_the_band_equals_the_dense_one(monkeypatch):
    """Every number of the default report (covariances, error ellipses, reliability, leave-one-out
    check points, outlier tests, the datum analysis, correlation warnings) of a connected strip
    with its images in random order: the band path (forced) against the dense path, compared as
    the example reports are against their fixtures (tests/test_report_fixtures.py: covariances
    to 1e-5 of sqrt(C_ii C_jj), what derives from them to 1e-5 relative, the rest to 1e-9). The
    solve is the same (one thread: the same sums); the two inverses differ by about cond * eps
    (S's condition is about 1e9 on the correlation scale)."""
    import solver.engine.native as native
    from solver.api import run

    job = _strip_job(shuffled=True, n_check=2)
    monkeypatch.setenv(native.THREADS_ENV, "1")
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 10**9)
    dense = run(job)
    calls = []
    real = banded.inverse_from_band
    monkeypatch.setattr(banded, "inverse_from_band", lambda f, out: calls.append(1) or real(f, out))
    monkeypatch.setattr(banded, "BAND_MIN_ROWS", 1)
    band = run(job)
    assert calls  # the report's covariance (the outlier tests and reliability reuse its inverse)
    assert_reports_close(band, dense)
