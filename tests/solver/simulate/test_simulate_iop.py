"""Interior-orientation errors of simulated cameras (solver/simulate/iop.py, docs/models.md
section 8): zero errors change nothing, round trips close, and single parameters move the image
point by the amounts the equations say."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from solver.cli import main
from solver.geometry.geodesy import ecef_to_geodetic
from solver.schema.job import load_job
from solver.simulate import presets
from solver.simulate.attitude import AttitudeModel, Platform
from solver.simulate.camera import prism_camera
from solver.simulate.iop import MASTER_CHIP, CameraIOP, default_iop
from solver.simulate.orbit import EarthModel, Orbit, circular_state_over, sun_synchronous_semi_major_axis
from solver.simulate.projection import ImageGeometry
from solver.simulate.scene import SceneSettings
from solver.simulate.terrain import Terrain

SOLVER_PX = 1e-7  # the 2-D (time, scan line) solution vs the nominal projection: both solved to ~1e-9 px
SHIFT_PX = 1e-6  # a chip's b0 shift seen in its columns: the projection's iterations (~1e-8 px)
UNTOUCHED_PX = 1e-9  # the other chips do not move: the same arithmetic
FOCAL_SCALE_PX = 2e-3  # df scales every focal-plane y by (f + df) / f: to first order in the ground offset

ATOL_PX = 1e-6  # image closure, pixels
ATOL_M = 1e-4  # ground closure, 0.1 mm
PIXEL_MM = 0.0071

EARTH = EarthModel()
_A = sun_synchronous_semi_major_axis(EARTH, 98.16)
PLATFORM = Platform(
    Orbit(EARTH, circular_state_over(EARTH, -51.39, -22.12, _A, 98.16), -200.0, 200.0),
    AttitudeModel.random(np.random.default_rng(7), jitter_rad=2e-6),
)
TERRAIN = Terrain.random(np.random.default_rng(8), -51.39, -22.12)


def _image(view: str) -> ImageGeometry:
    cam = prism_camera(view)
    lead = {"forward": -45.5, "nadir": 0.0, "backward": 45.2}[view]
    return ImageGeometry(view, cam, PLATFORM, lead - (cam.lines - 1) / 2 * cam.line_time_s)

ALL_TERMS = {  # every kind of term at once, larger than real ones
    "x0": 0.01,
    "y0": -0.02,
    "df": 2.0,
    "k1": 1e-8,
    "k2": 1e-12,
    "sy": 5e-5,
    "a0@1": -0.03,
    "b0@1": 0.03,
    "a1@3": 4e-6,
    "b1@3": -3e-6,
    "a0@4": 0.03,
    "delta@3": 4e-6,
}


def _with_iop(view: str, values: dict[str, float]) -> ImageGeometry:
    img = _image(view)
    cam = dataclasses.replace(img.camera, iop=CameraIOP.from_dict(values))
    return ImageGeometry(view, cam, PLATFORM, img.first_line_time_s)


def _ground_points(img: ImageGeometry, n: int = 200, seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lines = rng.uniform(0, img.camera.lines - 1, n)
    cols = rng.uniform(0, img.camera.columns - 1, n)
    return lines, cols, img.image_to_ground(lines, cols, terrain=TERRAIN)


def test_zero_iop_errors_leave_the_documents_unchanged():
    base = presets.prism_triplet(SceneSettings(preset="prism-triplet", seed=4))
    zero = presets.prism_triplet(
        SceneSettings(preset="prism-triplet", seed=4, iop_errors={"prism-nadir": {"df": 0.0, "a0@1": 0.0}})
    )
    # exact on purpose: zero IOP take the very code path of no IOP in the same process, so the
    # documents are bit-for-bit the same on any machine
    assert json.dumps(base.job()) == json.dumps(zero.job())
    assert all(not any(c["iop"].values()) for c in zero.truth()["cameras"].values())
    # the 2-D (line and column together) solution agrees with the nominal one at zero IOP
    img = _image("nadir")
    _, _, ground = _ground_points(img, 50)
    nominal = img.ground_to_image(ground)
    for k, chip in enumerate(img.camera.chips):
        on = nominal.inside & (nominal.chip == k)
        t, y_s = img.solve_time_and_scanline(ground[on], k)
        np.testing.assert_allclose(img.line_of_time(t), nominal.line[on], atol=SOLVER_PX)
        np.testing.assert_allclose(chip.centre_column + y_s / PIXEL_MM, nominal.column[on], atol=SOLVER_PX)


@pytest.mark.parametrize("view", ["backward", "nadir", "forward"])
def test_round_trips_close_with_every_iop_term(view: str):
    img = _with_iop(view, ALL_TERMS)
    lines, cols, ground = _ground_points(img)
    proj = img.ground_to_image(ground)
    keep = proj.inside
    assert keep.mean() > 0.98  # only seam gaps may lose a point
    assert np.max(np.abs(proj.line[keep] - lines[keep])) < ATOL_PX
    assert np.max(np.abs(proj.column[keep] - cols[keep])) < ATOL_PX
    h = ecef_to_geodetic(ground)[:, 2]
    again = img.image_to_ground(proj.line[keep], proj.column[keep], height_m=h[keep])
    assert np.max(np.linalg.norm(again - ground[keep], axis=1)) < ATOL_M


def test_a_chip_shift_moves_the_image_point_by_shift_over_pixel():
    """b0 = 0.03 mm on chip 3 moves its columns by -0.03 / 0.0071 = -4.225 px and nothing else;
    a0 = 0.03 mm moves its lines by 0.03 mm / (dx/dL) (1.027 px per line at nadir)."""
    nominal = _image("nadir")
    _, _, ground = _ground_points(nominal, 300)
    p0 = nominal.ground_to_image(ground)
    shifted = _with_iop("nadir", {"b0@3": 0.03}).ground_to_image(ground)
    on3 = p0.inside & (p0.chip == 2) & shifted.inside
    others = p0.inside & (p0.chip != 2) & shifted.inside
    assert on3.sum() > 20 and others.sum() > 20
    np.testing.assert_allclose(shifted.column[on3] - p0.column[on3], -0.03 / PIXEL_MM, atol=SHIFT_PX)
    np.testing.assert_allclose(shifted.line[on3], p0.line[on3], atol=SHIFT_PX)
    np.testing.assert_allclose(shifted.column[others], p0.column[others], atol=UNTOUCHED_PX)
    # along track: the chip's pixels move forward by a0 in the focal plane
    along = _with_iop("nadir", {"a0@3": 0.03}).ground_to_image(ground)
    dl = along.line[on3] - p0.line[on3]
    assert np.all(np.abs(np.abs(dl) - 0.03 / PIXEL_MM / 1.027) < 0.05)
    assert np.max(np.abs(along.column[on3] - p0.column[on3])) < 0.01


def test_a_focal_length_change_scales_the_columns_about_the_principal_point():
    nominal = _image("nadir")
    _, _, ground = _ground_points(nominal, 100)
    p0 = nominal.ground_to_image(ground)
    df = 2.0
    p1 = _with_iop("nadir", {"df": df}).ground_to_image(ground)
    cam = nominal.camera
    k = p0.inside & p1.inside & (p0.chip == p1.chip)
    # y = -(f + df) Y / Z: the focal-plane y of every point grows by (f + df) / f
    y0 = np.array([cam.chips[c].dy_mm for c in p0.chip[k]]) + (p0.column[k] - np.array([cam.chips[c].centre_column for c in p0.chip[k]])) * PIXEL_MM
    y1 = np.array([cam.chips[c].dy_mm for c in p1.chip[k]]) + (p1.column[k] - np.array([cam.chips[c].centre_column for c in p1.chip[k]])) * PIXEL_MM
    np.testing.assert_allclose(y1, y0 * (cam.focal_mm + df) / cam.focal_mm, atol=FOCAL_SCALE_PX * PIXEL_MM)


def test_default_preset_values_and_truth_file(tmp_path, capsys):
    for view in ("backward", "nadir", "forward"):
        cam = prism_camera(view)
        iop = default_iop(cam.id, cam.focal_mm, [c.id for c in cam.chips]).full([c.id for c in cam.chips])
        assert 1.5 <= iop["df"] <= 2.5
        assert all(iop[f"{p}@{MASTER_CHIP}"] == 0.0 for p in ("a0", "b0", "a1", "b1", "delta"))
        shifts = [abs(iop[f"{p}@{c}"]) for p in ("a0", "b0") for c in ("1", "3", "4")]
        assert 0.02 <= min(shifts) and max(shifts) <= 0.03
        assert all(0 < abs(iop[f"{p}@{c}"]) <= 5e-6 for p in ("a1", "b1") for c in ("1", "3", "4"))
        assert all(iop[n] == 0.0 for n in ("x0", "y0", "k1", "k2", "sy"))
    with pytest.raises(ValueError):
        CameraIOP.from_dict({"a0": 0.1})  # a chip term needs its chip
    out = tmp_path / "t.json"
    assert main(["simulate", "prism-triplet", "-o", str(out), "--seed", "2", "--iop-errors", "default"]) == 0
    truth = json.loads((tmp_path / "t.truth.json").read_text())
    job = load_job(out.read_text())
    assert truth["settings"]["iop_errors"] == "default"
    for cam in job.cameras:  # the job has the nominal cameras, the truth the errors
        assert cam.iop == {} and cam.focal_mm == truth["cameras"][cam.id]["nominal_focal_mm"]
        t = truth["cameras"][cam.id]
        assert t["true_focal_mm"] == pytest.approx(cam.focal_mm + t["iop"]["df"])
    custom = tmp_path / "iop.json"
    custom.write_text(json.dumps({"prism-nadir": {"b0@3": 0.03}}))
    assert main(["simulate", "prism-single", "-o", str(tmp_path / "s.json"), "--iop-errors", str(custom)]) == 0
    t = json.loads((tmp_path / "s.truth.json").read_text())
    assert t["cameras"]["prism-nadir"]["iop"]["b0@3"] == 0.03 and t["cameras"]["prism-nadir"]["iop"]["df"] == 0.0
