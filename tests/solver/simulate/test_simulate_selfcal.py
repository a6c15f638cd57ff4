"""The solver's interior orientation against the simulator's (docs/models.md section 8 is the
contract between them): true IOP written into the job reproduce the simulated images, and
self-calibration on simulated triplets with known IOP errors recovers them, lowers the
check-point RMSE, and helps a second triplet when reused (seed 001 experiments 1-4)."""

from __future__ import annotations

import copy

import pytest

from solver.api import run
from solver.observations.interior import camera_from_report
from solver.schema.job import load_job
from solver.simulate.camera import prism_camera
from solver.simulate.scene import Group, Scene, SceneSettings

VIEWS = ("backward", "nadir", "forward")
EPHEMERIS = {"sigma_position_m": 10.0}  # positions weighted, velocities free (docs/models.md 9)


def _triplet(scene_job: dict, truth: dict, k: int) -> dict:
    job = copy.deepcopy(scene_job)
    group = {p["id"]: p["group"] for p in truth["points"]}
    job["images"] = [im for im in job["images"] if im["id"].endswith(f"-{k + 1:02d}")]
    ids = {im["id"] for im in job["images"]}
    job["points"] = [p for p in job["points"] if group[p["id"]] == k]
    job["observations"] = [o for o in job["observations"] if o["image"] in ids]
    job["options"] = {"ephemeris": dict(EPHEMERIS)}
    return job


def _max_residual_rms_px(report: dict) -> float:
    return max(max(im["residual_rmse"]["line_px"], im["residual_rmse"]["column_px"]) for im in report["images"])


def test_true_iop_in_the_job_reproduce_the_simulated_cameras():
    """Noise-free triplet whose cameras have every kind of IOP error: with the true values in
    camera.iop the fit is at the platform model's own level (0.05 px), without them it is not."""
    errors = {
        f"prism-{v}": {"x0": 0.01, "y0": -0.02, "df": 2.0, "k1": 2e-8, "k2": 1e-12, "sy": 3e-5, "a0@1": -0.03, "b0@3": 0.03, "a1@4": 4e-5, "b1@3": -3e-5, "delta@3": 1e-3}
        for v in VIEWS
    }
    scene = Scene(SceneSettings(preset="t", seed=7, iop_errors=errors, noise_px=0.0, gcp_sigma_m=0.0), [Group([prism_camera(v) for v in VIEWS], 22, 20, 40)]).simulate()
    job, truth = scene.job(), scene.truth()
    job["options"] = {"ephemeris": dict(EPHEMERIS)}
    nominal = run(load_job(job))
    for cam in job["cameras"]:
        cam["iop"] = {k: v for k, v in truth["cameras"][cam["id"]]["iop"].items() if v}
    true = run(load_job(job))
    assert _max_residual_rms_px(nominal) > 0.5
    assert _max_residual_rms_px(true) < 0.06
    assert true["checkpoints"]["rmse_m"]["u"] < 0.1 and true["checkpoints"]["rmse_m"]["planimetric"] < 0.3


@pytest.fixture(scope="module")
def two_triplets():
    settings = SceneSettings(preset="seed001", seed=2008, iop_errors="default")
    scene = Scene(settings, [Group([prism_camera(v) for v in VIEWS], g, c, 40) for g, c in ((22, 20), (21, 24))]).simulate()
    job, truth = scene.job(), scene.truth()
    return _triplet(job, truth, 0), _triplet(job, truth, 1), truth


def test_self_calibration_recovers_df_and_chip_shifts_and_helps_the_next_triplet(two_triplets):
    t1, t2, truth = two_triplets
    without = run(load_job(t1))
    calib = copy.deepcopy(t1)
    calib["options"]["self_calibration"] = {"estimate": ["df", "a0", "b0"]}
    with_iop = run(load_job(calib))
    estimated = [(cam["id"], p) for cam in with_iop["cameras"] for p in cam["parameters"] if p["estimated"]]
    assert len(estimated) == 3 * (1 + 2 * 3)  # df and a0, b0 of the three non-master chips
    for cam_id, p in estimated:
        true = truth["cameras"][cam_id]["iop"][p["name"]]
        assert abs(p["value"] - true) < 3 * p["sigma"], (cam_id, p, true)
    rmse0, rmse1 = without["checkpoints"]["rmse_m"], with_iop["checkpoints"]["rmse_m"]
    assert rmse1["u"] < 0.5 * rmse0["u"] and rmse1["planimetric"] < 0.5 * rmse0["planimetric"]
    # experiment 4: the exported cameras, fixed, on the second triplet
    reused = copy.deepcopy(t2)
    reused["cameras"] = [camera_from_report(calib, with_iop, c["id"]) for c in t2["cameras"]]
    r3, r4 = run(load_job(t2)), run(load_job(reused))
    assert r4["checkpoints"]["rmse_m"]["u"] < 0.5 * r3["checkpoints"]["rmse_m"]["u"]
    assert r4["checkpoints"]["rmse_m"]["planimetric"] < 0.5 * r3["checkpoints"]["rmse_m"]["planimetric"]
