"""Geodesy: any CRS to ECEF and to the Local Geodetic System (one module, pyproj inside).

Units: metres and radians unless a name says ``_deg``. Axis order is decided once, here:
pyproj transformers are built with ``always_xy=True``, so coordinates are (x, y, z) =
(easting, northing, height) or (longitude, latitude, height) whatever the CRS definition says.

ECEF is WGS 84 geocentric (EPSG:4978), which coincides with ITRF at the metre level; its
ellipsoid differs from GRS80 (used by seed 000) by 0.1 mm in the semi-minor axis.

The Local Geodetic System (LGS) is east-north-up, with its origin at a given ECEF point
(the centroid of the control points) and its axes tangent to the ellipsoid at the geodetic
latitude/longitude of that point.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pyproj is imported where a CRS is parsed: the conversions on WGS 84 below need none (0.3 s saved for them)
    from pyproj import CRS, Transformer

ECEF_CRS = "EPSG:4978"
GEODETIC_CRS = "EPSG:4979"  # WGS 84 lon, lat, ellipsoidal height

# WGS 84 ellipsoid
A_WGS84_M = 6378137.0
F_WGS84 = 1.0 / 298.257223563
E2_WGS84 = F_WGS84 * (2.0 - F_WGS84)


class UnknownCRSError(ValueError):
    """The CRS string is not understood by PROJ."""


@lru_cache(maxsize=64)
def parse_crs(crs: str) -> CRS:
    """Parse an EPSG code, a PROJ string or WKT; raise :class:`UnknownCRSError` on failure."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError, ProjError

    try:
        return CRS.from_user_input(crs)
    except (CRSError, ProjError, TypeError) as exc:
        raise UnknownCRSError(f"unknown CRS {crs!r}: {exc}") from None


def _crs_text(crs: Any) -> str:
    """A CRS as text PROJ reads: a string as given, a CRS object (pyproj's, rasterio's) as its WKT."""
    return crs if isinstance(crs, str) else crs.to_wkt()


def transformer(src: Any, dst: Any) -> Transformer:
    """The transformer from ``src`` to ``dst`` (EPSG codes, PROJ strings, WKT or CRS objects)
    with ``always_xy``: the one place transformers are built, so every caller has the axis order
    of this module (x, y, z); cached (building one takes up to 0.1 s)."""
    return _transformer(_crs_text(src), _crs_text(dst))


@lru_cache(maxsize=128)
def _transformer(src: str, dst: str) -> Transformer:
    from pyproj import Transformer

    return Transformer.from_crs(parse_crs(src), parse_crs(dst), always_xy=True)


def _to_ecef(crs: str) -> Transformer:
    return transformer(crs, ECEF_CRS)


def _from_ecef(crs: str) -> Transformer:
    return transformer(ECEF_CRS, crs)


@lru_cache(maxsize=64)
def _to_ecef_3d(crs: str) -> Transformer:
    """From a 2D CRS promoted to 3D (ellipsoidal height carried through)."""
    return transformer(parse_crs(crs).to_3d(), ECEF_CRS)


@lru_cache(maxsize=64)
def _from_ecef_3d(crs: str) -> Transformer:
    return transformer(ECEF_CRS, parse_crs(crs).to_3d())


def to_ecef(xyz: np.ndarray, crs: str) -> np.ndarray:
    """Coordinates (n, 3) in ``crs`` (x/y order, metres or degrees) to ECEF metres (n, 3).

    A 2D CRS takes the third column as ellipsoidal height in metres.
    """
    xyz = np.atleast_2d(np.asarray(xyz, dtype=float))
    src = parse_crs(crs)
    if src.is_geocentric:
        tr = _to_ecef(crs)
        x, y, z = tr.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
        return np.column_stack([x, y, z])
    if len(src.axis_info) == 2:
        # 2D CRS: promote to 3D with ellipsoidal height so that z is carried through.
        tr = _to_ecef_3d(crs)
    else:
        tr = _to_ecef(crs)
    x, y, z = tr.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    out = np.column_stack([x, y, z])
    if not np.all(np.isfinite(out)):
        raise UnknownCRSError(f"coordinates cannot be transformed from {crs!r} to ECEF")
    return out


def from_ecef(ecef: np.ndarray, crs: str) -> np.ndarray:
    """ECEF metres (n, 3) to ``crs`` (x/y order). Inverse of :func:`to_ecef`."""
    ecef = np.atleast_2d(np.asarray(ecef, dtype=float))
    dst = parse_crs(crs)
    if not dst.is_geocentric and len(dst.axis_info) == 2:
        tr = _from_ecef_3d(crs)
    else:
        tr = _from_ecef(crs)
    x, y, z = tr.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])
    return np.column_stack([x, y, z])


def ecef_to_geodetic(ecef: np.ndarray) -> np.ndarray:
    """ECEF metres (n, 3) to (longitude_deg, latitude_deg, height_m) on WGS 84.

    Own iteration (Bowring's parametric latitude, to convergence) rather than PROJ's
    geocentric inverse, which is off by ~3.5 mm in height at satellite altitudes (700 km).
    """
    e = np.atleast_2d(np.asarray(ecef, dtype=float))
    x, y, z = e[:, 0], e[:, 1], e[:, 2]
    a = A_WGS84_M
    b = a * (1.0 - F_WGS84)
    ep2 = (a * a - b * b) / (b * b)
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    beta = np.arctan2(z * a, p * b)
    lat = np.zeros_like(p)
    for _ in range(10):
        lat_new = np.arctan2(z + ep2 * b * np.sin(beta) ** 3, p - E2_WGS84 * a * np.cos(beta) ** 3)
        beta = np.arctan2((1.0 - F_WGS84) * np.sin(lat_new), np.cos(lat_new))
        done = np.all(np.abs(lat_new - lat) < 1e-15)
        lat = lat_new
        if done:
            break
    sl, cl = np.sin(lat), np.cos(lat)
    n = a / np.sqrt(1.0 - E2_WGS84 * sl * sl)
    # height: well conditioned at all latitudes (projection on the normal)
    h = p * cl + z * sl - a * a / n
    return np.column_stack([np.degrees(lon), np.degrees(lat), h])


def geodetic_to_ecef(lon_lat_h: np.ndarray) -> np.ndarray:
    """(longitude_deg, latitude_deg, ellipsoidal height_m) (n, 3) to ECEF metres on WGS 84: the
    closed form PROJ's geodetic to geocentric conversion computes (X = (N + h) cos lat cos lon,
    Y = (N + h) cos lat sin lon, Z = (N (1 - e²) + h) sin lat, N the prime vertical radius),
    without PROJ (this one needs no CRS)."""
    g = np.atleast_2d(np.asarray(lon_lat_h, dtype=float))
    lon, lat, h = np.radians(g[:, 0]), np.radians(g[:, 1]), g[:, 2]
    sl, cl = np.sin(lat), np.cos(lat)
    n = A_WGS84_M / np.sqrt(1.0 - E2_WGS84 * sl * sl)
    return np.column_stack([(n + h) * cl * np.cos(lon), (n + h) * cl * np.sin(lon), (n * (1.0 - E2_WGS84) + h) * sl])


def enu_rotation(lon_rad: float, lat_rad: float) -> np.ndarray:
    """Rotation matrix taking ECEF vector components to local east, north, up (3 x 3)."""
    sl, cl = np.sin(lon_rad), np.cos(lon_rad)
    sp, cp = np.sin(lat_rad), np.cos(lat_rad)
    return np.array(
        [
            [-sl, cl, 0.0],
            [-sp * cl, -sp * sl, cp],
            [cp * cl, cp * sl, sp],
        ]
    )


@dataclass(frozen=True)
class LocalFrame:
    """East-north-up Local Geodetic System at ``origin_ecef_m``.

    ``lgs = R (ecef - origin)`` and ``ecef = origin + R^T lgs`` with ``R = rotation_ecef_to_lgs``.
    """

    origin_ecef_m: np.ndarray
    rotation_ecef_to_lgs: np.ndarray
    origin_lon_deg: float
    origin_lat_deg: float
    origin_height_m: float

    @classmethod
    def at(cls, origin_ecef_m: np.ndarray) -> "LocalFrame":
        origin = np.asarray(origin_ecef_m, dtype=float).reshape(3)
        lon, lat, h = ecef_to_geodetic(origin[None, :])[0]
        rot = enu_rotation(np.radians(lon), np.radians(lat))
        return cls(origin, rot, float(lon), float(lat), float(h))

    @classmethod
    def at_centroid(cls, points_ecef_m: np.ndarray) -> "LocalFrame":
        """LGS whose origin is the mean of the given ECEF points (seed 000 section 5.1)."""
        return cls.at(np.mean(np.atleast_2d(points_ecef_m), axis=0))

    def to_lgs(self, ecef_m: np.ndarray) -> np.ndarray:
        """ECEF metres (n, 3) or (3,) to LGS east, north, up metres."""
        e = np.asarray(ecef_m, dtype=float)
        return (e - self.origin_ecef_m) @ self.rotation_ecef_to_lgs.T

    def to_ecef(self, lgs_m: np.ndarray) -> np.ndarray:
        """LGS east, north, up metres (n, 3) or (3,) to ECEF metres."""
        g = np.asarray(lgs_m, dtype=float)
        return g @ self.rotation_ecef_to_lgs + self.origin_ecef_m

    def vector_to_lgs(self, v_ecef: np.ndarray) -> np.ndarray:
        """Rotate ECEF vector components (velocity, direction) into LGS axes."""
        return np.asarray(v_ecef, dtype=float) @ self.rotation_ecef_to_lgs.T

    def vector_to_ecef(self, v_lgs: np.ndarray) -> np.ndarray:
        """Rotate LGS vector components into ECEF axes."""
        return np.asarray(v_lgs, dtype=float) @ self.rotation_ecef_to_lgs

    def to_dict(self) -> dict:
        return {
            "origin_ecef_m": [float(x) for x in self.origin_ecef_m],
            "origin_lon_deg": self.origin_lon_deg,
            "origin_lat_deg": self.origin_lat_deg,
            "origin_height_m": self.origin_height_m,
            "axes": "east, north, up",
        }
