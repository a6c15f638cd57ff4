"""Presets write valid job documents with the requested content, noise and truth."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest
from tolerances import GROUND_ROUND_TRIP_M

from solver.cli import main
from solver.geometry.geodesy import enu_rotation, to_ecef
from solver.schema.job import load_job
from solver.simulate import presets
from solver.simulate.scene import SceneSettings

NOISE_STD_REL = 0.03  # the std of ~9000 simulated 0.5-px noise values: 3 x its standard error 0.75 %
SURVEY_STD_REL = 0.12  # the std of 300 simulated 0.3-m survey errors per axis: 3 x its standard error 4 %


@pytest.fixture(scope="module")
def triplet():
    return presets.prism_triplet(SceneSettings(preset="prism-triplet", seed=11))


def _roles(job) -> Counter:
    return Counter(p.role for p in job.points)


def test_prism_single_defaults_follow_seed_000():
    scene = presets.prism_single(SceneSettings(preset="prism-single", seed=1))
    job = load_job(scene.job())
    assert _roles(job) == {"gcp": 14, "check": 9}
    assert [im.model.name for im in job.images] == ["K2"]
    assert job.cameras[0].mounting_pitch_deg == 0.0 and len(job.cameras[0].chips) == 4
    assert all(p.sigma_m == (0.2, 0.2, 0.2) for p in job.points if p.role == "gcp")
    assert len(job.images[0].ephemeris) >= 5
    # swapping the configuration keeps the same 23 points (seed 000's 14/9 and 9/14)
    other = load_job(presets.prism_single(SceneSettings(preset="prism-single", seed=1), gcps=9, checks=14).job())
    assert _roles(other) == {"gcp": 9, "check": 14}
    assert {p.id: p.coordinates for p in job.points} == {p.id: p.coordinates for p in other.points}


def test_prism_triplet_counts_and_every_point_in_three_images(triplet):
    job = load_job(triplet.job())
    assert _roles(job) == {"gcp": 22, "check": 20, "tie": 40}
    assert [c.mounting_pitch_deg for c in job.cameras] == [-23.8, 0.0, 23.8]
    truth_obs = Counter(o["point"] for o in triplet.truth()["observations"])
    assert set(truth_obs.values()) == {3}
    # the backward image is taken after the nadir one, the forward before (~45 s each)
    t = {im.camera: im.first_line_time_s for im in job.images}
    assert 40 < t["prism-backward"] - t["prism-nadir"] < 50
    assert 40 < t["prism-nadir"] - t["prism-forward"] < 50


def test_approx_state_and_ephemeris_are_perturbed_truth(triplet):
    job = load_job(triplet.job())
    truth = triplet.truth()
    for im, tim in zip(job.images, truth["images"], strict=True):
        assert tim["samples"]["line"][0] == 0.0
        dp = np.subtract(im.approx_state.position_ecef_m, tim["samples"]["position_ecef_m"][0])
        dv = np.subtract(im.approx_state.velocity_ecef_m_s, tim["samples"]["velocity_ecef_m_s"][0])
        assert 0 < np.linalg.norm(dp) < 60 and 0 < np.linalg.norm(dv) < 0.2
        times = [e.time_s for e in im.ephemeris]
        assert np.allclose(np.diff(times), 60.0) and times[0] < im.first_line_time_s < times[-1]
        # ephemeris vectors are the integrated orbit plus metre-level noise
        for e in im.ephemeris:
            r, v = triplet.orbit.state(e.time_s - triplet.settings.epoch_s)
            assert np.linalg.norm(np.subtract(e.position_ecef_m, r[0])) < 6.0
            assert np.linalg.norm(np.subtract(e.velocity_ecef_m_s, v[0])) < 0.01


def test_noise_statistics_match_the_settings():
    s = SceneSettings(preset="strip", seed=5, noise_px=0.5, gcp_sigma_m=0.3)
    scene = presets.strip(s, triplets=2, tie_points=3000, gcps=150, checks=150)
    job = scene.job()
    truth = {(o["image"], o["point"]): (o["line"], o["column"]) for o in scene.truth()["observations"]}
    d = np.array([(o["line"] - truth[o["image"], o["point"]][0], o["column"] - truth[o["image"], o["point"]][1]) for o in job["observations"]])
    assert len(d) > 9000
    assert np.std(d[:, 0]) == pytest.approx(0.5, rel=NOISE_STD_REL)
    assert np.std(d[:, 1]) == pytest.approx(0.5, rel=NOISE_STD_REL)
    assert np.all(np.abs(d.mean(axis=0)) < 0.02)
    # survey noise, measured in local east/north/up from the written coordinates
    true_pts = {p["id"]: p for p in scene.truth()["points"]}
    enu = []
    for p in job["points"]:
        if p["role"] == "tie":
            continue
        tp = true_pts[p["id"]]
        diff = to_ecef(np.array([p["coordinates"]]), job["crs"])[0] - np.array(tp["ecef_m"])
        enu.append(enu_rotation(np.radians(tp["lon_deg"]), np.radians(tp["lat_deg"])) @ diff)
    enu = np.array(enu)
    assert len(enu) == 300
    np.testing.assert_allclose(np.std(enu, axis=0), 0.3, rtol=SURVEY_STD_REL)


def test_cbers_scene_writes_sad69_utm(tmp_path):
    scene = presets.cbers_scene(SceneSettings(preset="cbers-scene", seed=2))
    job = load_job(scene.job())
    assert job.crs == "EPSG:29192"
    assert _roles(job) == {"gcp": 23, "check": 8}
    assert job.cameras[0].columns == 5812 and len(job.cameras[0].chips) == 1
    pts = [p for p in job.points if p.role != "tie"]
    xyz = np.array([p.coordinates for p in pts])
    assert np.all((xyz[:, 0] > 4e5) & (xyz[:, 0] < 7e5) & (xyz[:, 1] > 7.4e6) & (xyz[:, 1] < 7.7e6))
    # written SAD69/UTM coordinates come back to the (noisy) surveyed ECEF to the millimetre
    back = to_ecef(xyz, "EPSG:29192")
    idx = [i for i, p in enumerate(scene.points) if p.role != "tie"]
    assert np.max(np.linalg.norm(back - scene.measured_ecef_m[idx], axis=1)) < GROUND_ROUND_TRIP_M
    # ~20 m ground sample distance
    img = scene.images[0]
    g = img.image_to_ground(np.array([2900.0, 2900.0]), np.array([2900.0, 2901.0]), height_m=450.0)
    assert 18.0 < np.linalg.norm(g[1] - g[0]) < 22.0


def test_same_seed_same_documents_other_seed_other_documents():
    a = presets.prism_single(SceneSettings(preset="prism-single", seed=4)).job()
    b = presets.prism_single(SceneSettings(preset="prism-single", seed=4)).job()
    c = presets.prism_single(SceneSettings(preset="prism-single", seed=5)).job()
    # exact on purpose: the same computation twice in one process is bit-for-bit reproducible on
    # any machine (the check across machines, with tolerances, is tests/test_examples.py)
    assert json.dumps(a) == json.dumps(b)
    assert json.dumps(a) != json.dumps(c)


def test_cli_writes_job_and_truth(tmp_path, capsys):
    out = tmp_path / "nadir.json"
    rc = main(["simulate", "prism-single", "--camera", "backward", "--gcps", "6", "--checks", "3", "--seed", "3", "--model", "P1", "-o", str(out)])
    assert rc == 0
    job = load_job(out.read_text())
    truth = json.loads((tmp_path / "nadir.truth.json").read_text())
    assert _roles(job) == {"gcp": 6, "check": 3}
    assert job.images[0].model.name == "P1" and job.cameras[0].mounting_pitch_deg == -23.8
    assert truth["settings"]["seed"] == 3 and len(truth["points"]) == 9
    assert len(truth["images"][0]["samples"]["line"]) == 161  # every 100th line and the last


@pytest.mark.slow
def test_strip_scale_generation(tmp_path):
    """A strip of 60 images and 30000 tie points is generated whole (its time: bench/bench_simulate.py)."""
    scene = presets.strip(SceneSettings(preset="strip", seed=1), triplets=20, tie_points=30000)
    job = scene.job()
    assert len(scene.images) == 60
    roles = Counter(p["role"] for p in job["points"])
    assert roles["tie"] == 30000 and roles["gcp"] == 80 and roles["check"] == 40
    assert len(job["observations"]) > 0.99 * 3 * 30120
