"""Every statistic the report states, recomputed by hand from what the report itself lists.

The whitened residuals (residual / sigma_px of each observation), the check-point
discrepancies and a dense Jacobian of the same problem are the inputs; scipy gives the
distributions. A scene simulated by solver/simulate (a PRISM triplet, K2, 0.5 px noise) with
fixed control points, so the observations are the only weighted residuals and
v^T P v = sum of the squared whitened image residuals.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from tolerances import RECOMPUTED_REL, SAME_NUMBER_REL, SHAPIRO_ABS

from solver.adjust import prepare, solve_problem
from solver.engine.linalg import linearise
from solver.report.document import assess
from solver.schema.job import load_job
from solver.simulate import presets
from solver.simulate.scene import SceneSettings

# the dense inverse of the normal matrix against the solver's Schur complement: the matrix is
# ill-conditioned (pitch / along-track position, ~1e11); a missing a-posteriori scaling is 100 %
DENSE_INVERSE_REL = 1e-5
# the same sigmas from two adjustments of one scene (stated sigma_px differ): the solutions
# differ within the solver's convergence tolerance; a missing scaling is a factor of 2
TWO_SOLUTIONS_REL = 1e-3
# the total redundancy from ~400 leverages of a dense inverse equals the degrees of freedom
REDUNDANCY_DENSE_REL = 1e-6
STANDARDIZED_ABS = 1e-8  # standardized residuals near zero: the dense inverse's rounding
SUBTRACTION_M = 1e-9  # a discrepancy is estimated - known: one subtraction of ~1e4-m coordinates
MEAN_NEAR_ZERO_M = 1e-15  # means of discrepancies that may be ~0: the relative bound alone fails there

ALPHA = 0.05  # the job default (options.alpha)


def _job(sigma_px: float | None = None, seed: int = 7) -> dict:
    scene = presets.prism_triplet(
        SceneSettings(preset="prism-triplet", seed=seed, gcp_sigma_m=0.0), gcps=8, checks=8, tie_points=12
    )
    job = scene.job()
    if sigma_px is not None:  # the simulated noise stays 0.5 px; only the stated sigma changes
        for o in job["observations"]:
            o["sigma_px"] = sigma_px
    return job


def _adjust(job: dict):
    """(problem at the solution, report), through the same steps as solver.adjust.adjust_job."""
    from solver.engine.backend import SolveControl

    parsed = load_job(job)
    problem = prepare(parsed)
    outcome = solve_problem(problem, SolveControl(None, None, parsed.options.max_iterations, (0.0, 1.0)))
    assert outcome.usable and outcome.converged, outcome.message
    return problem, assess(problem, outcome)


@pytest.fixture(scope="module")
def nominal():
    return _adjust(_job())


@pytest.fixture(scope="module")
def understated():
    """sigma_px stated as 0.25 px for 0.5 px noise: sigma0 about 2."""
    return _adjust(_job(sigma_px=0.25))


@pytest.fixture(scope="module")
def overstated():
    """sigma_px stated as 1.0 px for 0.5 px noise: sigma0 about 0.5."""
    return _adjust(_job(sigma_px=1.0))


def _whitened(report: dict) -> np.ndarray:
    return np.array(
        [[o["residual_line_px"] / o["sigma_px"], o["residual_column_px"] / o["sigma_px"]] for o in report["observations"]]
    ).ravel()


def _check_chi2(report: dict) -> dict:
    adj = report["adjustment"]
    v = _whitened(report)
    assert adj["n_observations"] == len(v)  # fixed control: no other weighted residual
    dof = adj["n_observations"] - adj["n_unknowns"]
    assert adj["dof"] == dof
    chi2 = adj["chi2"]
    vtpv = float(v @ v)
    assert chi2["statistic"] == pytest.approx(vtpv / adj["sigma0_apriori"] ** 2, rel=RECOMPUTED_REL)
    assert adj["sigma0_aposteriori"] == pytest.approx(math.sqrt(vtpv / dof), rel=RECOMPUTED_REL)
    assert chi2["dof"] == dof and chi2["alpha"] == ALPHA
    assert chi2["critical"] == pytest.approx(stats.chi2.ppf(1 - ALPHA / 2, dof), rel=RECOMPUTED_REL)
    assert chi2["critical_lower"] == pytest.approx(stats.chi2.ppf(ALPHA / 2, dof), rel=RECOMPUTED_REL)
    assert chi2["passed"] is bool(chi2["critical_lower"] <= vtpv <= chi2["critical"])
    return chi2


def test_chi2_statistic_critical_values_and_verdict_pass(nominal) -> None:
    chi2 = _check_chi2(nominal[1])
    assert chi2["passed"] is True  # sigma_px states the simulated noise


def test_chi2_fails_above_when_sigma_px_is_understated(understated) -> None:
    chi2 = _check_chi2(understated[1])
    assert chi2["statistic"] > chi2["critical"] and chi2["passed"] is False


def test_chi2_fails_below_when_sigma_px_is_overstated(overstated) -> None:
    chi2 = _check_chi2(overstated[1])
    assert chi2["statistic"] < chi2["critical_lower"] and chi2["passed"] is False


def _dense_inverse_normal(problem) -> tuple[np.ndarray, np.ndarray, object]:
    """(J, (J^T J)^-1, layout) of the whitened residuals at the solution, densely."""
    lin = linearise(problem)
    jac = lin.sparse_jacobian().toarray()
    return jac, np.linalg.inv(jac.T @ jac), lin.layout


def test_every_sigma_is_scaled_by_the_a_posteriori_variance_factor(understated, nominal) -> None:
    """sigma = sigma0_aposteriori sqrt((J^T J)^-1_kk): images and tie points. With sigma_px
    misstated by 2 the factor is about 2, and the reported sigmas equal those of the job with
    the right sigma_px (the a-posteriori scaling cancels the misstatement)."""
    problem, report = understated
    s0 = report["adjustment"]["sigma0_aposteriori"]
    assert 1.6 < s0 < 2.4
    _jac, ninv, lay = _dense_inverse_normal(problem)
    # dense inverse vs the solver's Schur complement; the normal matrix is ill-conditioned
    # (pitch / along-track position, ~1e11), so 1e-5 relative
    for img, rep in zip(problem.images, report["images"]):
        specs = img.model.parameters(img.options)
        c0 = lay.img_col[img.index]
        est = [p for p in rep["parameters"] if p["estimated"]]
        assert [p["name"] for p in est] == [s.name for s in specs]
        for k, (s, p) in enumerate(zip(specs, est)):
            expected = s0 * math.sqrt(ninv[c0 + k, c0 + k]) * abs(s.to_report)
            assert p["sigma"] == pytest.approx(expected, rel=DENSE_INVERSE_REL), (img.id, s.name)
    ties = {p.id: p for p in problem.points}
    for t in report["tie_points"]:
        c = lay.pt_col[ties[t["id"]].index]
        expected = s0 * np.sqrt(np.diag(ninv)[c : c + 3])
        np.testing.assert_allclose(t["sigma_m"], expected, rtol=DENSE_INVERSE_REL)

    # the same scene with the right sigma_px: same sigmas (1e-3: the two solutions differ
    # within the solver's tolerance and the Jacobians with them; a missing scaling is 100 %)
    right = {im["id"]: im for im in nominal[1]["images"]}
    for im in report["images"]:
        for p, q in zip(im["parameters"], right[im["id"]]["parameters"]):
            if p["estimated"]:
                assert p["sigma"] == pytest.approx(q["sigma"], rel=TWO_SOLUTIONS_REL), (im["id"], p["name"])


def test_standardized_residuals_use_redundancy_numbers_of_the_dense_hat_matrix(nominal) -> None:
    """standardized = v / (sigma0_apriori sqrt(r)), r = 1 - diag(J (J^T J)^-1 J^T)."""
    problem, report = nominal
    jac, ninv, _lay = _dense_inverse_normal(problem)
    h = np.einsum("ij,jk,ik->i", jac, ninv, jac)
    r = 1.0 - h[: 2 * len(report["observations"])]
    # total redundancy is the degrees of freedom (1e-6: sum of ~400 leverages from a dense inverse)
    assert r.sum() == pytest.approx(report["adjustment"]["dof"], rel=REDUNDANCY_DENSE_REL)
    v = _whitened(report)
    s0 = report["adjustment"]["sigma0_apriori"]
    got = np.array([[o["standardized_line"], o["standardized_column"]] for o in report["observations"]], float).ravel()
    # leverages through the Schur complement vs a dense inverse of an ill-conditioned matrix
    np.testing.assert_allclose(got, v / (s0 * np.sqrt(r)), rtol=DENSE_INVERSE_REL, atol=STANDARDIZED_ABS)


def _discrepancies(report: dict) -> dict[str, np.ndarray]:
    pts = report["checkpoints"]["points"]
    return {k: np.array([p["discrepancy_m"][k] for p in pts], float) for k in ("e", "n", "u")}


def test_checkpoint_rmse_mean_std_and_gsd_forms(nominal) -> None:
    cp = nominal[1]["checkpoints"]
    assert cp["method"] == "intersection" and cp["n"] == 8
    d = _discrepancies(nominal[1])
    for p in cp["points"]:  # each discrepancy is estimated - known (1e-9 m: a subtraction)
        np.testing.assert_allclose(
            [p["discrepancy_m"][k] for k in "enu"], np.subtract(p["estimated_lgs_m"], p["known_lgs_m"]), atol=SUBTRACTION_M
        )
        assert p["discrepancy_m"]["planimetric"] == pytest.approx(math.hypot(p["discrepancy_m"]["e"], p["discrepancy_m"]["n"]), rel=SAME_NUMBER_REL)
    rmse = {k: math.sqrt(np.mean(v**2)) for k, v in d.items()}
    rmse["planimetric"] = math.sqrt(np.mean(d["e"] ** 2 + d["n"] ** 2))
    gsd = float(np.mean([im["gsd_m"] for im in nominal[1]["images"]]))
    assert cp["gsd_m"] == pytest.approx(gsd, rel=SAME_NUMBER_REL)
    for k in ("e", "n", "u", "planimetric"):  # rel 1e-12: sums of 8 squares in another order
        assert cp["rmse_m"][k] == pytest.approx(rmse[k], rel=SAME_NUMBER_REL), k
        assert cp["rmse_gsd"][k] == pytest.approx(rmse[k] / gsd, rel=SAME_NUMBER_REL), k
    for k in ("e", "n", "u"):
        assert cp["mean_m"][k] == pytest.approx(np.mean(d[k]), rel=SAME_NUMBER_REL, abs=MEAN_NEAR_ZERO_M), k
        assert cp["std_m"][k] == pytest.approx(np.std(d[k], ddof=1), rel=SAME_NUMBER_REL), k
        assert cp["mean_gsd"][k] == pytest.approx(np.mean(d[k]) / gsd, rel=SAME_NUMBER_REL, abs=MEAN_NEAR_ZERO_M), k


@pytest.mark.parametrize("fixture", ["nominal", "understated"])
def test_checkpoint_t_tests_and_shapiro_wilk_against_scipy(fixture, request) -> None:
    report = request.getfixturevalue(fixture)[1]
    cp = report["checkpoints"]
    d = _discrepancies(report)
    for k, v in d.items():
        n = len(v)
        t = cp["t_test"][k]
        statistic = np.mean(v) * math.sqrt(n) / np.std(v, ddof=1)
        critical = stats.t.ppf(1 - ALPHA / 2, n - 1)
        assert t["statistic"] == pytest.approx(statistic, rel=RECOMPUTED_REL), k
        assert t["critical"] == pytest.approx(critical, rel=SAME_NUMBER_REL) and t["dof"] == n - 1, k
        assert t["passed"] is bool(abs(statistic) <= critical), k
        sw = cp["shapiro_wilk"][k]
        w, p = stats.shapiro(v)
        assert sw["statistic"] == pytest.approx(w, abs=SHAPIRO_ABS) and sw["p_value"] == pytest.approx(p, abs=SHAPIRO_ABS), k
        assert sw["passed"] is bool(p > ALPHA), k


def _samples_with_p_between(lo: float, hi: float) -> np.ndarray:
    """20 skewed values whose scipy Shapiro-Wilk p-value lies in (lo, hi] (first seed that does)."""
    for seed in range(10_000):
        v = np.random.default_rng(seed).gamma(2.0, size=20)
        if lo < stats.shapiro(v).pvalue <= hi:
            return v
    raise AssertionError(f"no sample with p in ({lo}, {hi}]")


@pytest.mark.parametrize("alpha", [0.05, 0.01])
def test_shapiro_wilk_verdict_at_the_edges_of_alpha(alpha) -> None:
    """Normality is rejected when p <= alpha, kept when p > alpha: samples whose scipy p-value
    lies in (alpha/2, alpha] and in (alpha, 2 alpha] tell the level from half of it (the
    report's check-point discrepancies are far from the edge, so they cannot)."""
    from solver.report.statistics import shapiro_wilk

    below = _samples_with_p_between(alpha / 2, alpha)
    above = _samples_with_p_between(alpha, 2 * alpha)
    assert shapiro_wilk(below, alpha)["passed"] is False
    assert shapiro_wilk(above, alpha)["passed"] is True
    assert shapiro_wilk(below, alpha)["p_value"] == pytest.approx(stats.shapiro(below).pvalue, abs=SHAPIRO_ABS)
