"""The quantiles and the Shapiro-Wilk test of solver.quality.distributions against scipy.stats
(the independent evidence: scipy.stats' own distribution objects and its Fortran AS R94)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import optimize, stats
from tolerances import SHAPIRO_ABS

from solver.quality import distributions as d

# the special functions are the ones scipy.stats evaluates: equal up to a few ulps of rounding
QUANTILE_REL = 1e-12
# the non-centrality: scipy's root finder against cdflib's inversion (each to ~1e-12 relative)
NONCENTRALITY_REL = 1e-9

LEVELS = [1e-6, 1e-3, 0.025, 0.05, 0.5, 0.975]
DOFS = [1, 2, 3, 6, 29, 1000, 199_934]


@pytest.mark.parametrize("dof", DOFS)
def test_chi2_quantiles(dof: int) -> None:
    for p in LEVELS:
        assert d.chi2_quantile(p, dof) == pytest.approx(stats.chi2.ppf(p, dof), rel=QUANTILE_REL)
        assert d.chi2_upper_quantile(p, dof) == pytest.approx(stats.chi2.isf(p, dof), rel=QUANTILE_REL)


@pytest.mark.parametrize("dof", DOFS)
def test_t_f_beta_normal_quantiles(dof: int) -> None:
    for p in LEVELS:
        assert d.t_quantile(p, dof) == pytest.approx(stats.t.ppf(p, dof), rel=QUANTILE_REL)
        assert d.f_quantile(p, 3, dof) == pytest.approx(stats.f.ppf(p, 3, dof), rel=QUANTILE_REL)
        assert d.beta_quantile(p, 1.5, dof / 2.0) == pytest.approx(stats.beta.ppf(p, 1.5, dof / 2.0), rel=QUANTILE_REL)
        assert d.normal_quantile(p) == pytest.approx(stats.norm.ppf(p), rel=QUANTILE_REL)


@pytest.mark.parametrize(("alpha0", "beta", "dim"), [(0.001, 0.8, 1), (0.001, 0.8, 2), (0.05, 0.8, 3), (1e-4, 0.9, 6), (0.01, 0.5, 1)])
def test_noncentrality_is_the_root_of_the_power_equation(alpha0: float, beta: float, dim: int) -> None:
    crit = stats.chi2.isf(alpha0, dim)
    expected = optimize.brentq(lambda lam: stats.ncx2.sf(crit, dim, lam) - beta, 1e-9, 1e4, xtol=1e-14)
    assert d.chi2_noncentrality(d.chi2_upper_quantile(alpha0, dim), dim, beta) == pytest.approx(expected, rel=NONCENTRALITY_REL)


def test_noncentrality_of_the_textbook_case() -> None:
    # Baarda: alpha0 = 0.001, beta = 0.80, one dimension: sqrt(lambda0) = 3.29 + 0.84 (two-digit values)
    assert np.sqrt(d.chi2_noncentrality(d.chi2_upper_quantile(0.001, 1), 1, 0.8)) == pytest.approx(4.13, abs=0.01)


def _samples(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    return [rng.standard_normal(n) * 3 + 10, rng.standard_exponential(n), rng.uniform(size=n), rng.standard_t(2, size=n)]


@pytest.mark.parametrize("n", [*range(3, 30), 31, 50, 100, 500, 3000])
def test_shapiro_wilk_equals_as_r94(n: int) -> None:
    rng = np.random.default_rng(n)
    for x in _samples(rng, n):
        w, p = d.shapiro_wilk(x)
        expected = stats.shapiro(x)
        assert w == pytest.approx(expected.statistic, abs=SHAPIRO_ABS)
        assert p == pytest.approx(expected.pvalue, abs=SHAPIRO_ABS)


def test_shapiro_wilk_rejects_what_it_should() -> None:
    # a power check that does not lean on scipy: exponential samples of 200 are rejected, normal
    # ones accepted about 95 % of the time at alpha 0.05 (400 draws: 95 % +- 3 sigma of 1.1 %)
    rng = np.random.default_rng(7)
    assert all(d.shapiro_wilk(rng.standard_exponential(200))[1] < 1e-6 for _ in range(20))
    accepted = np.mean([d.shapiro_wilk(rng.standard_normal(40))[1] > 0.05 for _ in range(400)])
    assert 0.95 - 3 * 0.011 <= accepted <= 0.95 + 3 * 0.011


def test_shapiro_wilk_coefficients_are_antisymmetric_with_unit_norm() -> None:
    for n in (3, 4, 5, 6, 7, 12, 100):
        a = d.shapiro_wilk_coefficients(n)
        assert np.linalg.norm(a) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(a, -a[::-1], atol=1e-15)


def test_shapiro_wilk_refuses_what_it_cannot_test() -> None:
    with pytest.raises(ValueError):
        d.shapiro_wilk(np.array([1.0, 2.0]))
    with pytest.raises(ValueError):
        d.shapiro_wilk(np.full(5, 3.0))
