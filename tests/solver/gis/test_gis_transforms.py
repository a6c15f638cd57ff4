"""Ground <-> image transforms with the adjusted rigorous model (solver/gis/model.py,
solver/gis/transforms.py, ``pba ground-to-image`` / ``pba image-to-ground``).

Evidence: the simulator's truth (an independent implementation of the pushbroom geometry), the
adjustment's own residuals in the report, round trips, the kernels' analytic derivatives, pyproj.
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from tolerances import GROUND_ROUND_TRIP_M, ROUND_TRIP_PX
from utils.gis_scenes import MODEL_KINDS, VIEWS, prism_butted, single_chip

from solver.cli import main
from solver.geometry.geodesy import ecef_to_geodetic, from_ecef, to_ecef
from solver.gis.transforms import ground_to_image_table
from solver.kernels import project

RESIDUAL_PX = 1e-6  # a report's residual is observed - projected: the projection recomputed here
INTERSECTION_HEIGHT_M = 1e-5  # image_to_ground at a height returns that height (intersection tolerance 1e-6 m)

SIGMA_LINE_REL = 0.01  # a point's line sigma propagated by the module vs J C J^T by hand (linearised at another point)
CSV_PX = 1e-9  # pixel coordinates written to CSV and read back

# The adjusted model differs from the simulated truth by the adjustment's error (0.05 px
# measurement noise, 16 control points, the model's approximation of the attitude): < 0.1 px
# measured for every kind and view. 0.2 px catches any half-pixel convention error.
TRUTH_TOL_PX = 0.2


@pytest.mark.parametrize("kind", list(MODEL_KINDS))
@pytest.mark.parametrize("view", list(VIEWS))
def test_ground_to_image_agrees_with_the_simulated_truth(kind, view):
    scene, _job, _report, model = single_chip(MODEL_KINDS[kind], VIEWS[view])
    truth = scene.images[0]
    pts = np.array([p.ecef_m for p in scene.points])
    expected = truth.ground_to_image(pts)
    line, col, chip = model.image("cam").ground_to_image(pts)
    assert np.all(chip == 0)
    assert np.max(np.abs(line - expected.line)) < TRUTH_TOL_PX
    assert np.max(np.abs(col - expected.column)) < TRUTH_TOL_PX


def test_image_to_ground_agrees_with_the_simulated_truth_in_our_pixel_convention():
    """Pixel (0, 0) is the centre of the top-left pixel for the simulator and for us: the
    corner pixels' centres land where the simulator puts them (< 0.2 px of ground), and
    GDAL's corner convention (+0.5 px) would be 0.5 px away."""
    scene, _job, _report, model = single_chip("J2-2")
    truth = scene.images[0]
    img = model.image("cam")
    gsd_m = 20.0  # ~ 520 mm focal length, 13 um pixels, 800 km range
    line = np.array([0.0, 0.0, 2399.0, 2399.0, 1200.0])
    col = np.array([0.0, 2399.0, 0.0, 2399.0, 1200.0])
    ours = img.image_to_ground(line, col, 450.0)
    theirs = truth.image_to_ground(line, col, height_m=450.0)
    assert np.max(np.linalg.norm(ours - theirs, axis=1)) < TRUTH_TOL_PX * gsd_m
    shifted = img.image_to_ground(line + 0.5, col + 0.5, 450.0)
    assert np.min(np.linalg.norm(shifted - theirs, axis=1)) > 0.4 * gsd_m


def test_projection_reproduces_the_reports_residuals():
    """observed - projected(known gcp) with the rebuilt model = the report's residual (the
    report's value is computed by the adjustment at its solution: 1e-6 px is the Newton
    tolerance of both projections)."""
    _scene, job, report, model = single_chip("OA-J2", 20.0)
    img = model.image("cam")
    crs = job.get("crs", "EPSG:4979")
    known = {p["id"]: to_ecef(np.array([p["coordinates"]]), p.get("crs") or crs) for p in job["points"] if p.get("coordinates")}
    # weighted control points: the adjusted position (report control_points) is the projected one
    known.update({p["id"]: np.array([p["ecef_m"]]) for p in report.get("control_points") or []})
    n = 0
    for o in report["observations"]:
        if o["role"] != "gcp":
            continue
        line, col, _ = img.ground_to_image(known[o["point"]])
        assert abs((o["line"] - line[0]) - o["residual_line_px"]) < RESIDUAL_PX
        assert abs((o["column"] - col[0]) - o["residual_column_px"]) < RESIDUAL_PX
        n += 1
    assert n >= 10


@pytest.mark.parametrize("kind", list(MODEL_KINDS))
def test_round_trip_ground_image_ground(kind):
    _scene, _job, _report, model = single_chip(MODEL_KINDS[kind], 20.0)
    img = model.image("cam")
    rng = np.random.default_rng(1)
    line, col = rng.uniform(0, 2399, 50), rng.uniform(0, 2399, 50)
    h = rng.uniform(200, 700, 50)
    ground = img.image_to_ground(line, col, h)
    assert np.max(np.abs(ecef_to_geodetic(ground)[:, 2] - h)) < INTERSECTION_HEIGHT_M
    line2, col2, _ = img.ground_to_image(ground)
    assert np.max(np.abs(line2 - line)) < ROUND_TRIP_PX
    assert np.max(np.abs(col2 - col)) < ROUND_TRIP_PX


def test_multi_chip_image_round_trip_and_chip_assignment():
    scene, _job, _report, model = prism_butted()
    img = model.image(scene.images[0].id)
    truth = scene.images[0]
    pts = np.array([p.ecef_m for p in scene.points])
    expected = truth.ground_to_image(pts)
    line, col, chip = img.ground_to_image(pts)
    assert np.array_equal(chip, expected.chip)
    assert np.max(np.abs(line - expected.line)) < TRUTH_TOL_PX
    assert np.max(np.abs(col - expected.column)) < TRUTH_TOL_PX
    h = ecef_to_geodetic(pts)[:, 2]
    back = img.image_to_ground(line, col, h)
    assert np.max(np.linalg.norm(back - pts, axis=1)) < GROUND_ROUND_TRIP_M


def test_propagated_line_sigma_matches_the_kernels_analytic_derivatives():
    """sigma_line by central differences (transforms.py) = sqrt(J C J^T) with J from the
    projection kernel's implicit-function derivatives (to 1 %: difference step 1e-3 sigma)."""
    scene, _job, report, model = single_chip("J2-2")
    img = model.image("cam")
    ecef = scene.points[0].ecef_m
    llh = ecef_to_geodetic(ecef[None, :])[0]
    rows = ground_to_image_table(img, [{"lon": llh[0], "lat": llh[1], "height": llh[2]}], sigmas=True)
    im = img.image
    line0 = rows[0]["line"]
    rec = img._record(0, line0, 1200.0)
    oc = rec[6:15].copy()
    out = project(im.kind, im.coef(), im.kc, model.problem.frame.to_lgs(ecef), oc, True)
    dl_dc = out[3]
    specs = im.model.parameters(im.options)
    jac = np.array([dl_dc[s.index] / s.to_report for s in specs])
    cov = np.array(next(e for e in report["images"] if e["id"] == "cam")["covariance"]["matrix"])
    sigma = float(np.sqrt(jac @ cov @ jac))
    assert rows[0]["sigma_line_px"] == pytest.approx(sigma, rel=SIGMA_LINE_REL)
    assert sigma > 0.001


def _write_csv(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_cli_ground_to_image_and_back_with_another_crs(tmp_path, capsys):
    scene, job, report, model = single_chip("J2-2")
    (tmp_path / "job.json").write_text(json.dumps(job))
    (tmp_path / "report.json").write_text(json.dumps(report))
    pts = np.array([p.ecef_m for p in scene.points[:5]])
    llh = ecef_to_geodetic(pts)
    _write_csv(tmp_path / "pts.csv", [{"lon": a, "lat": b, "height": c} for a, b, c in llh])
    args = [str(tmp_path / "job.json"), str(tmp_path / "report.json"), "--image", "cam"]
    assert main(["ground-to-image", *args, str(tmp_path / "pts.csv"), "-o", str(tmp_path / "px.csv")]) == 0
    px = _read_csv(tmp_path / "px.csv")
    assert list(px[0])[:5] == ["lon", "lat", "height", "line", "column"]
    line, col, _ = model.image("cam").ground_to_image(pts)
    assert np.allclose([float(r["line"]) for r in px], line, atol=CSV_PX, rtol=0)
    # back to the ground, in UTM 22S (EPSG:32722: columns e, n beside the given height)
    assert main(["image-to-ground", *args, str(tmp_path / "px.csv"), "--crs", "EPSG:32722"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    rows = list(csv.DictReader(out))
    en = np.array([[float(r["e"]), float(r["n"])] for r in rows])
    expected = from_ecef(pts, "EPSG:32722")[:, :2]
    assert np.max(np.abs(en - expected)) < GROUND_ROUND_TRIP_M


def test_cli_image_to_ground_with_a_dem(tmp_path):
    """--dem: the intersection lands on the DEM's surface (a constant-slope DEM in UTM)."""
    import rasterio
    from rasterio.transform import from_origin

    scene, job, report, model = single_chip("J2-2")
    (tmp_path / "job.json").write_text(json.dumps(job))
    (tmp_path / "report.json").write_text(json.dumps(report))
    centre = from_ecef(scene.points[0].ecef_m[None, :], "EPSG:32722")[0]
    x0, y0 = centre[0] - 40000, centre[1] + 40000
    cols = np.arange(800)
    dem = np.tile(300.0 + 0.2 * cols, (800, 1)).astype("float32")  # 0.2 m per 100 m eastwards
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=800, height=800, count=1, dtype="float32", crs="EPSG:32722", transform=from_origin(x0, y0, 100, 100)) as dst:
        dst.write(dem, 1)
    _write_csv(tmp_path / "px.csv", [{"line": 1200, "column": c} for c in (300, 1200, 2100)])
    args = [str(tmp_path / "job.json"), str(tmp_path / "report.json"), "--image", "cam"]
    assert main(["image-to-ground", *args, str(tmp_path / "px.csv"), "--dem", str(tmp_path / "dem.tif"), "--dem-vertical", "ellipsoid", "-o", str(tmp_path / "g.csv"), "--crs", "EPSG:32722"]) == 0
    rows = _read_csv(tmp_path / "g.csv")
    for r in rows:
        e, h = float(r["e"]), float(r["height"])
        expected_h = 300.0 + 0.2 * ((e - x0) / 100.0 - 0.5)  # pixel centres at x0 + 50 + 100 k
        assert abs(h - expected_h) < 0.01


def test_cli_names_the_bad_row(tmp_path, capsys):
    _scene, job, report, _model = single_chip("J2-2")
    (tmp_path / "job.json").write_text(json.dumps(job))
    (tmp_path / "report.json").write_text(json.dumps(report))
    (tmp_path / "pts.csv").write_text("lon,lat,height\n-51.1,-22.3,400\n-51.1,abc,400\n")
    assert main(["ground-to-image", str(tmp_path / "job.json"), str(tmp_path / "report.json"), "--image", "cam", str(tmp_path / "pts.csv")]) == 2
    assert "row 2, column 'lat'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["ground-to-image", str(tmp_path / "job.json"), str(tmp_path / "report.json"), "--image", "nope", str(tmp_path / "pts.csv")])
    assert exc.value.code == 2
    assert "no image 'nope'" in capsys.readouterr().err


def test_cli_export_geojson(tmp_path, capsys):
    """Footprint polygons contain the image's points; checks carry the report's discrepancies."""
    _scene, job, report, _model = single_chip("J2-2")
    (tmp_path / "job.json").write_text(json.dumps(job))
    (tmp_path / "report.json").write_text(json.dumps(report))
    assert main(["export-geojson", str(tmp_path / "job.json"), str(tmp_path / "report.json")]) == 0
    doc = json.loads(capsys.readouterr().out)
    feats = doc["features"]
    foot = [f for f in feats if f["properties"]["kind"] == "footprint"]
    assert len(foot) == 1
    from matplotlib.path import Path as Polygon

    ring = Polygon(foot[0]["geometry"]["coordinates"][0])
    points = [f for f in feats if f["geometry"]["type"] == "Point"]
    assert len(points) == len(job["points"])
    assert all(ring.contains_point(f["geometry"]["coordinates"]) for f in points)
    checks = {c["id"]: c["discrepancy_m"] for c in report["checkpoints"]["points"]}
    for f in points:
        if f["properties"]["kind"] == "check":
            assert f["properties"]["discrepancy_m"] == checks[f["properties"]["id"]]
        if f["properties"]["kind"] == "control":
            assert len(f["properties"]["residuals_px"]) == 1 and f["properties"]["rms_residual_px"] is not None
