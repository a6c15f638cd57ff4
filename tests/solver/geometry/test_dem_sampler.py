"""The DEM as the adjustment samples it (solver.geometry.dem): bilinear heights and slopes in
the DEM's own CRS (projected or geographic) against planes known in closed form, the slope
against finite differences of the heights, no data and the outside as NaN, the window read,
and the sigma formula's limits. The real SRTM crop (tests/data/dem) with its EGM96 heights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from pyproj import CRS, Transformer

from solver.geometry.dem import Dem, DemError, height_sigma, read_dem
from solver.geometry.vertical import VerticalDatumError, resolve

DATA = Path(__file__).parents[2] / "data" / "dem"
PLANE_M = 1e-6  # a bilinear interpolation reproduces a plane to rounding (heights ~1e3 m)
SLOPE_TOL = 2e-4  # m/m: a UTM grid's convergence and scale over the 1 m differences, and rounding
ELLIPSOIDAL = resolve(None, "ellipsoid")
UTM31 = CRS.from_epsg(32631)
TO_UTM = Transformer.from_crs(CRS.from_epsg(4326), UTM31, always_xy=True)


def _utm_plane(gx: float, gy: float, cell: float = 30.0) -> tuple[Dem, float, float]:
    """A 200 x 200 cell DEM in UTM 31N holding h = 500 + gx (x - x0) + gy (y - y0)."""
    x0, y0 = TO_UTM.transform(5.2, 44.2)
    n = 200
    c, f = x0 - n * cell / 2, y0 + n * cell / 2
    cols, rows = np.meshgrid(np.arange(n), np.arange(n))
    x, y = c + (cols + 0.5) * cell, f - (rows + 0.5) * cell
    values = 500.0 + gx * (x - x0) + gy * (y - y0)
    return Dem(values, (cell, 0.0, c, 0.0, -cell, f), UTM31, ELLIPSOIDAL, "plane"), x0, y0


def test_utm_plane_heights_and_slopes() -> None:
    dem, x0, y0 = _utm_plane(0.10, -0.05)
    rng = np.random.default_rng(3)
    lon = 5.2 + rng.uniform(-0.02, 0.02, 50)
    lat = 44.2 + rng.uniform(-0.02, 0.02, 50)
    x, y = TO_UTM.transform(lon, lat)
    h, slope = dem.sample(lon, lat)
    np.testing.assert_allclose(h, 500.0 + 0.10 * (x - x0) - 0.05 * (y - y0), atol=PLANE_M)
    # grid north differs from true north by the meridian convergence (about 0.56 deg here):
    # the east / north slope is the grid gradient rotated by it
    north = np.array(TO_UTM.transform(lon, lat + 1e-4))
    gamma = np.arctan2(north[0] - x, north[1] - y)  # grid azimuth of true north
    de = 0.10 * np.cos(gamma) + 0.05 * np.sin(gamma)
    dn = -0.05 * np.cos(gamma) + 0.10 * np.sin(gamma)
    np.testing.assert_allclose(slope[:, 0], de, atol=SLOPE_TOL)
    np.testing.assert_allclose(slope[:, 1], dn, atol=SLOPE_TOL)
    assert dem.cell_m == pytest.approx(30.0)


def test_geographic_dem_slope_is_in_metres_per_metre() -> None:
    """A geographic DEM (cells in degrees, as SRTM): h = 300 + 0.2 e + 0.1 n in metres east and
    north of a point; the slope comes out in m/m, not per degree."""
    lon0, lat0, d = 5.2, 44.2, 1.0 / 1200
    m_lon = 111_319.49 * np.cos(np.radians(lat0))
    m_lat = 111_132.95  # metres per degree of latitude at 44 deg (the slope test's tolerance covers the difference)
    n = 120
    c, f = lon0 - n * d / 2, lat0 + n * d / 2
    cols, rows = np.meshgrid(np.arange(n), np.arange(n))
    lon, lat = c + (cols + 0.5) * d, f - (rows + 0.5) * d
    values = 300.0 + 0.2 * (lon - lon0) * m_lon + 0.1 * (lat - lat0) * m_lat
    dem = Dem(values, (d, 0.0, c, 0.0, -d, f), CRS.from_epsg(4326), ELLIPSOIDAL)
    h, slope = dem.sample(np.array([lon0 + 0.01, lon0 - 0.013]), np.array([lat0 + 0.004, lat0 - 0.02]))
    np.testing.assert_allclose(slope, [[0.2, 0.1], [0.2, 0.1]], rtol=0.005)
    np.testing.assert_allclose(h, 300 + 0.2 * np.array([0.01, -0.013]) * m_lon + 0.1 * np.array([0.004, -0.02]) * m_lat, atol=PLANE_M)
    assert 60.0 < dem.cell_m < 100.0  # 3 arc seconds: 66 m east, 93 m north


def test_slope_agrees_with_finite_differences_of_the_heights() -> None:
    """On rough values (the bilinear surface's slope inside a cell)."""
    dem, _x0, _y0 = _utm_plane(0.0, 0.0)
    dem.values = dem.values + np.random.default_rng(1).normal(0, 20, dem.values.shape)
    lon = 5.2 + np.array([0.0031, -0.0077, 0.0123])
    lat = 44.2 + np.array([0.0042, 0.0011, -0.0093])
    h, slope = dem.sample(lon, lat)
    step = 0.05  # m: inside one 30 m cell
    dlon = step / (111_319.49 * np.cos(np.radians(lat)))
    dlat = step / 111_319.49
    fd_e = (dem.sample(lon + dlon, lat)[0] - dem.sample(lon - dlon, lat)[0]) / (2 * step)
    fd_n = (dem.sample(lon, lat + dlat)[0] - dem.sample(lon, lat - dlat)[0]) / (2 * step)
    # the finite differences use a spherical metre per degree: 0.3% off in north, below this
    np.testing.assert_allclose(slope[:, 0], fd_e, rtol=0.01, atol=1e-3)
    np.testing.assert_allclose(slope[:, 1], fd_n, rtol=0.01, atol=1e-3)


def test_no_data_and_outside_are_nan() -> None:
    dem, x0, y0 = _utm_plane(0.0, 0.0)
    dem.values[100, 100] = np.nan
    to_ll = Transformer.from_crs(UTM31, CRS.from_epsg(4326), always_xy=True)
    c, f = dem.transform[2], dem.transform[5]
    centre = to_ll.transform(c + 100.5 * 30, f - 100.5 * 30)  # the no-data cell's centre
    beside = to_ll.transform(c + 100.9 * 30, f - 100.9 * 30)  # between it and its neighbours
    far = to_ll.transform(c + 60.5 * 30, f - 60.5 * 30)
    outside = to_ll.transform(c - 300, f + 300)
    lon, lat = np.array([centre[0], beside[0], far[0], outside[0]]), np.array([centre[1], beside[1], far[1], outside[1]])
    h, slope = dem.sample(lon, lat)
    assert np.isnan(h[:2]).all() and np.isnan(slope[:2]).all()
    assert h[2] == pytest.approx(500.0) and np.isnan(h[3])


def test_sigma_formula_limits() -> None:
    # flat ground: the DEM's stated accuracy alone, whatever the resolution
    assert height_sigma(3.0, np.array([0.0]), 0.5, 30.0, 0.5)[0] == pytest.approx(3.0)
    # the resolution term: a 30 m cell under 0.5 m pixels, slope 0.2, a point known to 0.5 m
    expected = np.sqrt(9.0 + 0.04 * (0.25 + (900 - 0.25) / 12))
    assert height_sigma(3.0, np.array([0.2]), 0.5, 30.0, 0.5)[0] == pytest.approx(expected)
    # an image as coarse as the DEM: no resolution term
    assert height_sigma(3.0, np.array([0.2]), 0.5, 30.0, 30.0)[0] == pytest.approx(np.sqrt(9.0 + 0.04 * 0.25))
    assert height_sigma(3.0, np.array([0.2]), 0.5, 30.0, 60.0)[0] == pytest.approx(np.sqrt(9.0 + 0.04 * 0.25))


def test_real_srtm_crop_with_its_egm96_heights() -> None:
    """The SRTM crop states no vertical datum: refused without one; with ``egm96`` its heights
    are the file's bilinear values plus the EGM96 undulation (about 50.8 m at Mont Ventoux)."""
    path = DATA / "srtm_ventoux.tif"
    with pytest.raises(VerticalDatumError, match="does not state its vertical datum"):
        read_dem(path)
    dem = read_dem(path, "egm96")
    assert dem.vertical.to_dict()["crs"] == "EPSG:5773"
    with rasterio.open(path) as src:
        raw = src.read(1).astype(float)
        t = src.transform
    # a cell centre: the file's value plus N
    r, c = 30, 40
    lon, lat = t.c + (c + 0.5) * t.a, t.f + (r + 0.5) * t.e
    h, slope = dem.sample(np.array([lon]), np.array([lat]))
    undulation = resolve(None, "egm96").undulation(np.array([lon]), np.array([lat]))[0]
    assert 50.0 < undulation < 52.0
    assert h[0] == pytest.approx(raw[r, c] + undulation, abs=1e-6)
    assert np.isfinite(slope).all() and np.hypot(*slope[0]) < 1.5
    # the window around the matching crops holds the same values as the whole file
    part = read_dem(path, "egm96", bounds_lon_lat=(5.19, 44.20, 5.20, 44.21))
    assert part.values.size < dem.values.size
    lon_q, lat_q = np.array([5.1935, 5.1962]), np.array([44.2051, 44.2077])
    np.testing.assert_allclose(part.sample(lon_q, lat_q)[0], dem.sample(lon_q, lat_q)[0], atol=1e-9)
    with pytest.raises(DemError, match="does not cover"):
        read_dem(path, "egm96", bounds_lon_lat=(6.0, 45.0, 6.1, 45.1))


FLOAT32_M = 1e-4  # heights of ~1,000 m carried as float32 in the job (6e-5 m steps)


def test_a_dem_carried_in_the_job_reads_back_ellipsoidal() -> None:
    """``grid_to_job`` converts the EGM96 heights to ellipsoidal ones cell by cell; the job's
    grid samples as the file does through its datum (no geoid grid needed to read it back)."""
    from solver.geometry.dem import grid_from_job, grid_to_job

    dem = read_dem(DATA / "srtm_ventoux.tif", "egm96")
    grid = grid_to_job(dem)
    assert (grid["rows"], grid["columns"]) == dem.values.shape
    assert "EGM96" in grid["vertical"] and "converted" in grid["vertical"]
    back = grid_from_job(grid)
    assert back.vertical.ellipsoidal
    rng = np.random.default_rng(4)
    lon, lat = rng.uniform(5.17, 5.22, 200), rng.uniform(44.19, 44.22, 200)
    want, want_slope = dem.sample(lon, lat)
    got, got_slope = back.sample(lon, lat)
    # the undulation is taken at cell centres and interpolated: its own curvature over 90 m is < 1 mm
    np.testing.assert_allclose(got, want, atol=FLOAT32_M + 1e-3)
    np.testing.assert_allclose(got_slope, want_slope, atol=1e-4)
    # too many cells for a job: averaged over k x k blocks, the cell k times larger
    small = grid_from_job(grid_to_job(dem, max_cells=1000))
    assert small.values.size <= 1000 and small.cell_m == pytest.approx(3 * dem.cell_m, rel=0.01)
    assert np.nanmean(small.values) == pytest.approx(np.nanmean(back.values[: small.values.shape[0] * 3, : small.values.shape[1] * 3]), abs=0.01)
    with pytest.raises(DemError, match="holds"):
        grid_from_job({**grid, "rows": grid["rows"] + 1})
