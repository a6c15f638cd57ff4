"""Vertical datums of DEM heights (solver.geometry.vertical): taken from the file or the
caller, never assumed; EGM96 converted offline by PROJ with the shipped grid, checked against
NGA's own test values; a grid that is not on the machine is an error that names it."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS

from solver.geometry.vertical import VerticalDatumError, resolve

# NGA's test points of the EGM96 15' interpolation program (F477: INPUT.DAT -> OUTINTPT.DAT):
# latitude, longitude (degrees east, 0-360), undulation (m). NGA interpolates the grid with a
# bicubic spline, PROJ bilinearly: they differ by centimetres.
NGA_EGM96 = [
    (38.6281550, 269.7791550, -31.628),
    (-14.6212170, 305.0211140, -2.969),
    (46.8743190, 102.4487290, -43.575),
    (-23.6174460, 133.8747120, 15.871),
    (38.6254730, 359.9995000, 50.066),
    (-0.4667440, 0.0023000, 17.329),
]
BILINEAR_VS_SPLINE_M = 0.1  # measured: at most 0.056 m over these points


def test_egm96_undulations_agree_with_nga_test_values() -> None:
    datum = resolve(CRS.from_epsg(4326), "egm96")
    assert datum.to_dict() == {"name": "EGM96 height", "crs": "EPSG:5773", "source": "the caller's choice"}
    lat = np.array([p[0] for p in NGA_EGM96])
    lon = np.array([p[1] for p in NGA_EGM96])
    lon = np.where(lon > 180.0, lon - 360.0, lon)
    expected = np.array([p[2] for p in NGA_EGM96])
    np.testing.assert_allclose(datum.undulation(lon, lat), expected, atol=BILINEAR_VS_SPLINE_M)
    # h = H + N
    np.testing.assert_allclose(datum.to_ellipsoidal(lon, lat, np.full(6, 100.0)), 100.0 + expected, atol=BILINEAR_VS_SPLINE_M)


def test_the_datum_comes_from_the_file_or_the_flag_never_assumed() -> None:
    with pytest.raises(VerticalDatumError, match="does not state its vertical datum.*egm96.*egm2008"):
        resolve(CRS.from_epsg(4326), None)
    with pytest.raises(VerticalDatumError, match="does not state its vertical datum"):
        resolve(CRS.from_epsg(32631), None)
    assert resolve(CRS.from_user_input("EPSG:4326+5773"), None).to_dict()["source"] == "the file's CRS"
    assert resolve(CRS.from_user_input("EPSG:4326+5773"), "egm96").to_dict()["crs"] == "EPSG:5773"
    assert resolve(CRS.from_epsg(4979), None).ellipsoidal  # a 3D geographic CRS: ellipsoidal heights
    assert resolve(CRS.from_epsg(32631), "ellipsoid").ellipsoidal
    assert resolve(CRS.from_epsg(32631), "EPSG:5773").to_dict()["crs"] == "EPSG:5773"
    assert resolve(CRS.from_epsg(4326), "ellipsoid").undulation(np.array([5.0]), np.array([44.0]))[0] == 0.0


def test_a_flag_that_contradicts_the_file_or_is_no_vertical_crs_is_refused() -> None:
    with pytest.raises(VerticalDatumError, match="CRS says its heights are EGM96 height, the flag says WGS 84 ellipsoidal"):
        resolve(CRS.from_user_input("EPSG:4326+5773"), "ellipsoid")
    with pytest.raises(VerticalDatumError, match="not a vertical CRS"):
        resolve(None, "EPSG:32631")
    with pytest.raises(VerticalDatumError, match="unknown vertical datum 'egm84x'"):
        resolve(None, "egm84x")


def test_a_geoid_grid_missing_here_is_named_not_skipped() -> None:
    """EGM2008 needs PROJ's us_nga_egm08_25.tif (77 MB, not shipped). Where it is not installed
    the error names it and where to put it; where someone installed it, the conversion works
    (the Mont Ventoux area: EGM2008 and EGM96 agree within a metre there)."""
    try:
        datum = resolve(None, "egm2008")
    except VerticalDatumError as exc:
        text = str(exc)
        assert "us_nga_egm08_25.tif" in text and "not on this machine" in text and "--dem-vertical ellipsoid" in text
        return
    egm96 = resolve(None, "egm96")
    lon, lat = np.array([5.2]), np.array([44.2])
    assert abs(datum.undulation(lon, lat)[0] - egm96.undulation(lon, lat)[0]) < 1.0
