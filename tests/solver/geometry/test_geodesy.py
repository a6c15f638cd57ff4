"""Geodesy round trips and cross-checks (pymap3d style: named tolerances, edge cases)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solver.geometry.geodesy import (
    A_WGS84_M,
    E2_WGS84,
    LocalFrame,
    UnknownCRSError,
    ecef_to_geodetic,
    enu_rotation,
    from_ecef,
    geodetic_to_ecef,
    to_ecef,
)

ORTHONORMAL_ABS = 1e-15  # the ENU rotation times its transpose: an ulp

ATOL_DIST = 1e-6  # 1 micrometre
ATOL_DEG = 1e-11  # ~1 micrometre on the ground


def _ecef_closed_form(lon_deg, lat_deg, h):
    lon, lat = math.radians(lon_deg), math.radians(lat_deg)
    n = A_WGS84_M / math.sqrt(1 - E2_WGS84 * math.sin(lat) ** 2)
    return np.array(
        [(n + h) * math.cos(lat) * math.cos(lon), (n + h) * math.cos(lat) * math.sin(lon), (n * (1 - E2_WGS84) + h) * math.sin(lat)]
    )


@pytest.mark.parametrize(
    "lon,lat,h",
    [(-51.39, -22.12, 450.0), (0.0, 0.0, 0.0), (179.999, 89.999, 1000.0), (-45.0, -89.9999, -50.0), (120.0, 45.0, 700e3)],
)
def test_geodetic_ecef_round_trip_and_closed_form(lon, lat, h):
    e = geodetic_to_ecef(np.array([[lon, lat, h]]))[0]
    np.testing.assert_allclose(e, _ecef_closed_form(lon, lat, h), atol=ATOL_DIST)
    back = ecef_to_geodetic(e[None, :])[0]
    np.testing.assert_allclose(back[:2], [lon, lat], atol=ATOL_DEG)
    assert back[2] == pytest.approx(h, abs=ATOL_DIST)


def test_own_inverse_agrees_with_pyproj_at_ground_level():
    pts = np.array([[-51.39, -22.12, 450.0], [10.0, 60.0, 0.0], [-170.0, -5.0, 3000.0]])
    e = geodetic_to_ecef(pts)
    np.testing.assert_allclose(ecef_to_geodetic(e), from_ecef(e, "EPSG:4979"), atol=ATOL_DIST)


def test_utm_sad69_round_trip_and_datum_shift():
    # seed 002: UTM 22S on SAD69 (EPSG:29192)
    utm = np.array([[458000.0, 7553000.0, 420.0], [471500.5, 7561234.25, 380.0]])
    ecef = to_ecef(utm, "EPSG:29192")
    back = from_ecef(ecef, "EPSG:29192")
    np.testing.assert_allclose(back, utm, atol=ATOL_DIST)
    # the same numbers read as SIRGAS 2000 / UTM 22S (EPSG:31982) differ by the SAD69 shift (~tens of m)
    other = to_ecef(utm, "EPSG:31982")
    shift = np.linalg.norm(ecef - other, axis=1)
    assert np.all((shift > 30) & (shift < 120))


def test_geographic_2d_crs_carries_height():
    e = to_ecef(np.array([[-51.39, -22.12, 450.0]]), "EPSG:4326")
    np.testing.assert_allclose(ecef_to_geodetic(e)[0], [-51.39, -22.12, 450.0], atol=ATOL_DIST)


def test_proj_string_and_ecef_identity():
    x = np.array([[3.7e6, -4.6e6, -2.4e6]])
    np.testing.assert_allclose(to_ecef(x, "EPSG:4978"), x, atol=ATOL_DIST)
    e = to_ecef(np.array([[-51.39, -22.12, 450.0]]), "+proj=longlat +ellps=WGS84 +datum=WGS84 +no_defs")
    np.testing.assert_allclose(e, geodetic_to_ecef(np.array([[-51.39, -22.12, 450.0]])), atol=ATOL_DIST)


def test_unknown_crs():
    with pytest.raises(UnknownCRSError):
        to_ecef(np.zeros((1, 3)), "EPSG:999999")


def test_local_frame_round_trip_and_axes():
    origin = geodetic_to_ecef(np.array([[-51.39, -22.12, 450.0]]))[0]
    f = LocalFrame.at(origin)
    pts = geodetic_to_ecef(np.array([[-51.30, -22.00, 500.0], [-51.5, -22.3, 350.0]]))
    np.testing.assert_allclose(f.to_ecef(f.to_lgs(pts)), pts, atol=ATOL_DIST)
    # a point 100 m above the origin is (0, 0, 100) in the LGS
    up = geodetic_to_ecef(np.array([[-51.39, -22.12, 550.0]]))[0]
    np.testing.assert_allclose(f.to_lgs(up), [0, 0, 100.0], atol=ATOL_DIST)
    # a point slightly north has positive north and ~zero east
    north = f.to_lgs(geodetic_to_ecef(np.array([[-51.39, -22.11, 450.0]]))[0])
    assert north[1] > 1000 and abs(north[0]) < ATOL_DIST
    r = enu_rotation(0.3, -0.4)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=ORTHONORMAL_ABS)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_centroid_frame_is_the_mean_of_the_points():
    pts = geodetic_to_ecef(np.array([[-51.3, -22.0, 400.0], [-51.5, -22.2, 500.0], [-51.4, -22.3, 450.0]]))
    f = LocalFrame.at_centroid(pts)
    np.testing.assert_allclose(f.to_lgs(pts).mean(axis=0), 0.0, atol=ATOL_DIST)
