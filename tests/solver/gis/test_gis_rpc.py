"""RPC export verified through GDAL itself (rasterio's RPC transformer reading the files we
write), not through our own RPC evaluator: ground points made by the adjusted rigorous model
from a grid of image positions and heights must come back through GDAL to those positions
within 0.01 px RMS and 0.05 px maximum (issue 16), for every model kind, nadir and tilted,
single-chip cameras, and for each chip's RPC of a multi-chip camera.

GDAL's transformer works in pixel corners: it returns our (line, column) + 0.5.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from utils.gis_scenes import MODEL_KINDS, VIEWS, prism_butted, single_chip

from solver.cli import main
from solver.geometry.geodesy import ecef_to_geodetic
from solver.gis.rpc_io import gdal_ground_to_image, read_rpc_txt, rpc_rpb, rpc_txt

RPC_TXT_REL = 1e-14  # RPC coefficients written to _RPC.TXT and read back (printed to 15 digits)

pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")  # the blank rasters

GDAL_CORNER_PX = 0.5  # GDAL's pixel (0, 0) is the top-left corner; ours the top-left centre
RMS_TOL_PX = 0.01
MAX_TOL_PX = 0.05


def _blank_tif(path, lines=64, columns=64):
    with rasterio.open(path, "w", driver="GTiff", width=columns, height=lines, count=1, dtype="uint8") as dst:
        dst.write(np.zeros((1, lines, columns), np.uint8))


def _files(tmp_path, job, report):
    (tmp_path / "job.json").write_text(json.dumps(job))
    (tmp_path / "report.json").write_text(json.dumps(report))
    return [str(tmp_path / "job.json"), str(tmp_path / "report.json")]


def _check_grid(img, columns, heights=(250.0, 420.0, 610.0), n=13, chip=None):
    """Image positions strictly inside the image (cell centres of an n x n grid) and their
    ground points at each height, by the rigorous model."""
    lines = (0.0, img.lines - 1.0)
    ll, cc = np.meshgrid(lines[0] + (np.arange(n) + 0.5) * (lines[1] - lines[0]) / n, columns[0] + (np.arange(n) + 0.5) * (columns[1] - columns[0]) / n, indexing="ij")
    line, col = np.tile(ll.ravel(), len(heights)), np.tile(cc.ravel(), len(heights))
    h = np.repeat(heights, n * n)
    llh = ecef_to_geodetic(img.image_to_ground(line, col, h, chip=chip))
    return line, col, llh


def _gdal_errors(rpcs, line, col, llh, column_offset=0.0):
    rows, cols = gdal_ground_to_image(rpcs, llh[:, 0], llh[:, 1], llh[:, 2])
    dl = rows - GDAL_CORNER_PX - line
    dc = cols - GDAL_CORNER_PX + column_offset - col
    err = np.hypot(dl, dc)
    return float(np.sqrt(np.mean(err**2))), float(np.max(err))


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(MODEL_KINDS))
@pytest.mark.parametrize("view", list(VIEWS))
def test_rpc_txt_through_gdal_single_chip(tmp_path, kind, view):
    _scene, job, report, model = single_chip(MODEL_KINDS[kind], VIEWS[view])
    _blank_tif(tmp_path / "cam.tif")
    args = _files(tmp_path, job, report)
    assert main(["export-rpc", *args, "--image", "cam", "-o", str(tmp_path / "cam_RPC.TXT"), "--fit-report", str(tmp_path / "fit.json")]) == 0
    with rasterio.open(tmp_path / "cam.tif") as src:
        rpcs = src.rpcs
    assert rpcs is not None, "GDAL did not pick up the _RPC.TXT sidecar"
    img = model.image("cam")
    line, col, llh = _check_grid(img, (0.0, img.columns - 1.0))
    rms, mx = _gdal_errors(rpcs, line, col, llh)
    assert rms <= RMS_TOL_PX and mx <= MAX_TOL_PX, (rms, mx)
    fit = json.loads((tmp_path / "fit.json").read_text())[0]
    assert fit["check_residuals"]["rms_px"] <= RMS_TOL_PX and not fit["warnings"]


def test_gdal_pixel_corner_convention_is_half_a_pixel(tmp_path):
    """Without the half-pixel shift GDAL would be 0.5 px off in line and column: the shift is
    GDAL's convention, not a fit error (the rigorous point is exact, the RPC error < 0.01 px)."""
    _scene, job, report, model = single_chip("J2-2")
    _blank_tif(tmp_path / "cam.tif")
    assert main(["export-rpc", *_files(tmp_path, job, report), "--image", "cam", "-o", str(tmp_path / "cam_RPC.TXT")]) == 0
    img = model.image("cam")
    line, col, llh = _check_grid(img, (0.0, img.columns - 1.0), heights=(400.0,), n=5)
    with rasterio.open(tmp_path / "cam.tif") as src:
        rows, cols = gdal_ground_to_image(src.rpcs, llh[:, 0], llh[:, 1], llh[:, 2])
    assert np.allclose(rows - line, 0.5, atol=RMS_TOL_PX) and np.allclose(cols - col, 0.5, atol=RMS_TOL_PX)


def test_rpb_and_geotiff_tags_give_gdal_the_same_model(tmp_path):
    _scene, job, report, model = single_chip("OA-J2", 20.0)
    args = [*_files(tmp_path, job, report), "--image", "cam"]
    assert main(["export-rpc", *args, "-o", str(tmp_path / "a_RPC.TXT")]) == 0
    rpc = read_rpc_txt((tmp_path / "a_RPC.TXT").read_text())
    (tmp_path / "b.RPB").write_text(rpc_rpb(rpc))
    _blank_tif(tmp_path / "b.tif")
    _blank_tif(tmp_path / "raw.tif")
    assert main(["export-rpc", *args, "-o", str(tmp_path / "c.tif"), "--raster", str(tmp_path / "raw.tif")]) == 0
    img = model.image("cam")
    line, col, llh = _check_grid(img, (0.0, img.columns - 1.0), n=7)
    for path in ("b.tif", "c.tif"):
        with rasterio.open(tmp_path / path) as src:
            assert src.rpcs is not None, path
            rms, mx = _gdal_errors(src.rpcs, line, col, llh)
            assert rms <= RMS_TOL_PX and mx <= MAX_TOL_PX, (path, rms, mx)
    with rasterio.open(tmp_path / "c.tif") as src:
        assert src.read().shape == (1, 64, 64)  # the raster's pixels are copied
    assert read_rpc_txt(rpc_txt(rpc)).line_num == pytest.approx(rpc.line_num, rel=RPC_TXT_REL, abs=0)


@pytest.mark.slow
def test_multi_chip_whole_image_rpc_warns_and_per_chip_rpcs_pass_through_gdal(tmp_path, capsys):
    scene, job, report, model = prism_butted()
    image_id = scene.images[0].id
    img = model.image(image_id)
    args = [*_files(tmp_path, job, report), "--image", image_id]
    assert main(["export-rpc", *args, "-o", str(tmp_path / "raw_RPC.TXT"), "--fit-report", str(tmp_path / "whole.json")]) == 0
    err = capsys.readouterr().err
    whole = json.loads((tmp_path / "whole.json").read_text())[0]
    # the chips' offsets (1.5-3 px along track) cannot be followed by one rational function
    assert whole["check_residuals"]["rms_px"] > 0.3 and whole["warnings"] and "--per-chip" in err
    assert main(["export-rpc", *args, "-o", str(tmp_path / "raw_RPC.TXT"), "--per-chip", "--fit-report", str(tmp_path / "chips.json")]) == 0
    fits = json.loads((tmp_path / "chips.json").read_text())
    assert len(fits) == 4
    for k, fit in enumerate(fits):
        _blank_tif(tmp_path / f"raw_{fit['chip']}.tif")
        with rasterio.open(tmp_path / f"raw_{fit['chip']}.tif") as src:
            rpcs = src.rpcs
        assert rpcs is not None
        lo, hi = img.chip_range(k)
        assert fit["column_offset"] == lo
        line, col, llh = _check_grid(img, (lo, hi), n=9, chip=k)
        rms, mx = _gdal_errors(rpcs, line, col, llh, column_offset=lo)
        assert rms <= RMS_TOL_PX and mx <= MAX_TOL_PX, (fit["chip"], rms, mx)


def test_the_check_grid_shares_no_point_with_the_fit_grid(monkeypatch):
    """The fit is assessed on an independent grid only if no check point is a fit point
    (tests/solver/gis/rpc_grids.py)."""
    from rpc_grids import assert_independent, spy_grids

    from solver.gis import rpc_fit

    grids = spy_grids(monkeypatch, rpc_fit)
    _scene, _job, _report, model = single_chip("P2")
    rpc_fit.fit_image_rpc(model.image("cam"), (200.0, 700.0))
    assert_independent(grids["fit"], grids["check"])
