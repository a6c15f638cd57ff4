"""Self-calibration (seed 001): recovery of known IOP errors, significance analysis, reuse."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from utils.scenes import block_job

from solver.adjust import adjust_job
from solver.observations.interior import camera_from_report
from solver.schema.job import load_job

TRUTH = {"df": 2.0, "a0@1": 0.03, "b0@1": -0.02, "a0@3": -0.03, "b0@4": 0.03}  # mm; chip 2 is the master
CAMS = ("backward", "nadir", "forward")


def triplet(seed: int):
    return block_job(
        "K2", n_triplets=1, n_tie=40, n_gcp=22, n_check=20, seed=seed, chips=4,
        iop_truth={c: dict(TRUTH) for c in CAMS}, state_sigma=(20.0, 0.05), gcp_sigma_m=0.3,
    )[0]


def rmse3d(rep) -> float:
    r = rep["checkpoints"]["rmse_m"]
    return float(np.sqrt(r["e"] ** 2 + r["n"] ** 2 + r["u"] ** 2))


@pytest.fixture(scope="module")
def calibrated():
    job = triplet(3)
    plain = adjust_job(load_job(job))
    job_sc = copy.deepcopy(job)
    job_sc["options"]["self_calibration"] = {"estimate": ["df", "a0", "b0"], "sigmas": {"a0": None, "b0": None}}
    return job_sc, plain, adjust_job(load_job(job_sc))


def test_self_calibration_recovers_known_errors_within_3_sigma(calibrated):
    _job, plain, rep = calibrated
    for cam in rep["cameras"]:
        assert cam["master_chip"] == "2"
        names = {p["name"] for p in cam["parameters"] if p["estimated"]}
        assert "a0@2" not in names and {"df", "a0@1", "b0@4"} <= names
        for p in cam["parameters"]:
            if p["estimated"]:
                assert abs(p["value"] - TRUTH.get(p["name"], 0.0)) <= 3 * p["sigma"], (cam["id"], p)
        cov = np.array(cam["iop_covariance"]["matrix"])
        assert cov.shape == (7, 7)
    assert abs(rep["adjustment"]["sigma0_aposteriori"] - 1) < 0.15
    assert plain["adjustment"]["sigma0_aposteriori"] > 2  # the unmodelled IOP errors show
    assert rmse3d(rep) < 0.5 * rmse3d(plain)


def test_significance_analysis_drops_the_parameters_simulated_as_zero():
    job = triplet(4)
    job["options"]["self_calibration"] = {
        "estimate": ["df", "a0", "b0", "a1", "b1"],
        "sigmas": {"a0": None, "b0": None, "a1": None, "b1": None},
        "significance_analysis": True,
    }
    rep = adjust_job(load_job(job))
    pa = rep["parameter_analysis"]
    assert pa["dropped"], pa
    for name in pa["dropped"]:
        assert TRUTH.get(name.split("/")[1], 0.0) == 0.0, name
    kept = {f"{c['id']}/{p['name']}" for c in rep["cameras"] for p in c["parameters"] if p["estimated"]}
    for c in CAMS:
        assert f"{c}/df" in kept and f"{c}/a0@1" in kept
    assert pa["steps"][-1]["dropped"] is None
    # every step is reported with its statistics
    assert [s["step"] for s in pa["steps"]] == list(range(len(pa["steps"])))


@pytest.mark.parametrize("use", ["fixed", "weighted"])
def test_exported_calibration_improves_a_second_triplet(calibrated, use):
    job_sc, _plain, rep = calibrated
    second = triplet(11)
    base = adjust_job(load_job(second))
    reuse = copy.deepcopy(second)
    for cam in reuse["cameras"]:
        definition = camera_from_report(job_sc, rep, cam["id"])
        cam["iop"] = definition["iop"]
        cam["iop_use"] = use
        if use == "weighted":
            cam["iop_covariance"] = definition["iop_covariance"]
    if use == "weighted":
        reuse["options"]["self_calibration"] = {"estimate": ["df", "a0", "b0"], "sigmas": {"a0": None, "b0": None}}
    rep2 = adjust_job(load_job(reuse))
    assert rmse3d(rep2) < 0.6 * rmse3d(base)
    assert rep2["adjustment"]["sigma0_aposteriori"] < 0.5 * base["adjustment"]["sigma0_aposteriori"]


def test_a_creeping_solve_names_the_nearly_undetermined_pair():
    """K2 on the simulated triplet with interior-orientation errors, df estimated and the header
    states unweighted: df and each image's flying height are nearly one direction (rho beyond
    0.9999, df sigma of hundreds of mm), Gauss-Newton creeps along it and runs out of
    iterations; the report then names that pair. Without df the solve converges and the
    warning is absent."""
    from solver.simulate import presets
    from solver.simulate.scene import SceneSettings

    job = presets.prism_triplet(SceneSettings(preset="prism-triplet", seed=1, iop_errors="default")).job()
    job["options"] = {"self_calibration": {"estimate": ["df", "a0", "b0"]}}
    rep = adjust_job(load_job(job))
    assert not rep["adjustment"]["converged"]
    creep = [w for w in rep["warnings"] if "nearly undetermined together" in w]
    assert len(creep) == 1 and "/df" in creep[0], rep["warnings"]
    df = next(p for c in rep["cameras"] for p in c["parameters"] if p["name"] == "df")
    assert df["sigma"] > 100.0 and not df["significant"]
    job["options"]["self_calibration"]["estimate"] = ["a0", "b0"]
    rep = adjust_job(load_job(job))
    assert rep["adjustment"]["converged"], rep["adjustment"]["message"]
    assert not [w for w in rep["warnings"] if "nearly undetermined together" in w]


# -- camera_from_report: the one conversion of an estimated camera (CLI and server) ----------
def _calibration(iop_covariance: dict | None) -> tuple[dict, dict]:
    camera = {
        "id": "cam", "ref": {"name": "shared/prism-nadir", "version": 2}, "iop_use": "weighted",
        "focal_mm": 1939.0, "iop": {"df": 0.1, "a0@2": 0.02},
        "iop_covariance": {"names": ["df"], "matrix": [[9.0]]},  # the prior's, of other values
    }
    entry = {"id": "cam", "iop": {"df": 0.25, "b0@1": -0.01}}
    if iop_covariance is not None:
        entry["iop_covariance"] = iop_covariance
    return {"cameras": [camera, {"id": "other", "focal_mm": 1.0}]}, {"cameras": [entry]}


def test_camera_from_report_keeps_the_job_camera_and_takes_the_estimate() -> None:
    cov = {"names": ["df", "b0@1"], "matrix": [[1e-4, 0.0], [0.0, 4e-6]]}
    job, report = _calibration(cov)
    out = camera_from_report(job, report, "cam")
    assert {k: out[k] for k in ("id", "ref", "iop_use", "focal_mm")} == {
        "id": "cam", "ref": {"name": "shared/prism-nadir", "version": 2}, "iop_use": "weighted", "focal_mm": 1939.0,
    }
    assert out["iop"] == {"df": 0.25, "a0@2": 0.02, "b0@1": -0.01}  # estimated over the job's
    assert out["iop_covariance"] == cov
    job, report = _calibration(None)
    assert "iop_covariance" not in camera_from_report(job, report, "cam")  # never the prior's


@pytest.mark.parametrize("camera_id", ["other", "missing"])
def test_camera_from_report_names_what_is_missing(camera_id: str) -> None:
    from solver.observations.interior import NoEstimatedCamera

    job, report = _calibration(None)
    with pytest.raises(NoEstimatedCamera, match=repr(camera_id)):
        camera_from_report(job, report, camera_id)
