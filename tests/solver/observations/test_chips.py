"""Butted CCD chips (issue 13): chips that overlap and extend beyond the delivered image, the rule
that gives an image column its chip (solver.geometry.sensor: the covering chip whose centre column is
nearest), the optional ``chip`` of an observation, and the simulator and solver applying the
same rule."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from solver.api import run
from solver.blocks.cameras import iop_names
from solver.engine.assemble import build_problem
from solver.engine.validate import validate_job
from solver.errors import JobError
from solver.geometry.sensor import camera_chip
from solver.kernels import N_IOP, camera_model
from solver.schema.job import Camera, load_job
from solver.simulate import presets
from solver.simulate.camera import CameraSpec, ChipSpec, prism_camera
from solver.simulate.iop import CameraIOP
from solver.simulate.scene import SceneSettings

SAME_FORMULA_MM = 1e-9  # 1e-9 mm = 1.4e-7 px: the same focal-plane formula evaluated twice

# two chips of 100 columns overlapping by 32 columns (68..99), the first starting 10 columns
# before the image and the second ending 10 columns after it (image columns 0..147)
TWO = {
    "id": "two",
    "focal_mm": 1000.0,
    "pixel_mm": 0.01,
    "line_time_s": 1e-3,
    "lines": 100,
    "columns": 148,
    "chips": [
        {"id": "a", "first_column": -10, "columns": 100, "dx_mm": 0.001, "dy_mm": -0.34},
        {"id": "b", "first_column": 58, "columns": 100, "dx_mm": -0.002, "dy_mm": 0.34},
    ],
}
# chip centres 39.5 and 107.5: the overlap 58..89 splits at 73.5


def test_overlap_splits_in_the_middle_in_solver_and_simulator():
    cam = Camera(**TWO)
    spec = CameraSpec("two", 1000.0, 0.01, 1e-3, 100, 148, tuple(ChipSpec(**c) for c in TWO["chips"]))
    cols = [57.0, 58.0, 73.0, 73.4, 73.5, 73.6, 74.0, 89.0, 90.0]  # 73.5: the tie, to the later centre
    want = ["a", "a", "a", "a", "b", "b", "b", "b", "b"]
    assert [camera_chip(cam, c)[0] for c in cols] == want
    assert ["ab"[k] for k in spec.chip_of_column(np.array(cols))] == want
    # 16 of the 32 overlapping columns go to either chip; the seam the simulator avoids is there
    assert [camera_chip(cam, float(c))[0] for c in range(58, 90)].count("a") == 16
    assert list(spec.seams()) == [73.5]
    # the constants are the chip's own (centre column, dy)
    assert camera_chip(cam, 73.6) == ("b", -0.002, 0.34, 107.5)


def test_explicit_chip_overrides_the_rule():
    cam = Camera(**TWO)
    assert camera_chip(cam, 60.0)[0] == "a"
    assert camera_chip(cam, 60.0, "b") == ("b", -0.002, 0.34, 107.5)
    assert camera_chip(cam, 88.0, "a")[0] == "a"
    with pytest.raises(KeyError):
        camera_chip(cam, 40.0, "b")  # chip b starts at column 58


@pytest.fixture(scope="module")
def butted_triplet() -> tuple[dict, dict]:
    scene = presets.prism_triplet(SceneSettings(preset="prism-triplet", seed=13), chip_layout="butted")
    return scene.job(), scene.truth()


def test_prism_butted_layout_is_the_papers():
    """Seed 001 section 3: nadir chips of 4992 columns, backward/forward of 4928, neighbours
    overlapping by 32; four of them make the 14496-column image, the outer ones in part."""
    for view, width in (("nadir", 4992), ("backward", 4928), ("forward", 4928)):
        cam = prism_camera(view, "butted")
        assert [c.columns for c in cam.chips] == [width] * 4
        ends = [(c.first_column, c.first_column + c.columns - 1) for c in cam.chips]
        assert all(a[1] - b[0] + 1 == 32 for a, b in zip(ends, ends[1:]))
        assert ends[0][0] < 0 and ends[-1][1] > cam.columns - 1
        # every chip sees a column where its neighbours see it (nominal dy from the centre column)
        for c in cam.chips:
            nominal = (c.centre_column - (cam.columns - 1) / 2) * cam.pixel_mm
            assert abs(c.dy_mm - nominal) < 0.5 * cam.pixel_mm


def test_beyond_image_overlapping_chips_are_accepted(butted_triplet):
    job, _ = butted_triplet
    firsts = [c["first_column"] for cam in job["cameras"] for c in cam["chips"]]
    assert min(firsts) < 0
    result = validate_job(load_job(copy.deepcopy(job)))
    assert result["valid"], result["problems"]


def test_observation_named_chip_must_cover_its_column(butted_triplet):
    job = copy.deepcopy(butted_triplet[0])
    cam = next(c for c in job["cameras"] if c["id"] == "prism-nadir")
    k, j, m = [i for i, o in enumerate(job["observations"]) if o["image"] == "prism-nadir"][:3]
    chip2 = cam["chips"][1]
    job["observations"][k]["column"] = chip2["first_column"] - 5.0
    job["observations"][k]["chip"] = chip2["id"]
    job["observations"][j]["chip"] = "9"
    job["observations"][m]["column"] = -3.0  # on chip 1, but not a delivered column
    with pytest.raises(JobError) as e:
        run(job)
    found = {(p.code, tuple(p.location)) for p in e.value.problems}
    assert ("outside_chip", ("observations", k, "column")) in found
    assert ("unknown_chip", ("observations", j, "chip")) in found
    assert ("outside_image", ("observations", m, "column")) in found


def test_named_chip_outside_its_columns_is_a_422_with_a_pointer(tmp_path: Path, butted_triplet):
    from service.app import create_app
    from service.settings import Settings as ServiceSettings

    job = copy.deepcopy(butted_triplet[0])
    cam = job["cameras"][0]
    k = next(i for i, o in enumerate(job["observations"]) if o["image"] == cam["id"])
    job["observations"][k]["chip"] = cam["chips"][3]["id"]
    job["observations"][k]["column"] = 100.0
    settings = ServiceSettings(data_dir=tmp_path, workers=0, log_format="text")
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        r = c.post("/jobs/validate", json={"inputs": {"job": job}})
    assert r.status_code == 422, r.text[:500]
    assert r.headers["content-type"].startswith("application/problem+json")
    assert f"/inputs/job/observations/{k}/column" in [e["pointer"] for e in r.json()["errors"]]


def test_named_chip_sets_the_observation_constants(butted_triplet):
    job = copy.deepcopy(butted_triplet[0])
    cam = next(c for c in job["cameras"] if c["id"] == "prism-nadir")
    c1, c2 = cam["chips"][0], cam["chips"][1]
    overlap_col = c2["first_column"] + 3.0  # in the overlap, nearer chip 1's centre
    k, j = [i for i, o in enumerate(job["observations"]) if o["image"] == "prism-nadir"][:2]
    job["observations"][k]["column"] = overlap_col
    job["observations"][j]["column"] = overlap_col
    job["observations"][j]["chip"] = c2["id"]
    obs = build_problem(load_job(job)).obs
    assert obs.chip[k] == c1["id"] and obs.chip[j] == c2["id"]
    assert obs.oc[k][7] == c1["first_column"] + (c1["columns"] - 1) / 2  # centre columns (exact integers/2)
    assert obs.oc[j][7] == c2["first_column"] + (c2["columns"] - 1) / 2
    assert obs.chip_idx[k] == 0 and obs.chip_idx[j] == 1


def test_simulator_and_solver_map_overlap_columns_to_the_same_focal_plane_point():
    """Every quarter column across each overlap of the butted nadir camera with per-chip IOP
    errors: the simulator's pixel position (CameraSpec.image_plane) and the solver's (chip by
    camera_chip, kernels.camera_model) agree. A different chip on either side would differ by
    the chip shifts (0.02-0.03 mm, 3-4 px)."""
    errors = {"a0@1": 0.03, "b0@1": -0.02, "a0@3": -0.02, "b0@3": 0.03, "b0@4": 0.025, "a1@4": 3e-6, "delta@2": 1e-4}
    spec = prism_camera("nadir", "butted")
    spec = CameraSpec(spec.id, spec.focal_mm, spec.pixel_mm, spec.line_time_s, spec.lines, spec.columns, spec.chips, 0.0, CameraIOP(errors))
    cam = Camera(**spec.to_job())
    names = iop_names(cam)
    vec = np.zeros(N_IOP)
    for n, v in errors.items():
        vec[names.index(n)] = v
    cols = np.concatenate([np.arange(c.first_column - 1.0, c.first_column + 33.0, 0.25) for c in spec.chips[1:]])
    x_sim, y_sim, k_sim = spec.image_plane(cols)
    ids = [c.id for c in spec.chips]
    chips_seen = set()
    for col, xs, ys, ks in zip(cols, x_sim, y_sim, k_sim):
        chip_id, dx, dy, centre = camera_chip(cam, float(col))
        k = ids.index(chip_id)
        assert k == ks, col
        chips_seen.add(k)
        oc = np.array([0.0, col, 1.0, cam.focal_mm, cam.pixel_mm, dx, dy, centre, 0.0])
        xi, yi = camera_model(oc, vec, k, spec.chips[k].columns * cam.pixel_mm, float(col), False)[:2]
        assert abs(xi - xs) < SAME_FORMULA_MM and abs(yi - ys) < SAME_FORMULA_MM, col
    assert chips_seen == {0, 1, 2, 3}


def test_simulated_overlap_points_carry_the_rule_s_chip():
    """Ground points seen through each overlap of a butted camera (IOP errors shift the chips by
    3-4 px): the simulator's projection assigns every point the chip the solver's rule gives its
    column, and both chips of each overlap image some."""
    from solver.simulate.iop import default_iop
    from solver.simulate.projection import ImageGeometry
    from tests.solver.simulate.test_simulate_geometry import PLATFORM, TERRAIN

    spec = prism_camera("nadir", "butted")
    spec = CameraSpec(
        spec.id, spec.focal_mm, spec.pixel_mm, spec.line_time_s, spec.lines, spec.columns, spec.chips, 0.0,
        default_iop(spec.id, spec.focal_mm, [c.id for c in spec.chips]),
    )
    img = ImageGeometry("n", spec, PLATFORM, -(spec.lines - 1) / 2 * spec.line_time_s)
    cols = np.concatenate([np.linspace(c.first_column - 4.0, c.first_column + 36.0, 41) for c in spec.chips[1:]])
    lines = np.linspace(100.0, spec.lines - 100.0, len(cols))
    ground = img.image_to_ground(lines, cols, terrain=TERRAIN)
    pr = img.ground_to_image(ground)
    cam = Camera(**spec.to_job())
    ids = [c.id for c in spec.chips]
    inside = pr.inside
    assert inside.mean() > 0.9
    rule = [ids.index(camera_chip(cam, float(c))[0]) for c in pr.column[inside]]
    assert rule == list(pr.chip[inside])
    for j in (1, 2, 3):  # both chips of every overlap image points
        near = np.abs(pr.column[inside] - spec.seams()[j - 1]) < 20
        assert {j - 1, j} <= set(pr.chip[inside][near])


def test_butted_triplet_round_trips_through_the_simulator_and_adjusts(butted_triplet):
    """Real PRISM layout: simulated, validated, adjusted (K2, 0.5 px noise, 0.2 m survey)."""
    job, truth = butted_triplet
    cams = {c["id"]: Camera(**c) for c in job["cameras"]}
    image_camera = {im["id"]: im["camera"] for im in job["images"]}
    # the simulator's chip of each noise-free observation is the solver's rule on its column
    for o in truth["observations"]:
        assert camera_chip(cams[image_camera[o["image"]]], o["column"])[0] == o["chip"]
    report = run(copy.deepcopy(job))
    sigma0 = report["adjustment"]["sigma0_aposteriori"]
    assert 0.8 < sigma0 < 1.25  # image noise as simulated: chips and columns as the simulator's
    rmse = report["checkpoints"]["rmse_m"]
    # PRISM GSD 2.5 m; the partition layout gives ~1 m (docs/experiments.md)
    assert rmse["planimetric"] < 2.5 and rmse["u"] < 4.0, rmse
