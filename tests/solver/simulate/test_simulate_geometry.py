"""Cameras, attitude and the exact ground <-> image mapping of the simulator."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq
from tolerances import GEODESY_M, ROTATION_ABS

from solver.geometry.geodesy import ecef_to_geodetic
from solver.simulate.attitude import AttitudeModel, Platform, opk_from_matrix, rx, ry, rz
from solver.simulate.camera import CameraSpec, ChipSpec, cbers_camera, prism_camera
from solver.simulate.orbit import EarthModel, Orbit, circular_state_over, sun_synchronous_semi_major_axis
from solver.simulate.projection import ImageGeometry
from solver.simulate.terrain import Terrain

ONE_LINE_REL = 0.05  # 100 m on the ground is ~40 lines or columns (2.5 m GSD): terrain and obliquity
GSD_REL = 5e-3  # the distance between adjacent pixels' ground points vs the camera's nominal GSD
PITCH_DEG = 1e-9  # the angle between nadir and boresight equals the pitch: arccos of unit vectors

ATOL_PX = 1e-6  # image closure, pixels
ATOL_M = 1e-4  # ground closure, 0.1 mm

EARTH = EarthModel()
A = sun_synchronous_semi_major_axis(EARTH, 98.16)
ORBIT = Orbit(EARTH, circular_state_over(EARTH, -51.39, -22.12, A, 98.16), -200.0, 200.0)
PLATFORM = Platform(ORBIT, AttitudeModel.random(np.random.default_rng(7), jitter_rad=2e-6))
TERRAIN = Terrain.random(np.random.default_rng(8), -51.39, -22.12)


def _image(view: str) -> ImageGeometry:
    cam = prism_camera(view)
    lead = {"forward": -45.5, "nadir": 0.0, "backward": 45.2}[view]
    return ImageGeometry(view, cam, PLATFORM, lead - (cam.lines - 1) / 2 * cam.line_time_s)


@pytest.mark.parametrize("camera", [prism_camera("backward"), prism_camera("nadir"), prism_camera("forward"), cbers_camera()])
def test_chip_columns_partition_the_image(camera: CameraSpec):
    cols = np.concatenate([np.arange(c.first_column, c.first_column + c.columns) for c in camera.chips])
    np.testing.assert_array_equal(np.sort(cols), np.arange(camera.columns))
    assert len(cols) == camera.columns
    # every column belongs to exactly one chip, and the chip centre sits at its nominal place
    k = camera.chip_of_column(np.arange(camera.columns))
    assert np.all(k >= 0)
    for c in camera.chips:
        nominal = (c.centre_column - (camera.columns - 1) / 2) * camera.pixel_mm
        assert abs(c.dy_mm - nominal) < 0.5 * camera.pixel_mm


def test_bad_chip_layout_is_refused():
    # chips must cover every image column; they may overlap and extend beyond the image
    with pytest.raises(ValueError):
        CameraSpec("gap", 1000, 0.01, 1e-3, 10, 100, (ChipSpec("1", 0, 40), ChipSpec("2", 50, 50)))
    with pytest.raises(ValueError):
        CameraSpec("short", 1000, 0.01, 1e-3, 10, 100, (ChipSpec("1", 0, 60),))
    CameraSpec("butted", 1000, 0.01, 1e-3, 10, 100, (ChipSpec("1", -5, 60), ChipSpec("2", 50, 60)))


def test_prism_cameras_have_table1_focal_lengths_and_pitches():
    assert prism_camera("backward").focal_mm == 1999.8762715
    assert prism_camera("nadir").focal_mm == 1999.8630195
    assert prism_camera("forward").focal_mm == 2000.0645632
    assert [prism_camera(v).mounting_pitch_deg for v in ("backward", "nadir", "forward")] == [-23.8, 0.0, 23.8]


@pytest.mark.parametrize("view", ["backward", "nadir", "forward"])
def test_ground_image_ground_round_trip(view: str):
    img = _image(view)
    rng = np.random.default_rng(3)
    lines = rng.uniform(0, img.camera.lines - 1, 300)
    cols = rng.uniform(0, img.camera.columns - 1, 300)
    ground = img.image_to_ground(lines, cols, terrain=TERRAIN)
    proj = img.ground_to_image(ground)
    keep = proj.inside
    assert keep.mean() > 0.99  # only seam gaps may lose a point
    assert np.max(np.abs(proj.line[keep] - lines[keep])) < ATOL_PX
    assert np.max(np.abs(proj.column[keep] - cols[keep])) < ATOL_PX
    # back to the ground with each point's own height
    h = ecef_to_geodetic(ground)[:, 2]
    again = img.image_to_ground(proj.line[keep], proj.column[keep], height_m=h[keep])
    assert np.max(np.linalg.norm(again - ground[keep], axis=1)) < ATOL_M
    # the point really is on the terrain
    llh = ecef_to_geodetic(ground)
    np.testing.assert_allclose(llh[:, 2], TERRAIN.height(llh[:, 0], llh[:, 1]), atol=GEODESY_M)


def test_line_solution_agrees_with_an_independent_root_finder():
    img = _image("nadir")
    pts = img.image_to_ground(np.array([100.0, 8000.0, 15900.0]), np.array([50.0, 7000.0, 14400.0]), terrain=TERRAIN)
    proj = img.ground_to_image(pts)
    for p, line, k in zip(pts, proj.line, proj.chip, strict=True):
        dx = img.camera.chips[k].dx_mm

        def g(t: float) -> float:
            return float(img.focal_plane(np.array([t]), p[None, :])[0][0] - dx)

        t = brentq(g, img.first_line_time_s - 1.0, img.first_line_time_s + 8.0, xtol=1e-14, rtol=4 * np.finfo(float).eps)
        assert img.line_of_time(t) == pytest.approx(line, abs=ATOL_PX)


def test_line_grows_along_track_and_column_along_camera_y():
    img = _image("nadir")
    p0 = img.image_to_ground(np.array([8000.0]), np.array([7000.0]), height_m=450.0)[0]
    t0 = img.time_of_line(8000.0)
    _, _, m = img.frames(np.array([t0]))
    x_c, y_c = m[0, 0], m[0, 1]
    base = img.ground_to_image(p0[None])
    ahead = img.ground_to_image((p0 + 100 * x_c)[None])
    right = img.ground_to_image((p0 + 100 * y_c)[None])
    assert ahead.line[0] - base.line[0] == pytest.approx(40, rel=ONE_LINE_REL)
    assert abs(ahead.column[0] - base.column[0]) < 1.0
    assert right.column[0] - base.column[0] == pytest.approx(40, rel=ONE_LINE_REL)
    assert abs(right.line[0] - base.line[0]) < 1.0


def test_mounting_pitch_tilts_the_boresight_along_track():
    t = np.array([0.0, 3.0])
    _, _, nadir = PLATFORM.camera_frames(t, 0.0)
    for pitch in (23.8, -23.8):
        r, v, m = PLATFORM.camera_frames(t, pitch)
        cosang = np.einsum("ni,ni->n", nadir[:, 2], m[:, 2])
        np.testing.assert_allclose(np.degrees(np.arccos(cosang)), abs(pitch), atol=PITCH_DEG)
        # forward (+) looks ahead along the velocity, backward (-) behind it
        ahead = np.einsum("ni,ni->n", -m[:, 2], v / np.linalg.norm(v, axis=1, keepdims=True))
        assert np.all(np.sign(ahead) == np.sign(pitch))
        # camera frames are right-handed rotations
        np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=ROTATION_ABS)


def test_yaw_steering_keeps_the_ccd_across_the_ground_track():
    def cross_track_drift(platform: Platform) -> float:
        cam = prism_camera("nadir")
        img = ImageGeometry("n", cam, platform, -3.0)
        centre = (cam.columns - 1) / 2
        g = img.image_to_ground(np.array([0.0, 16000.0]), np.array([centre, centre]), height_m=450.0)
        _, _, m = img.frames(np.array([img.time_of_line(8000.0)]))
        d = g[1] - g[0]
        return float(abs(d @ m[0, 1]) / abs(d @ m[0, 0]))

    steered = Platform(ORBIT, AttitudeModel(yaw_steering=True))
    fixed = Platform(ORBIT, AttitudeModel(yaw_steering=False))
    # without steering the Earth's rotation moves the track sideways by ~ omega R cos(lat) cos(i)/v
    assert cross_track_drift(fixed) > 0.03
    assert cross_track_drift(steered) < 2e-3


def test_nadir_gsd_matches_pixel_over_focal_times_height():
    img = _image("nadir")
    g = img.image_to_ground(np.array([8000.0, 8000.0]), np.array([7000.0, 7001.0]), height_m=450.0)
    r, _, _ = img.frames(np.array([img.time_of_line(8000.0)]))
    height = ecef_to_geodetic(r)[0, 2] - 450.0
    assert np.linalg.norm(g[1] - g[0]) == pytest.approx(img.camera.gsd_nadir_m(height), rel=GSD_REL)


def test_omega_phi_kappa_round_trip():
    rng = np.random.default_rng(2)
    for w, p, k in rng.uniform(-1.2, 1.2, (20, 3)):
        np.testing.assert_allclose(opk_from_matrix(rx(w) @ ry(p) @ rz(k)), (w, p, k), atol=ROTATION_ABS)


def test_terrain_stays_in_its_height_range():
    lon, lat = np.meshgrid(np.linspace(-51.8, -51.0, 200), np.linspace(-22.5, -21.7, 200))
    h = TERRAIN.height(lon, lat)
    assert h.min() >= 350.0 and h.max() <= 550.0
    assert np.ptp(h) > 100.0  # not flat
