"""Orthorectification (``pba ortho``, solver/gis/ortho.py) of a synthetic raster
(``pba simulate --raster``, solver/simulate/raster.py): every marked target is found in the
orthoimage within 0.5 GSD of its ground coordinates, with the rigorous model and with the
fitted RPC through GDAL's warper (rasterio's reproject with RPCs: the ``gdalwarp -rpc`` of
docs/how-to/export-gis.md); the two orthoimages agree."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from pyproj import Transformer
from rasterio.transform import from_origin
from utils.gis_scenes import single_chip

from solver.cli import main
from solver.geometry.geodesy import ecef_to_geodetic, to_ecef
from solver.simulate.raster import render_image

GSD_M = 20.0  # the scene's ground sample distance (520 mm, 13 um, ~800 km)
CRS = "EPSG:32722"
pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")]


@pytest.fixture(scope="module")
def ortho_inputs(tmp_path_factory):
    scene, job, report, _model = single_chip("J2-2")
    d = tmp_path_factory.mktemp("ortho")
    (d / "job.json").write_text(json.dumps(job))
    (d / "report.json").write_text(json.dumps(report))
    data = render_image(scene, 0)
    with rasterio.open(d / "cam.tif", "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype="uint8") as dst:
        dst.write(data, 1)
    # the scene's terrain as a DEM (ellipsoidal heights, geographic, 0.002 deg ~ 200 m)
    llh = ecef_to_geodetic(np.array([p.ecef_m for p in scene.points]))
    lon0, lat1 = llh[:, 0].min() - 0.5, llh[:, 1].max() + 0.5
    step = 0.002
    n = int(1.0 / step) + 1
    lons = lon0 + (np.arange(n) + 0.5) * step
    lats = lat1 - (np.arange(n) + 0.5) * step
    lo, la = np.meshgrid(lons, lats)
    h = scene.terrain.height(lo.ravel(), la.ravel()).reshape(lo.shape).astype("float32")
    with rasterio.open(d / "dem.tif", "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs="EPSG:4326", transform=from_origin(lon0, lat1, step, step)) as dst:
        dst.write(h, 1)
    targets = [(p["id"], p["coordinates"], p.get("crs") or job.get("crs", "EPSG:4979")) for p in job["points"] if p["role"] in ("gcp", "check")]
    return d, targets


def _find_targets(path, targets):
    """Centroid of each target's bright blob (above the texture) near its known position; the
    distances in metres."""
    with rasterio.open(path) as src:
        img = src.read(1).astype(float)
        inv = ~src.transform
        crs = src.crs.to_string()
    dist = []
    for _id, coords, pcrs in targets:
        ecef = to_ecef(np.array([coords]), pcrs)
        llh = ecef_to_geodetic(ecef)[0]
        x, y = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(llh[0], llh[1])
        col, row = inv.a * x + inv.b * y + inv.c, inv.d * x + inv.e * y + inv.f
        r0, c0 = int(row), int(col)
        if not (8 <= r0 < img.shape[0] - 8 and 8 <= c0 < img.shape[1] - 8):
            continue
        win = img[r0 - 7 : r0 + 8, c0 - 7 : c0 + 8]
        w = np.clip(win - 150.0, 0.0, None)  # texture <= 140, target peak +120
        rr, cc = np.mgrid[r0 - 7 : r0 + 8, c0 - 7 : c0 + 8]
        # pixel centres at +0.5 in GDAL's raster coordinates
        rc, cc_ = (w * (rr + 0.5)).sum() / w.sum(), (w * (cc + 0.5)).sum() / w.sum()
        dist.append(np.hypot(rc - row, cc_ - col) * src.transform.a)
    return np.array(dist)


@pytest.mark.parametrize("method", ["rigorous", "rpc"])
def test_targets_in_the_orthoimage(ortho_inputs, method):
    d, targets = ortho_inputs
    out = d / f"ortho-{method}.tif"
    assert main(["ortho", str(d / "cam.tif"), str(d / "job.json"), str(d / "report.json"), "--image", "cam", "--dem", str(d / "dem.tif"), "--dem-vertical", "ellipsoid", "--crs", CRS, "--gsd", str(GSD_M), "--method", method, "-o", str(out), "-q"]) == 0
    dist = _find_targets(out, targets)
    assert len(dist) >= 0.8 * len(targets)
    assert dist.max() < 0.5 * GSD_M, dist


def test_rigorous_and_rpc_orthoimages_agree(ortho_inputs):
    d, _ = ortho_inputs
    for method in ("rigorous", "rpc"):
        if not (d / f"ortho-{method}.tif").exists():  # run alone
            assert main(["ortho", str(d / "cam.tif"), str(d / "job.json"), str(d / "report.json"), "--image", "cam", "--dem", str(d / "dem.tif"), "--dem-vertical", "ellipsoid", "--crs", CRS, "--gsd", str(GSD_M), "--method", method, "-o", str(d / f"ortho-{method}.tif"), "-q"]) == 0
    with rasterio.open(d / "ortho-rigorous.tif") as a, rasterio.open(d / "ortho-rpc.tif") as b:
        assert a.transform == b.transform and a.shape == b.shape
        x, y = a.read(1).astype(float), b.read(1).astype(float)
    both = (x > 0) & (y > 0)
    assert both.sum() > 0.5 * x.size
    # same geometry to < 0.01 px: only resampling round-off remains (grey levels)
    assert np.mean(np.abs(x[both] - y[both])) < 1.0


def test_the_readme_gdalwarp_with_the_exported_sidecar(ortho_inputs):
    """What docs/how-to/export-gis.md's ``gdalwarp -rpc -to RPC_DEM=dem.tif -t_srs EPSG:32722 -tr 20 20 -r bilinear``
    does, through rasterio: GDAL reads the exported scene_RPC.TXT beside the raster itself; the
    result is the ``--method rpc`` orthoimage (same grid, same pixels)."""
    from rasterio.warp import Resampling, reproject

    d, _ = ortho_inputs
    if not (d / "ortho-rpc.tif").exists():  # run alone
        assert main(["ortho", str(d / "cam.tif"), str(d / "job.json"), str(d / "report.json"), "--image", "cam", "--dem", str(d / "dem.tif"), "--dem-vertical", "ellipsoid", "--crs", CRS, "--gsd", str(GSD_M), "--method", "rpc", "-o", str(d / "ortho-rpc.tif"), "-q"]) == 0
    assert main(["export-rpc", str(d / "job.json"), str(d / "report.json"), "--image", "cam", "--dem", str(d / "dem.tif"), "--dem-vertical", "ellipsoid", "-o", str(d / "cam_RPC.TXT")]) == 0
    with rasterio.open(d / "ortho-rpc.tif") as ref:
        expected, transform, shape = ref.read(1), ref.transform, ref.shape
    with rasterio.open(d / "cam.tif") as src:
        assert src.rpcs is not None
        out = np.zeros(shape, np.uint8)
        reproject(rasterio.band(src, 1), out, rpcs=src.rpcs, src_crs="EPSG:4326", dst_transform=transform, dst_crs=CRS, resampling=Resampling.bilinear, dst_nodata=0, RPC_DEM=str(d / "dem.tif"))
    assert np.mean(out != expected) < 0.001
