"""``pba match-gcp`` against simulated truth: the backward/nadir/forward triplet of
tests/solver/matching/test_matching.py (20 m GSD, terrain 200-1200 m, rich texture) and a true orthophoto of
the same ground with its DEM (``solver.simulate.raster.render_ortho``: the ground texture on a
geographic grid, radiometry of its own), at orthophoto pixels finer and coarser than the
images'.

Truth of a control measurement: its control point (longitude and latitude from the
orthophoto, height from the DEM) projected with the true geometry of the image (solver/simulate,
independent of the matching).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from solver.cli import main
from solver.geometry.geodesy import ecef_to_geodetic, geodetic_to_ecef
from solver.importers.measurements_csv import read_measurements
from solver.importers.points_csv import read_points
from solver.simulate.camera import simple_camera
from solver.simulate.raster import render_image, render_ortho
from solver.simulate.scene import Group, Scene, SceneSettings

pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")]

SIZE_PX = 480
TRUTH_RMS_PX = 0.3  # radial RMS of the control measurements about their true positions
TRUTH_MAX_PX = 1.0  # no control measurement wrong by more than this
MIN_CONTROL_POINTS = 15
MARGIN_PX = 20  # orthophoto pixels beyond the nadir image's footprint
GRID = ["--grid", "8"]


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("gcp")
    cams = [simple_camera(n, 520.0, 0.013, 0.00292, SIZE_PX, SIZE_PX, p) for n, p in (("back", -20.0), ("nadir", 0.0), ("fwd", 20.0))]
    settings = SceneSettings(preset="match-test", seed=3, name="match", model="J2-2", noise_px=0.05, terrain_min_m=200.0, terrain_max_m=1200.0)
    scene = Scene(settings, [Group(cams, 8, 8, 30)]).simulate()
    (d / "sim.json").write_text(json.dumps(scene.job()))
    for i, g in enumerate(scene.images):
        data = render_image(scene, i, texture="rich", seed=3)
        with rasterio.open(d / f"sim.{g.id}.tif", "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype=data.dtype.name) as dst:
            dst.write(data, 1)
    return scene, d


def _ortho(scene, d, pixel_m: float, shift_deg: float = 0.0):
    """Orthophoto and DEM (EPSG:4326) of ``pixel_m`` over the nadir footprint."""
    nadir = scene.images[1]
    corners = np.array([0.0, SIZE_PX - 1.0])
    ll, cc = np.meshgrid(corners, corners)
    llh = ecef_to_geodetic(nadir.image_to_ground(ll.ravel(), cc.ravel(), terrain=scene.terrain))
    lat_mid = float(np.mean(llh[:, 1]))
    dlat = pixel_m / 111_320.0
    dlon = dlat / np.cos(np.radians(lat_mid))
    lons = np.arange(llh[:, 0].min() - MARGIN_PX * dlon, llh[:, 0].max() + MARGIN_PX * dlon, dlon)
    lats = np.arange(llh[:, 1].max() + MARGIN_PX * dlat, llh[:, 1].min() - MARGIN_PX * dlat, -dlat)
    grey, dem = render_ortho(scene, lons, lats, seed=5)
    transform = from_origin(lons[0] - dlon / 2 + shift_deg, lats[0] + dlat / 2, dlon, dlat)
    paths = []
    for name, arr in (("ortho", grey), ("dem", dem)):
        path = d / f"{name}-{pixel_m:g}-{shift_deg:g}.tif"
        with rasterio.open(path, "w", driver="GTiff", width=arr.shape[1], height=arr.shape[0], count=1, dtype=arr.dtype.name,
                           crs="EPSG:4326", transform=transform) as dst:
            dst.write(arr, 1)
        paths.append(path)
    return paths


@pytest.mark.parametrize("image, pixel_m", [("nadir", 15.0), ("back", 8.0), ("back", 30.0)])
def test_control_points_match_the_truth(scene_files, image, pixel_m):
    scene, d = scene_files
    ortho, dem = _ortho(scene, d, pixel_m)
    out, meas, summary = d / f"g-{image}.csv", d / f"m-{image}.csv", d / f"s-{image}.json"
    assert main(["match-gcp", str(d / f"sim.{image}.tif"), str(ortho), "--dem", str(dem), "--dem-vertical", "ellipsoid", "--job", str(d / "sim.json"),
                 "--dem-sigma", "2", "-o", str(out), "--measurements", str(meas), "--summary", str(summary), "-q", *GRID]) == 0
    points = {p["id"]: p for p in read_points(out.read_text(), out.name)}
    # survey sigmas: the orthophoto's pixel horizontally, the DEM height's sigma (its 2 m, the slope
    # times the pixel; the simulated DEM has the orthophoto's cells) vertically
    for p in points.values():
        assert p["sigma_m"][0] == pytest.approx(pixel_m, rel=0.01) and p["sigma_m"][1] == p["sigma_m"][0]
        assert 2.0 <= p["sigma_m"][2] < 2.0 + pixel_m, p
    measurements = read_measurements(meas.read_text(), meas.name)
    assert len(measurements) >= MIN_CONTROL_POINTS and all(p["role"] == "gcp" for p in points.values())
    geom = scene.images[[g.id for g in scene.images].index(image)]
    errors = []
    for m in measurements:
        true = geom.ground_to_image(geodetic_to_ecef(np.array([points[m["point"]]["coordinates"]])))
        errors.append((m["line"] - true.line[0], m["column"] - true.column[0]))
    e = np.array(errors)
    radial = np.hypot(e[:, 0], e[:, 1])
    assert float(np.sqrt(np.mean(radial**2))) < TRUTH_RMS_PX and float(radial.max()) < TRUTH_MAX_PX, e
    # the stated precision is that of the errors, within a factor 2 per axis
    stated = json.loads(summary.read_text())["sigma_px"]
    for k, axis in enumerate(("line", "column")):
        rms = float(np.sqrt(np.mean(e[:, k] ** 2)))
        assert 0.5 * rms < stated[axis] < 2.0 * rms + 0.05, (axis, stated, rms)


def _fails(argv, capsys, *words):
    assert main(argv) == 2
    err = capsys.readouterr().err
    for w in words:
        assert w in err, err


def test_bad_inputs_exit_2(scene_files, tmp_path, capsys):
    scene, d = scene_files
    ortho, dem = _ortho(scene, d, 15.0)
    base = ["match-gcp", str(d / "sim.nadir.tif"), "--job", str(d / "sim.json"), "-o", str(tmp_path / "g.csv"),
            "--measurements", str(tmp_path / "m.csv"), "-q"]
    _fails([*base, str(ortho)], capsys, "--dem", "--height")
    _fails([*base, str(d / "sim.back.tif"), "--height", "500"], capsys, "georeferenced")
    far, far_dem = _ortho(scene, d, 15.0, shift_deg=1.0)
    _fails([*base, str(far), "--dem", str(far_dem), "--dem-vertical", "ellipsoid"], capsys, "does not fall")
    _fails([*base, str(ortho), "--dem", str(dem)], capsys, "does not state its vertical datum", "egm96")
    cut = tmp_path / "cut.tif"
    cut.write_bytes(ortho.read_bytes()[:2000])
    _fails([*base, str(cut), "--dem", str(dem), "--dem-vertical", "ellipsoid"], capsys, "cut.tif")


def test_pba_job_adds_control_from_the_orthophoto_in_one_step(scene_files, tmp_path, capsys, monkeypatch):
    """``pba job ... --control-from ORTHO --control-image ID=RASTER --dem DEM``: the job composed
    from its sources gains the control ``pba match-gcp`` finds (one step instead of two), each
    point in EPSG:4979 with the DEM's survey sigmas, named after its image; the measurements
    land where the simulation's true geometry puts those ground points."""
    import shlex

    from solver.matching.gcp import GCP_CRS

    scene, d = scene_files
    ortho, dem = _ortho(scene, d, 15.0)
    assert main(["job-sources", str(d / "sim.json"), "-o", str(tmp_path)]) == 0
    call = shlex.split(capsys.readouterr().err.strip().splitlines()[-1])[2:-2]  # pba job <call> -o job.json
    monkeypatch.chdir(tmp_path)
    before = json.loads((d / "sim.json").read_text())
    assert main(["job", *call, "--control-from", str(ortho), "--control-image", f"back={d / 'sim.back.tif'}",
                 "--control-image", f"nadir={d / 'sim.nadir.tif'}", "--dem", str(dem), "--dem-vertical", "ellipsoid",
                 "--dem-sigma", "2", "-o", "job.json"]) == 0
    err = capsys.readouterr().err
    assert "control from the orthophoto in back:" in err and "control from the orthophoto in nadir:" in err, err
    job = json.loads((tmp_path / "job.json").read_text())
    added = [p for p in job["points"] if p["id"].startswith(("back.G", "nadir.G"))]
    assert len(job["points"]) == len(before["points"]) + len(added)
    for image in ("back", "nadir"):
        points = {p["id"]: p for p in added if p["id"].startswith(f"{image}.")}
        assert len(points) >= MIN_CONTROL_POINTS
        assert all(p["role"] == "gcp" and p["crs"] == GCP_CRS and p["sigma_m"][0] == pytest.approx(15.0, rel=0.01) for p in points.values())
        rows = [m for m in job["observations"] if m["point"] in points]
        assert {m["image"] for m in rows} == {image} and len(rows) == len(points)
        geom = scene.images[[g.id for g in scene.images].index(image)]
        e = np.array([(m["line"], m["column"]) for m in rows]) - np.array(
            [(t.line[0], t.column[0]) for t in (geom.ground_to_image(geodetic_to_ecef(np.array([points[m["point"]]["coordinates"]]))) for m in rows)])
        assert float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) < TRUTH_RMS_PX, e


def test_pba_job_control_from_needs_the_terrain_and_an_image(scene_files, tmp_path, capsys, monkeypatch):
    scene, d = scene_files
    ortho, _dem = _ortho(scene, d, 15.0)
    assert main(["job-sources", str(d / "sim.json"), "-o", str(tmp_path)]) == 0
    import shlex

    call = shlex.split(capsys.readouterr().err.strip().splitlines()[-1])[2:-2]
    monkeypatch.chdir(tmp_path)
    assert main(["job", *call, "--control-from", str(ortho), "-o", "job.json"]) == 2
    assert "--control-image" in capsys.readouterr().err
    assert main(["job", *call, "--control-from", str(ortho), "--control-image", f"back={d / 'sim.back.tif'}", "-o", "job.json"]) == 2
    assert "--dem DEM or --control-height" in capsys.readouterr().err
