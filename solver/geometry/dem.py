"""A DEM as the adjustment samples it: ellipsoidal heights and the local slope at horizontal
positions, bilinear between cell centres in the DEM's own CRS, and the standard deviation of
such a height as an observation of a ground point.

Units: heights and sigmas in metres, slopes in metres per metre along local east and north,
positions as WGS 84 longitude and latitude in degrees. The DEM's heights are converted to
ellipsoidal heights by its vertical datum (:mod:`solver.geometry.vertical`): ``h = H + N``,
with the geoid undulation N taken at each sampled position (its horizontal gradient, below
1e-4 m/m, is left out of the slope).

The sigma of a DEM height at a point (docs/dem.md states it for users)::

    sigma^2 = sigma_dem^2 + |grad h|^2 (sigma_xy^2 + max(d^2 - g^2, 0) / 12)

``sigma_dem``: the DEM's stated vertical accuracy (one sigma); ``|grad h|``: the local slope;
``sigma_xy``: the horizontal uncertainty of the point (one axis); ``d``: the DEM's cell size
and ``g``: the image's ground sample distance (both metres). A DEM cell holds one height for an
area d wide, the image sees the point to within g: where in the cell the point lies is
uniformly unknown over the difference of the two, a variance of (d^2 - g^2) / 12 per axis,
which the slope turns into height. On flat ground only the stated accuracy remains; on steep
ground a 30 m DEM under 0.5 m images weighs little.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
from pyproj import CRS, Transformer

from solver.geometry.geodesy import transformer
from solver.geometry.vertical import VerticalDatum, resolve

M_PER_DEG = 111_319.49  # metres per degree on WGS 84's equator (cell sizes of geographic DEMs)
STEP_M = 1.0  # metres east / north of the finite differences that map the DEM's axes onto the LGS's


def metres_per_degree(lat_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Metres per degree of longitude and of latitude on the WGS 84 ellipsoid at ``lat_deg``
    (the prime-vertical radius times cos(lat), the meridian radius)."""
    from solver.geometry.geodesy import A_WGS84_M, E2_WGS84

    phi = np.radians(np.asarray(lat_deg, dtype=float))
    w2 = 1.0 - E2_WGS84 * np.sin(phi) ** 2
    n = A_WGS84_M / np.sqrt(w2)
    m = A_WGS84_M * (1.0 - E2_WGS84) / w2**1.5
    return np.radians(1.0) * n * np.cos(phi), np.radians(1.0) * m


class DemError(ValueError):
    """A DEM that cannot be used (unreadable, no CRS, no heights where asked)."""


def height_sigma(sigma_dem_m: float | np.ndarray, slope: np.ndarray, sigma_xy_m: float | np.ndarray,
                 cell_m: float, gsd_m: float | np.ndarray) -> np.ndarray:
    """The standard deviation (metres) of a DEM height as an observation of a point (the
    module's formula): ``slope`` the local slope |grad h| (m/m), ``sigma_xy_m`` the point's
    horizontal sigma per axis, ``cell_m`` the DEM's cell size, ``gsd_m`` the image's ground
    sample distance."""
    slope = np.asarray(slope, dtype=float)
    resolution = np.maximum(cell_m**2 - np.asarray(gsd_m, dtype=float) ** 2, 0.0) / 12.0
    return np.sqrt(np.asarray(sigma_dem_m, dtype=float) ** 2 + slope**2 * (np.asarray(sigma_xy_m, dtype=float) ** 2 + resolution))


@dataclass
class Dem:
    """A DEM raster in memory: ``values`` (rows, columns; NaN where no data) in ``crs`` (the
    horizontal CRS) under the affine ``transform`` (GDAL's: x = c + a col + b row, y = f + d
    col + e row, at pixel corners), heights in ``vertical``."""

    values: np.ndarray
    transform: tuple[float, float, float, float, float, float]  # a, b, c, d, e, f
    crs: CRS
    vertical: VerticalDatum
    source: str = "DEM"
    _to_dem: Transformer = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.values = np.asarray(self.values, dtype=float)
        self._to_dem = transformer("EPSG:4326", self.crs)

    @cached_property
    def cell_m(self) -> float:
        """The cell size in metres (the larger axis; a geographic DEM's at its centre)."""
        a, b, _c, d, e, _f = self.transform
        sx, sy = float(np.hypot(a, d)), float(np.hypot(b, e))
        if self.crs.is_geographic:
            lat = np.radians(self.centre_lon_lat()[1])
            return max(sx * M_PER_DEG * np.cos(lat), sy * M_PER_DEG)
        return max(sx, sy) * float(self.crs.axis_info[0].unit_conversion_factor)

    def centre_lon_lat(self) -> tuple[float, float]:
        rows, cols = self.values.shape
        a, b, c, d, e, f = self.transform
        x, y = c + a * cols / 2 + b * rows / 2, f + d * cols / 2 + e * rows / 2
        lon, lat = transformer(self.crs, "EPSG:4326").transform(x, y)
        return float(lon), float(lat)

    def _pixel(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (column, row) from the first cell's centre."""
        a, b, c, d, e, f = self.transform
        det = a * e - b * d
        dx, dy = x - c, y - f
        col = (e * dx - b * dy) / det - 0.5
        row = (-d * dx + a * dy) / det - 0.5
        return col, row

    def _bilinear(self, col: np.ndarray, row: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Value, d/dcol, d/drow at fractional cell-centre positions (NaN outside or next to no data)."""
        h, w = self.values.shape
        inside = (col >= 0) & (col <= w - 1) & (row >= 0) & (row <= h - 1)
        c0 = np.clip(np.floor(col).astype(np.int64), 0, max(w - 2, 0))
        r0 = np.clip(np.floor(row).astype(np.int64), 0, max(h - 2, 0))
        c1, r1 = np.minimum(c0 + 1, w - 1), np.minimum(r0 + 1, h - 1)
        fc, fr = np.clip(col - c0, 0.0, 1.0), np.clip(row - r0, 0.0, 1.0)
        v = self.values
        v00, v01, v10, v11 = v[r0, c0], v[r0, c1], v[r1, c0], v[r1, c1]
        top = v00 + (v01 - v00) * fc
        bottom = v10 + (v11 - v10) * fc
        value = top + (bottom - top) * fr
        d_col = (v01 - v00) * (1 - fr) + (v11 - v10) * fr
        d_row = bottom - top
        nan = ~inside
        return (np.where(nan, np.nan, value), np.where(nan, np.nan, d_col), np.where(nan, np.nan, d_row))

    def sample(self, lon_deg: np.ndarray, lat_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ellipsoidal heights (n,) and slopes (n, 2: dh/d east, dh/d north, m/m) at WGS 84
        positions; NaN outside the DEM or next to a no-data cell."""
        lon = np.atleast_1d(np.asarray(lon_deg, dtype=float))
        lat = np.atleast_1d(np.asarray(lat_deg, dtype=float))
        # the DEM's axes against local east / north: finite differences of STEP_M metres on the
        # ellipsoid (its radii of curvature at the latitude)
        m_lon, m_lat = metres_per_degree(lat)
        dlon = STEP_M / m_lon
        dlat = STEP_M / m_lat
        xs, ys = self._to_dem.transform(np.concatenate([lon, lon + dlon, lon]), np.concatenate([lat, lat, lat + dlat]))
        xs, ys = np.asarray(xs).reshape(3, -1), np.asarray(ys).reshape(3, -1)
        col, row = self._pixel(xs[0], ys[0])
        value, d_col, d_row = self._bilinear(col, row)
        ce, re = self._pixel(xs[1], ys[1])
        cn, rn = self._pixel(xs[2], ys[2])
        # cells per metre east / north (the DEM's pixel axes against the ground's), then m/m
        dh_de = (d_col * (ce - col) + d_row * (re - row)) / STEP_M
        dh_dn = (d_col * (cn - col) + d_row * (rn - row)) / STEP_M
        heights = value + self.vertical.undulation(lon, lat) if not self.vertical.ellipsoidal else value
        return heights, np.column_stack([dh_de, dh_dn])

    def height(self, lon_deg: np.ndarray, lat_deg: np.ndarray) -> np.ndarray:
        """Ellipsoidal heights only (:meth:`sample`)."""
        return self.sample(lon_deg, lat_deg)[0]

    @property
    def range_m(self) -> tuple[float, float]:
        """The DEM's lowest and highest value (its own datum; (0, 0) without data)."""
        finite = self.values[np.isfinite(self.values)]
        return (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)


def read_dem(path: Path | str, vertical: str | None = None, bounds_lon_lat: tuple[float, float, float, float] | None = None,
             margin_cells: int = 2) -> Dem:
    """A DEM from a raster file (a format the raster gate allows: GeoTIFF, JPEG 2000...), its vertical datum from the file or
    ``vertical`` (:func:`solver.geometry.vertical.resolve`). ``bounds_lon_lat``: (west, south,
    east, north) degrees: only the window covering them (plus ``margin_cells``) is read.
    Raises :class:`DemError` or :class:`solver.geometry.vertical.VerticalDatumError`."""
    from rasterio.windows import Window, from_bounds

    from solver.raster_gate import RasterRefused, open_raster

    shown = Path(path).name
    try:
        gated = open_raster(path, shown=shown)  # the raster gate: allowed formats, local files, no sidecar
    except RasterRefused as exc:
        raise DemError(f"{shown}: cannot read the DEM ({exc.message})") from None
    with gated:
        src = gated.dataset
        if src.crs is None:
            raise DemError(f"{shown}: the DEM has no CRS")
        crs = CRS.from_user_input(src.crs.to_wkt())
        datum = resolve(crs, vertical, where=f"the DEM {shown}")
        horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
        if horizontal.is_geographic and len(horizontal.axis_info) == 3:
            horizontal = horizontal.to_2d()
        window = Window(0, 0, src.width, src.height)
        if bounds_lon_lat is not None:
            w, s, e, n = bounds_lon_lat
            to_dem = transformer("EPSG:4326", horizontal)
            xs, ys = to_dem.transform([w, e, w, e], [s, s, n, n])
            win = from_bounds(min(xs), min(ys), max(xs), max(ys), src.transform)
            col0 = max(int(np.floor(win.col_off)) - margin_cells, 0)
            row0 = max(int(np.floor(win.row_off)) - margin_cells, 0)
            col1 = min(int(np.ceil(win.col_off + win.width)) + margin_cells, src.width)
            row1 = min(int(np.ceil(win.row_off + win.height)) + margin_cells, src.height)
            if col1 <= col0 or row1 <= row0:
                raise DemError(f"{shown}: the DEM does not cover the area asked (longitude {w:.4f} to {e:.4f}, "
                               f"latitude {s:.4f} to {n:.4f})")
            window = Window(col0, row0, col1 - col0, row1 - row0)
        values = src.read(1, window=window, masked=True).astype(float).filled(np.nan)
        t = src.transform
    c0, r0 = float(window.col_off), float(window.row_off)
    corner = (t.c + c0 * t.a + r0 * t.b, t.f + c0 * t.d + r0 * t.e)  # the window's first corner
    return Dem(values, (t.a, t.b, corner[0], t.d, t.e, corner[1]), horizontal, datum, shown)


MAX_JOB_CELLS = 4_000_000  # cells a job may carry (16 MB of float32; a 60 x 60 km scene at 30 m)


def ellipsoidal_grid(dem: Dem) -> np.ndarray:
    """The DEM's values as WGS 84 ellipsoidal heights, cell by cell (its geoid undulation at
    each cell centre added; the values themselves for an ellipsoidal DEM)."""
    if dem.vertical.ellipsoidal:
        return dem.values.copy()
    rows, cols = dem.values.shape
    a, b, c, d, e, f = dem.transform
    cc, rr = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)
    x, y = c + a * cc + b * rr, f + d * cc + e * rr
    lon, lat = transformer(dem.crs, "EPSG:4326").transform(x.ravel(), y.ravel())
    return dem.values + dem.vertical.undulation(np.asarray(lon), np.asarray(lat)).reshape(rows, cols)


def grid_to_job(dem: Dem, max_cells: int = MAX_JOB_CELLS) -> dict:
    """The job document's ``dem.grid`` of ``dem``: its heights converted to ellipsoidal ones
    (so that the solver needs no geoid grid), float32 little-endian, row-major, base64; NaN
    where there is no data. A DEM of more than ``max_cells`` cells is averaged over blocks of
    k x k cells (the smallest k that fits; the cell size, and so the height sigma's resolution
    term, grows by k)."""
    import base64

    values = ellipsoidal_grid(dem)
    a, b, c, d, e, f = dem.transform
    k = 1
    while values.size / (k * k) > max_cells:
        k += 1
    if k > 1:
        rows, cols = (values.shape[0] // k) * k, (values.shape[1] // k) * k
        blocks = values[:rows, :cols].reshape(rows // k, k, cols // k, k)
        with np.errstate(invalid="ignore"):
            values = np.nanmean(blocks, axis=(1, 3)) if np.isfinite(blocks).any() else blocks.mean(axis=(1, 3))
        a, b, d, e = a * k, b * k, d * k, e * k
    data = values.astype("<f4").tobytes()
    return {
        "crs": dem.crs.to_wkt(),
        "transform": [float(a), float(b), float(c), float(d), float(e), float(f)],
        "rows": int(values.shape[0]),
        "columns": int(values.shape[1]),
        "heights": base64.b64encode(data).decode("ascii"),
        "source": dem.source + (f" (averaged over {k} x {k} cells)" if k > 1 else ""),
        "vertical": dem.vertical.name + ("" if dem.vertical.ellipsoidal else ", converted to WGS 84 ellipsoidal heights"),
    }


def grid_from_job(grid: dict) -> Dem:
    """The :class:`Dem` of a job's ``dem.grid`` (ellipsoidal heights). Raises :class:`DemError`
    when the heights do not decode to rows x columns float32 values."""
    import base64
    import binascii

    try:
        raw = base64.b64decode(grid["heights"], validate=True)
    except (binascii.Error, ValueError):
        raise DemError("dem.grid.heights is not base64") from None
    rows, cols = int(grid["rows"]), int(grid["columns"])
    if len(raw) != 4 * rows * cols:
        raise DemError(f"dem.grid.heights holds {len(raw) // 4} values, rows x columns is {rows * cols}")
    values = np.frombuffer(raw, dtype="<f4").astype(float).reshape(rows, cols)
    try:
        crs = CRS.from_user_input(grid["crs"])
    except Exception as exc:  # pyproj raises CRSError; any failure is the same bad input
        raise DemError(f"dem.grid.crs: {exc}") from None
    a, b, _c, d, e, _f = grid["transform"]
    if a * e - b * d == 0:
        raise DemError("dem.grid.transform is singular")
    ellipsoidal = VerticalDatum(None, "WGS 84 ellipsoidal heights", "the job (converted when it was composed)")
    return Dem(values, tuple(float(t) for t in grid["transform"]), crs, ellipsoidal, str(grid.get("source", "DEM")))
