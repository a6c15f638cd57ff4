"""The GIS path's DEM (solver/gis/dem.py: ``pba image-to-ground --dem``, ``export-rpc --dem``,
``ortho --dem``) takes the DEM's vertical datum from the file or ``--dem-vertical`` and converts
its heights to ellipsoidal ones; a DEM that states none is refused, never taken as ellipsoidal.

Evidence: the same surface written twice by the simulator (solver/simulate/dem.py), once as
WGS 84 ellipsoidal heights (EPSG:4979) and once as EGM96 heights under EPSG:4326+5773, the
latter converted by PROJ directly in the opposite direction to the solver's reader; the two
must give the same ellipsoidal heights, which differ from the EGM96 file's own values by the
geoid undulation (about +50 m in the Alps' foreland used here, -5 m at the GIS scenes' place).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from utils.gis_scenes import single_chip

from solver.cli import main
from solver.geometry.geodesy import ecef_to_geodetic
from solver.gis.dem import Dem, VerticalDatumError
from solver.simulate.dem import DemDegradation, degraded_dem

# the two files' heights after conversion: float32 storage (6e-5 m at 1000 m), PROJ's bilinear
# geoid in two directions at cell centres vs the sampled position (N varies < 1e-3 m per cell)
SAME_HEIGHT_M = 0.01


def _surface(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """A tilted plane with a bump (ellipsoidal metres)."""
    return 400.0 + 3000.0 * (lon - lon.mean()) + 1500.0 * np.sin(40.0 * (lat - lat.mean()))


def _pair(tmp_path, bounds, cell_arcsec: float = 1.0, surface=_surface):
    """The ellipsoidal and EGM96 files of the same surface (no noise, no bias), and a copy of
    the EGM96 heights under a CRS without a vertical part (as an SRTM tile comes)."""
    import rasterio

    ell, egm = tmp_path / "ell.tif", tmp_path / "egm96.tif"
    degraded_dem(surface, bounds, DemDegradation(cell_arcsec=cell_arcsec, noise_m=0.0, vertical="ellipsoid"), ell)
    degraded_dem(surface, bounds, DemDegradation(cell_arcsec=cell_arcsec, noise_m=0.0, vertical="egm96"), egm)
    bare = tmp_path / "srtm_like.tif"
    with rasterio.open(egm) as src:
        profile = {**src.profile, "crs": "EPSG:4326"}
        data = src.read(1)
    with rasterio.open(bare, "w", **profile) as dst:
        dst.write(data, 1)
    return ell, egm, bare


def test_heights_are_ellipsoidal_whatever_the_file_holds(tmp_path) -> None:
    bounds = (5.15, 44.15, 5.25, 44.25)
    ell, egm, bare = _pair(tmp_path, bounds)
    rng = np.random.default_rng(1)
    lon = rng.uniform(5.16, 5.24, 50)
    lat = rng.uniform(44.16, 44.24, 50)
    h_ell = Dem(ell).height(lon, lat)  # EPSG:4979: the file says ellipsoidal
    h_egm = Dem(egm).height(lon, lat)  # EPSG:4326+5773: the file says EGM96
    np.testing.assert_allclose(h_egm, h_ell, atol=SAME_HEIGHT_M)
    # the EGM96 file's own values are N (about +50 m here) below: the conversion took place
    raw = Dem(bare, "ellipsoid").height(lon, lat)
    assert np.all(np.abs(h_ell - raw - 50.0) < 2.0), h_ell - raw
    # the bare file with the flag that says what it holds
    np.testing.assert_allclose(Dem(bare, "egm96").height(lon, lat), h_ell, atol=SAME_HEIGHT_M)
    # the height range (RPC fit grids, orthoimage bounds): ellipsoidal too
    lo_e, hi_e = Dem(ell).range_m
    lo_g, hi_g = Dem(egm).range_m
    assert abs(lo_g - lo_e) < 0.5 and abs(hi_g - hi_e) < 0.5  # N varies by ~0.3 m over the tile: an envelope
    assert lo_g <= lo_e + SAME_HEIGHT_M and hi_g >= hi_e - SAME_HEIGHT_M


def test_a_dem_that_states_no_vertical_datum_is_refused(tmp_path) -> None:
    _ell, egm, bare = _pair(tmp_path, (5.15, 44.15, 5.25, 44.25), cell_arcsec=6.0)
    with pytest.raises(VerticalDatumError, match="does not state its vertical datum"):
        Dem(bare)
    with pytest.raises(VerticalDatumError, match="flag says"):
        Dem(egm, "ellipsoid")  # the file says EGM96: a contradicting flag is refused


@pytest.fixture(scope="module")
def gis_scene_dems(tmp_path_factory):
    """The GIS test scene (J2-2 single chip, near 51 W 22 S, N about -5 m) with its terrain
    as an ellipsoidal and an EGM96 DEM (0.002 degree cells)."""
    scene, job, report, _model = single_chip("J2-2")
    d = tmp_path_factory.mktemp("gis_dem")
    (d / "job.json").write_text(json.dumps(job))
    (d / "report.json").write_text(json.dumps(report))
    llh = ecef_to_geodetic(np.array([p.ecef_m for p in scene.points]))
    bounds = (llh[:, 0].min() - 0.5, llh[:, 1].min() - 0.5, llh[:, 0].max() + 0.5, llh[:, 1].max() + 0.5)
    ell, egm, bare = _pair(d, bounds, cell_arcsec=7.2, surface=lambda lo, la: scene.terrain.height(lo, la))
    return d, ell, egm, bare


def _read(path) -> list[dict]:
    import csv

    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_image_to_ground_on_an_egm96_dem(gis_scene_dems, capsys) -> None:
    """``pba image-to-ground --dem``: the same ground from the EGM96 file as from the ellipsoidal
    one (heights within 1 cm, positions within 2 cm); the bare file without --dem-vertical
    exits 2 naming the choices."""
    d, ell, egm, bare = gis_scene_dems
    (d / "px.csv").write_text("line,column\n" + "\n".join(f"{r},{c}" for r in (300, 1200, 2100) for c in (300, 1200, 2100)) + "\n")
    args = ["image-to-ground", str(d / "job.json"), str(d / "report.json"), "--image", "cam", str(d / "px.csv"), "--crs", "EPSG:32722"]
    out = {}
    for name, dem, flag in (("ell", ell, []), ("egm", egm, []), ("bare", bare, ["--dem-vertical", "egm96"])):
        assert main([*args, "--dem", str(dem), *flag, "-o", str(d / f"g_{name}.csv")]) == 0
        out[name] = np.array([[float(r["e"]), float(r["n"]), float(r["height"])] for r in _read(d / f"g_{name}.csv")])
    for name in ("egm", "bare"):
        np.testing.assert_allclose(out[name][:, 2], out["ell"][:, 2], atol=SAME_HEIGHT_M)
        np.testing.assert_allclose(out[name][:, :2], out["ell"][:, :2], atol=2 * SAME_HEIGHT_M)
    capsys.readouterr()
    assert main([*args, "--dem", str(bare), "-o", str(d / "g_refused.csv")]) == 2
    assert "does not state its vertical datum" in capsys.readouterr().err
    assert not (d / "g_refused.csv").exists()


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")
@pytest.mark.parametrize("method", ["rigorous", "rpc"])
def test_orthoimages_on_an_egm96_dem(gis_scene_dems, method, monkeypatch) -> None:
    """``pba ortho --dem``: an EGM96 DEM (converted on the output grid by the rigorous path; a
    temporary ellipsoidal copy for GDAL's RPC transformer) gives the orthoimage of the
    ellipsoidal DEM. The undulation here is 5 m, far below a pixel of parallax in this
    near-nadir image, so for the rigorous path the heights it resamples with are compared too
    (captured from its kernel's calls): within 5 cm of the ellipsoidal DEM's."""
    import rasterio

    import solver.gis.ortho_kernel as kernel
    from solver.simulate.raster import render_image

    heights: dict[str, list[np.ndarray]] = {}
    real = kernel.sample_block
    current = {"name": ""}

    def capture(data, l0, c0, l1, c1, step, ny, nx, r0, hb, *rest):
        heights.setdefault(current["name"], []).append(np.array(hb, copy=True))
        return real(data, l0, c0, l1, c1, step, ny, nx, r0, hb, *rest)

    monkeypatch.setattr(kernel, "sample_block", capture)

    d, ell, egm, _bare = gis_scene_dems
    scene, _job, _report, _model = single_chip("J2-2")
    if not (d / "cam.tif").exists():
        data = render_image(scene, 0)
        with rasterio.open(d / "cam.tif", "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype="uint8") as dst:
            dst.write(data, 1)
    base = ["ortho", str(d / "cam.tif"), str(d / "job.json"), str(d / "report.json"), "--image", "cam", "--crs", "EPSG:32722",
            "--gsd", "20", "--method", method, "-q"]
    for name, dem in (("ell", ell), ("egm", egm)):
        current["name"] = name
        assert main([*base, "--dem", str(dem), "-o", str(d / f"o_{method}_{name}.tif")]) == 0
    if method == "rigorous":
        h_ell, h_egm = np.concatenate(heights["ell"]), np.concatenate(heights["egm"])
        assert h_ell.shape == h_egm.shape
        ok = np.isfinite(h_ell) & np.isfinite(h_egm)
        assert ok.mean() > 0.9
        assert np.max(np.abs(h_egm[ok] - h_ell[ok])) < 0.05
    with rasterio.open(d / f"o_{method}_ell.tif") as a, rasterio.open(d / f"o_{method}_egm.tif") as b:
        assert a.transform.almost_equals(b.transform, precision=1e-6) and a.shape == b.shape
        x, y = a.read(1).astype(float), b.read(1).astype(float)
    both = (x > 0) & (y > 0)
    assert both.sum() > 0.5 * x.size
    assert np.mean(np.abs(x[both] - y[both])) < 1.0
