"""Every platform model recovers its own truth; the registry; the report contract."""

from __future__ import annotations

import numpy as np
import pytest
from tolerances import GEODESY_M, RECOMPUTED_REL
from utils.scenes import block_job, single_image_job, truth_parameters

from solver.adjust import adjust_job
from solver.platforms import all_models, get_model, model_names
from solver.schema.job import load_job

T_TABLE_ABS = 1e-3  # the tabled Student quantile t(8; 0.975) = 2.306 has three decimals

PAPER_MODELS = ["K1", "K2", "J2-1", "J2-2", "ON1", "ON2", "P1", "P2"]
GENERAL_ORDERS = {"orders": {"X": 2, "Y": 2, "Z": 2, "omega": 0, "phi": 0, "kappa": 2}}


def assert_within_3_sigma(err: np.ndarray, sigma: np.ndarray, names: list[str]) -> None:
    """Each parameter within 3 of its reported sigmas of the truth. (A joint Mahalanobis test
    is not usable here: pitch and along-track position make the covariance ill-conditioned,
    ~1e11, and the linear covariance does not describe the curved weak direction; the
    calibration of the sigmas is tested by Monte Carlo in test_montecarlo.py.)"""
    z = err / sigma
    assert np.all(np.abs(z) <= 3.0), dict(zip(names, z.round(2)))


def test_registry_lists_every_model_of_the_papers():
    names = model_names()
    for n in PAPER_MODELS + ["GENERAL", "MT8"]:
        assert n in names
    assert get_model("mt12").name == "ON2"  # seed 002's 12-parameter model is ON2
    for m in all_models():
        d = m.describe()
        # RPC bias models (issue 17) act in image space on the image's RPC (geodetic ground)
        assert d["frame"] in ("LGS", "ECEF") or (not m.kind.has_camera and d["frame"].startswith("image"))
        assert d["parameters"] and all(p["unit"] for p in d["parameters"])
        assert d["time_variable"]
    assert [p.name for p in get_model("K2").parameters()] == ["X0", "Y0", "Z0", "ux", "uy", "uz", "omega", "phi", "kappa", "d1", "d2"]
    assert len(get_model("ON1").parameters()) == 11  # seed 000 Table 2
    assert len(get_model("P2").parameters()) == 14
    assert len(get_model("MT8").parameters()) == 8  # seed 002, first order


@pytest.mark.parametrize("model", PAPER_MODELS + ["GENERAL", "MT8", "OA-K", "OA-J2"])
@pytest.mark.parametrize("pitch", [0.0, -23.8])
def test_model_recovers_its_own_truth_within_3_sigma(model, pitch):
    opts = GENERAL_ORDERS if model == "GENERAL" else None
    job, truth = single_image_job(model, seed=6, pitch_deg=pitch, n_gcp=20 if model == "GENERAL" else 14, options=opts)
    rep = adjust_job(load_job(job))
    a = rep["adjustment"]
    assert a["converged"], a["message"]
    assert 0.5 < a["sigma0_aposteriori"] < 1.6
    tp = truth_parameters(model, np.array(truth["coef"]), job["images"][0]["model"]["options"])
    im = rep["images"][0]
    est = [p for p in im["parameters"] if p["estimated"]]
    err = np.array([p["value"] - tp[p["name"]] for p in est])
    assert_within_3_sigma(err, np.array([p["sigma"] for p in est]), [p["name"] for p in est])
    for p in im["parameters"]:
        if not p["estimated"]:  # held values are reported as given
            assert p["sigma"] is None


@pytest.mark.parametrize("model", ["K2", "J2-2", "P2", "ON2", "OA-K"])
def test_triplet_bundle_recovers_images_and_tie_points(model):
    job, truth = block_job(model, n_triplets=1, n_tie=30, n_gcp=10, n_check=6, seed=2, gcp_sigma_m=0.3)
    rep = adjust_job(load_job(job))
    for im in rep["images"]:
        tp = truth_parameters(model, np.array(truth["coef"][im["id"]]), job["images"][[i["id"] for i in job["images"]].index(im["id"])]["model"]["options"])
        est = [p for p in im["parameters"] if p["estimated"]]
        assert_within_3_sigma(
            np.array([p["value"] - tp[p["name"]] for p in est]), np.array([p["sigma"] for p in est]), [p["name"] for p in est]
        )
    tz = []
    for t in rep["tie_points"]:
        tz += list((np.array(t["lgs_m"]) - np.array(truth["points_lgs"][t["id"]])) / np.array(t["sigma_m"]))
    # tie-point errors share the images' orientation error, so their RMS over one scene scatters
    # widely between noise draws; calibration is tested by Monte Carlo. Measured over seeds 2-5
    # and the five models (2026-11-23): RMS 0.86-1.62, max 2.1-4.65, seed 2 (this one) the
    # worst for every model; RMS bound 1.5 x the worst, max bound 1.07 x (5 sigma is already
    # the largest z-score a calibrated covariance gives in 90 coordinates)
    assert np.sqrt(np.mean(np.square(tz))) < 2.4 and np.max(np.abs(tz)) < 5.0
    cp = rep["checkpoints"]
    assert cp["method"] == "intersection" and cp["n"] == 6
    assert cp["rmse_m"]["u"] is not None


def test_report_contract_fields():
    job, _ = block_job("K2", n_triplets=1, n_tie=10, n_gcp=8, n_check=4, seed=5)
    rep = adjust_job(load_job(job))
    a = rep["adjustment"]
    for k in ("n_observations", "n_unknowns", "dof", "iterations", "converged", "termination", "sigma0_aposteriori", "solve_time_s"):
        assert k in a
    assert set(a["chi2"]) >= {"statistic", "dof", "critical", "alpha", "passed"}
    assert a["dof"] == a["n_observations"] - a["n_unknowns"]
    im = rep["images"][0]
    assert {"id", "model", "parameters", "covariance"} <= set(im)
    assert set(im["parameters"][0]) >= {"name", "value", "sigma", "unit", "estimated"}
    n_est = sum(p["estimated"] for p in im["parameters"])
    assert np.array(im["covariance"]["matrix"]).shape == (n_est, n_est)
    cov = np.array(im["covariance"]["matrix"])
    sig = np.array([p["sigma"] for p in im["parameters"] if p["estimated"]])
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), sig, rtol=RECOMPUTED_REL)
    assert {"line_px", "column_px", "x_mm", "y_mm"} <= set(im["residual_rmse"])
    assert "pairs" in rep["correlations"] and rep["correlations"]["threshold"] == 0.75
    for pair in rep["correlations"]["pairs"]:
        assert abs(pair["rho"]) > 0.75
    o = rep["observations"][0]
    assert {"residual_line_px", "residual_column_px", "standardized_line", "standardized_column"} <= set(o)
    assert rep["tie_points"] and set(rep["tie_points"][0]) >= {"id", "lgs_m", "sigma_m"}
    cp = rep["checkpoints"]
    for k in ("method", "mean_m", "std_m", "rmse_m", "rmse_gsd", "t_test", "shapiro_wilk"):
        assert k in cp
    assert set(cp["rmse_m"]) == {"e", "n", "u", "planimetric", "3d"}  # "3d": issue 15
    assert cp["rmse_gsd"]["e"] == pytest.approx(cp["rmse_m"]["e"] / cp["gsd_m"])
    d = np.array([[p["discrepancy_m"][c] for c in "enu"] for p in cp["points"]])
    assert cp["rmse_m"]["3d"] == pytest.approx(np.sqrt(np.mean(np.sum(d**2, axis=1))), rel=RECOMPUTED_REL)


def test_mono_checkpoints_and_t_test_against_hand_computation():
    job, truth = single_image_job("P2", seed=8, n_check=9)
    rep = adjust_job(load_job(job))
    cp = rep["checkpoints"]
    assert cp["method"] == "mono" and cp["n"] == 9
    e = np.array([p["discrepancy_m"]["e"] for p in cp["points"]])
    assert cp["rmse_m"]["e"] == pytest.approx(np.sqrt(np.mean(e**2)))
    t = e.mean() / (e.std(ddof=1) / np.sqrt(len(e)))
    assert cp["t_test"]["e"]["statistic"] == pytest.approx(t)
    assert cp["t_test"]["e"]["critical"] == pytest.approx(2.306, abs=T_TABLE_ABS)  # t(8; 0.975)
    # mono intersection puts the point at its known height
    for p in cp["points"]:
        assert p["estimated_lgs_m"][2] == pytest.approx(p["known_lgs_m"][2], abs=GEODESY_M)
    # the chi-square bound is the paper's chi2(dof; 0.975)
    from scipy.stats import chi2

    a = rep["adjustment"]
    assert a["chi2"]["critical"] == pytest.approx(chi2.ppf(0.975, a["dof"]))


def test_standardized_residuals_use_redundancy():
    job, _ = single_image_job("P2", seed=9)
    rep = adjust_job(load_job(job))
    for o in rep["observations"]:
        w = o["residual_line_px"] / o["sigma_px"]
        # |standardized| >= |whitened residual| because the redundancy number is <= 1
        assert abs(o["standardized_line"]) >= abs(w) - 1e-12
