"""Control points from an orthophoto (``pba match-gcp IMAGE ORTHO [--dem DEM]``; docs/matching.md).

1. **Candidates.** The image's footprint (its border taken to the ground at the terrain's
   middle height) is drawn in the orthophoto. In each cell of a ``grid`` x ``grid`` division of
   the part inside the orthophoto, the strongest corner (OpenCV ``goodFeaturesToTrack``) is a
   candidate; a cell without texture gives none.
2. **Ground.** The candidate's map coordinates (the orthophoto's CRS and geotransform, pixel
   centres) become longitude and latitude, and its ellipsoidal height comes from the DEM
   (bilinear, :mod:`solver.geometry.dem`; ``--dem``, its vertical datum from the file or
   ``--dem-vertical``, converted to ellipsoidal heights) or is the constant ``--height``. With
   ``--dem-sigma`` (the DEM's stated accuracy) each point gets survey sigmas: the orthophoto's
   pixel horizontally (its georeferencing, at best) and the DEM height's sigma of
   docs/datum.md (the accuracy, the slope times that pixel, the DEM's cell against it).
3. **Prediction.** The image model (the job's orientation, or the raster's RPC) projects that
   ground point into the image. The local affine from orthophoto pixels to image pixels is
   taken by finite differences (2 orthophoto pixels, with the DEM's heights).
4. **Correlation.** A template of the orthophoto around the candidate is compared with the
   image resampled into the orthophoto's geometry by that affine: first over the search range
   (normalised cross-correlation, the integer peak), then refined to sub-pixel as tie points are
   (:func:`solver.matching.refine.correlate`). A peak below ``min_ncc`` loses the candidate.
   Sizes follow the image's pixels: the template spans at least ``template_half_px`` image
   pixels each side and the search ``search_px`` image pixels, whatever the orthophoto's
   pixel size (a finer orthophoto gets a larger template in its own pixels).
5. **Consistency.** The orientation's error is smooth over an image: measured minus predicted
   positions are fitted robustly by an affine function of the image position (per axis,
   iteratively, points beyond ``max(3.5 sigma, 1 px)`` excluded, sigma from the median absolute
   deviation). The points beyond are removed; the RMS scatter of the rest, per axis, is the
   ``sigma_px`` of the measurements.

The result: control points (``id, x = longitude, y = latitude, z = ellipsoidal height``, CRS
EPSG:4979) and their measurements in the image (``image, point, line, column, sigma_px``).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from solver.geometry.geodesy import transformer
from solver.matching.features import MatchSettings
from solver.matching.orientation import MatchImage, OrientationError
from solver.matching.raster import RasterError
from solver.matching.refine import correlate

GCP_CRS = "EPSG:4979"  # longitude, latitude (degrees), ellipsoidal height (m)
JACOBIAN_STEP_PX = 2.0  # orthophoto pixels of the finite differences
CONSISTENCY_FLOOR_PX = 1.0  # a residual within this of the smooth fit is never removed
SIGMA_FLOOR_PX = 0.05  # the least sigma written
MIN_POINTS_FOR_FIT = 6
MIN_SEARCH_PX = 5  # orthophoto pixels searched at least, whatever the scale
FOOTPRINT_NODES = 9


class GcpError(ValueError):
    """Control points cannot be matched (the message says why)."""


@dataclass
class Georaster:
    """A georeferenced raster (orthophoto or DEM), band 1, read through rasterio."""

    path: Path
    dataset: Any

    gated: Any = None  # solver.raster_gate.GatedRaster: closed with close()

    @classmethod
    def open(cls, path: Path, what: str) -> "Georaster":
        """Open ``path`` through the raster gate (:mod:`solver.raster_gate`; its georeferencing
        must be inside the file); :class:`RasterError` when refused or not georeferenced."""
        from solver.raster_gate import RasterRefused, open_raster

        path = Path(path)
        try:
            gated = open_raster(path)
        except RasterRefused as exc:
            raise RasterError(exc.message if exc.message.startswith(str(path)) else f"{path}: {exc.message}") from None
        ds = gated.dataset
        if ds.crs is None or ds.transform.is_identity:
            gated.close()
            raise RasterError(f"{path}: the {what} has no CRS or geotransform inside the file (it must be georeferenced)")
        if ds.transform.b != 0 or ds.transform.d != 0:
            gated.close()
            raise RasterError(f"{path}: the {what}'s geotransform is rotated (not supported)")
        return cls(path, ds, gated)

    def to_lonlat(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = transformer(self.dataset.crs, "EPSG:4326")
        lon, lat = t.transform(x, y)
        return np.asarray(lon, float), np.asarray(lat, float)

    def from_lonlat(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = transformer("EPSG:4326", self.dataset.crs)
        x, y = t.transform(lon, lat)
        return np.asarray(x, float), np.asarray(y, float)

    def pixel_to_map(self, row: np.ndarray, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map coordinates of pixel centres (row, col: 0 at the first pixel's centre)."""
        t = self.dataset.transform
        return t.c + t.a * (col + 0.5), t.f + t.e * (row + 0.5)

    def map_to_pixel(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = self.dataset.transform
        return (y - t.f) / t.e - 0.5, (x - t.c) / t.a - 0.5

    def read(self, row0: int, col0: int, rows: int, cols: int) -> np.ndarray:
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return self.dataset.read(1, window=Window(col0, row0, cols, rows), boundless=True, fill_value=0).astype(np.float32)
        except (RasterioError, OSError, ValueError) as exc:
            raise RasterError(f"{self.path}: cannot read its pixels (truncated or corrupt file?): {exc}") from None

    def sample(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Band 1 at geographic points, bilinear (a DEM's heights); NaN outside or on nodata."""
        x, y = self.from_lonlat(lon, lat)
        r, c = self.map_to_pixel(x, y)
        r0, c0 = int(np.floor(np.nanmin(r))) - 1, int(np.floor(np.nanmin(c))) - 1
        r1, c1 = int(np.ceil(np.nanmax(r))) + 2, int(np.ceil(np.nanmax(c))) + 2
        h, w = self.dataset.height, self.dataset.width
        r0, c0, r1, c1 = max(r0, 0), max(c0, 0), min(r1, h), min(c1, w)
        if r1 - r0 < 2 or c1 - c0 < 2:
            return np.full(np.shape(lon), np.nan)
        z = self.read(r0, c0, r1 - r0, c1 - c0).astype(float)
        if self.dataset.nodata is not None:
            z[z == self.dataset.nodata] = np.nan
        rr, cc = r - r0, c - c0
        i, j = np.floor(rr).astype(int), np.floor(cc).astype(int)
        ok = (i >= 0) & (j >= 0) & (i < z.shape[0] - 1) & (j < z.shape[1] - 1)
        i, j = np.clip(i, 0, z.shape[0] - 2), np.clip(j, 0, z.shape[1] - 2)
        fr, fc = rr - i, cc - j
        v = (z[i, j] * (1 - fr) * (1 - fc) + z[i, j + 1] * (1 - fr) * fc + z[i + 1, j] * fr * (1 - fc) + z[i + 1, j + 1] * fr * fc)
        return np.where(ok, v, np.nan)

    def close(self) -> None:
        if self.gated is not None:
            self.gated.close()  # the dataset, its descriptors and private folder
        else:
            self.dataset.close()


@dataclass
class GcpResult:
    points: list[dict[str, Any]]
    measurements: list[dict[str, Any]]
    summary: dict[str, Any]


def control_points_csv(points: list[dict[str, Any]]) -> str:
    """The control points table the importers read (:mod:`solver.importers.points_csv`):
    ``id,x,y,z,role`` with the CRS in a comment (``--crs EPSG:4979`` for ``pba job --gcps``)."""
    if points and all("sigma_m" in p for p in points):
        rows = [f"# crs: {GCP_CRS}", "id,x,y,z,sigma_x,sigma_y,sigma_z,role"]
        rows += [f"{p['id']},{p['coordinates'][0]:.9f},{p['coordinates'][1]:.9f},{p['coordinates'][2]:.3f},"
                 f"{p['sigma_m'][0]:.3f},{p['sigma_m'][1]:.3f},{p['sigma_m'][2]:.3f},{p['role']}" for p in points]
        return "\n".join(rows) + "\n"
    rows = [f"# crs: {GCP_CRS}", "id,x,y,z,role"]
    rows += [f"{p['id']},{p['coordinates'][0]:.9f},{p['coordinates'][1]:.9f},{p['coordinates'][2]:.3f},{p['role']}" for p in points]
    return "\n".join(rows) + "\n"


class DemHeights:
    """The DEM under the orthophoto (:func:`solver.geometry.dem.read_dem`: its window, its
    vertical datum resolved): ``sample(lon, lat)`` -> ellipsoidal heights."""

    def __init__(self, path: Path, vertical: str | None, ortho: Georaster):
        from solver.geometry.dem import read_dem

        self.path = Path(path)
        if not self.path.is_file():
            raise RasterError(f"{path}: no such file")
        t = np.linspace(0.0, 1.0, 3)
        rr, cc = np.meshgrid(t * ortho.dataset.height, t * ortho.dataset.width, indexing="ij")
        lon, lat = ortho.to_lonlat(*ortho.pixel_to_map(rr.ravel() - 0.5, cc.ravel() - 0.5))
        self.dem = read_dem(self.path, vertical, bounds_lon_lat=(lon.min(), lat.min(), lon.max(), lat.max()))

    def sample(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        return self.dem.sample(lon, lat)[0]

    def slope(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """|grad h| (m/m)."""
        s = self.dem.sample(lon, lat)[1]
        return np.hypot(s[:, 0], s[:, 1])

    def close(self) -> None:
        return None


def _heights(dem: DemHeights | None, height_m: float | None, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    if dem is not None:
        return dem.sample(lon, lat)
    return np.full(np.shape(lon), float(height_m))


def _predict(image: MatchImage, ortho: Georaster, dem: DemHeights | None, height_m: float | None, row: np.ndarray, col: np.ndarray):
    """(image line, image column, lon, lat, h) of orthophoto pixels."""
    from solver.geometry.geodesy import geodetic_to_ecef

    lon, lat = ortho.to_lonlat(*ortho.pixel_to_map(np.asarray(row, float), np.asarray(col, float)))
    h = _heights(dem, height_m, lon, lat)
    with np.errstate(all="ignore"):
        line, column, _ = image.model.ground_to_image(geodetic_to_ecef(np.column_stack([lon, lat, h])))
    return np.asarray(line, float), np.asarray(column, float), lon, lat, h


def _footprint_box(image: MatchImage, ortho: Georaster, height: float) -> tuple[int, int, int, int] | None:
    """(row0, col0, row1, col1) of the image's footprint in the orthophoto, clipped to it."""
    from solver.geometry.geodesy import ecef_to_geodetic

    t = np.linspace(0, 1, FOOTPRINT_NODES)
    L, C = image.lines - 1.0, image.columns - 1.0
    line = np.concatenate([t * L, t * L, np.zeros_like(t), np.full_like(t, L)])
    col = np.concatenate([np.zeros_like(t), np.full_like(t, C), t * C, t * C])
    with np.errstate(all="ignore"):
        llh = ecef_to_geodetic(image.model.image_to_ground(line, col, height_m=height))
    ok = np.all(np.isfinite(llh), axis=1)
    if not ok.any():
        return None
    r, c = ortho.map_to_pixel(*ortho.from_lonlat(llh[ok, 0], llh[ok, 1]))
    r0, c0 = max(int(np.floor(r.min())), 0), max(int(np.floor(c.min())), 0)
    r1, c1 = min(int(np.ceil(r.max())) + 1, ortho.dataset.height), min(int(np.ceil(c.max())) + 1, ortho.dataset.width)
    return (r0, c0, r1, c1) if r1 > r0 and c1 > c0 else None


def _candidates(ortho: Georaster, box: tuple[int, int, int, int], grid: int, margin: int) -> list[tuple[int, int]]:
    """The strongest corner (orthophoto row, column) of each grid cell of ``box``."""
    import cv2

    r0, c0, r1, c1 = box
    out = []
    rows = np.linspace(r0, r1, grid + 1).astype(int)
    cols = np.linspace(c0, c1, grid + 1).astype(int)
    for a in range(grid):
        for b in range(grid):
            h, w = rows[a + 1] - rows[a], cols[b + 1] - cols[b]
            if h <= 2 * margin or w <= 2 * margin:
                continue
            win = ortho.read(rows[a], cols[b], h, w)
            lo, hi = np.percentile(win, [0.5, 99.5])
            if hi - lo <= 0:
                continue
            img8 = np.clip((win - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)
            mask = np.zeros_like(img8)
            mask[margin:h - margin, margin:w - margin] = 255
            found = cv2.goodFeaturesToTrack(img8, maxCorners=1, qualityLevel=0.01, minDistance=margin, mask=mask)
            if found is not None:
                x, y = found[0, 0]
                out.append((int(rows[a] + round(float(y))), int(cols[b] + round(float(x)))))
    return out


def _coarse(tpl: np.ndarray, image: MatchImage, start: np.ndarray, jac: np.ndarray, search: int) -> np.ndarray | None:
    """The integer-shift peak of the NCC of the orthophoto template against the image
    resampled into the orthophoto's geometry over +-``search`` orthophoto pixels: the image
    position of the template's centre, or None (peak on the border, or outside the image)."""
    import cv2

    half = tpl.shape[0] // 2
    radius = half + search
    u = np.arange(-radius, radius + 1, dtype=float)
    uu, vv = np.meshgrid(u, u, indexing="ij")
    lines = start[0] + jac[0, 0] * uu + jac[0, 1] * vv
    cols = start[1] + jac[1, 0] * uu + jac[1, 1] * vv
    r0, c0 = int(np.floor(lines.min())) - 3, int(np.floor(cols.min())) - 3
    r1, c1 = int(np.ceil(lines.max())) + 4, int(np.ceil(cols.max())) + 4
    if r0 < 0 or c0 < 0 or r1 > image.lines or c1 > image.columns:
        return None
    win = image.raster.window(r0, c0, r1 - r0, c1 - c0)
    warped = cv2.remap(win, (cols - c0).astype(np.float32), (lines - r0).astype(np.float32), cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    res = cv2.matchTemplate(warped, tpl, cv2.TM_CCOEFF_NORMED)
    i, j = np.unravel_index(int(np.argmax(res)), res.shape)
    if i in (0, res.shape[0] - 1) or j in (0, res.shape[1] - 1) or not np.isfinite(res[i, j]):
        return None
    return start + jac @ np.array([i - search, j - search], float)


def _consistent(pred: np.ndarray, meas: np.ndarray, lines: int, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """(kept mask, sigma per axis px) of measured - predicted positions about a robust affine
    fit of the image position (module docstring, step 5)."""
    n = len(meas)
    d = meas - pred
    keep = np.ones(n, bool)
    if n < MIN_POINTS_FOR_FIT:
        return keep, np.full(2, SIGMA_FLOOR_PX)
    a = np.column_stack([np.ones(n), meas[:, 0] / max(lines, 1), meas[:, 1] / max(columns, 1)])
    sigma = np.full(2, SIGMA_FLOOR_PX)
    resid = d
    for _ in range(10):
        coef = np.linalg.lstsq(a[keep], d[keep], rcond=None)[0]
        resid = d - a @ coef
        sigma = np.maximum(1.4826 * np.median(np.abs(resid[keep]), axis=0), SIGMA_FLOOR_PX)
        new = np.all(np.abs(resid) <= np.maximum(3.5 * sigma, CONSISTENCY_FLOOR_PX), axis=1)
        if np.array_equal(new, keep) or new.sum() < MIN_POINTS_FOR_FIT:
            break
        keep = new
    sigma = np.maximum(np.sqrt(np.mean(resid[keep] ** 2, axis=0)), SIGMA_FLOOR_PX)
    return keep, sigma


def match_gcps(image: MatchImage, ortho_path: Path, dem_path: Path | None, height_m: float | None,
               settings: MatchSettings = MatchSettings(), progress: Callable[[float, str], None] | None = None,
               dem_vertical: str | None = None, dem_sigma_m: float | None = None) -> GcpResult:
    """Control points of ``image`` from the orthophoto (module docstring). ``height_m``: the
    terrain's ellipsoidal height where there is no DEM (one of the two is needed);
    ``dem_vertical``: the DEM's vertical datum where its file does not state it;
    ``dem_sigma_m``: the DEM's accuracy (the points then get survey sigmas)."""
    say = progress or (lambda f, m: None)
    if dem_path is None and height_m is None:
        raise GcpError("give the terrain: --dem DEM or --height METRES (ellipsoidal)")
    ortho = Georaster.open(ortho_path, "orthophoto")
    try:
        dem = DemHeights(dem_path, dem_vertical, ortho) if dem_path is not None else None
        result = _match(image, ortho, dem, height_m, settings, say)
        if dem is not None:
            result.summary["dem"] = {"path": str(dem.path), "vertical": dem.dem.vertical.to_dict(), "cell_m": round(dem.dem.cell_m, 3)}
            if dem_sigma_m is not None:
                _dem_sigmas(result, dem, ortho, dem_sigma_m)
        return result
    finally:
        ortho.close()


def _dem_sigmas(result: GcpResult, dem: DemHeights, ortho: Georaster, dem_sigma_m: float) -> None:
    """Survey sigmas of the points (module docstring, step 2), in place."""
    from solver.geometry.dem import height_sigma

    t = ortho.dataset.transform
    lat = np.array([p["coordinates"][1] for p in result.points])
    lon = np.array([p["coordinates"][0] for p in result.points])
    pixel = abs(t.a) * (111_319.49 * np.cos(np.radians(lat)) if ortho.dataset.crs.is_geographic else 1.0)
    vertical = height_sigma(dem_sigma_m, dem.slope(lon, lat), pixel, dem.dem.cell_m, pixel)
    for p, sh, sv in zip(result.points, np.broadcast_to(pixel, lat.shape), vertical, strict=True):
        p["sigma_m"] = [round(float(sh), 3), round(float(sh), 3), round(float(sv), 3)]
    result.summary["dem"]["sigma_m"] = dem_sigma_m


def _match(image: MatchImage, ortho: Georaster, dem: DemHeights | None, height_m: float | None, s: MatchSettings, say) -> GcpResult:
    import cv2

    cv2.setNumThreads(1)
    half = s.template_half_px
    mid = height_m
    if dem is not None:  # the footprint's height: the DEM's median over the orthophoto
        t = np.linspace(0.0, 1.0, FOOTPRINT_NODES)
        rr, cc = np.meshgrid(t * (ortho.dataset.height - 1), t * (ortho.dataset.width - 1), indexing="ij")
        z = dem.sample(*ortho.to_lonlat(*ortho.pixel_to_map(rr.ravel(), cc.ravel())))
        if not np.isfinite(z).any():
            raise GcpError(f"{dem.path}: the DEM has no height under the orthophoto")
        mid = float(np.nanmedian(z))
    box = _footprint_box(image, ortho, float(mid))
    if box is None:
        raise GcpError(f"{ortho.path}: the image {image.id!r} does not fall on the orthophoto")
    # the template and the search in orthophoto pixels: at least the tie points' template in
    # image pixels, and the search's image pixels (scale: image pixels per orthophoto pixel)
    r_mid, c_mid = 0.5 * (box[0] + box[2]), 0.5 * (box[1] + box[3])
    line, col, *_ = _predict(image, ortho, dem, height_m, np.array([r_mid, r_mid + JACOBIAN_STEP_PX, r_mid]), np.array([c_mid, c_mid, c_mid + JACOBIAN_STEP_PX]))
    scale = float(np.sqrt(abs((line[1] - line[0]) * (col[2] - col[0]) - (line[2] - line[0]) * (col[1] - col[0])))) / JACOBIAN_STEP_PX
    if not np.isfinite(scale) or scale <= 0:
        raise GcpError(f"the orientation does not map the orthophoto's part under image {image.id!r} into the image")
    half = max(half, int(np.ceil(half / scale)))
    search = max(MIN_SEARCH_PX, int(np.ceil(s.search_px / scale)))
    say(0.05, "candidates")
    cands = _candidates(ortho, box, s.grid, half + 2)
    rows: list[dict[str, Any]] = []
    for k, (r, c) in enumerate(cands):
        if k % 10 == 0:
            say(0.05 + 0.9 * k / max(len(cands), 1), "correlation")
        rr = np.array([r, r + JACOBIAN_STEP_PX, r, r], float)
        cc = np.array([c, c, c + JACOBIAN_STEP_PX, c], float)
        line, col, lon, lat, h = _predict(image, ortho, dem, height_m, rr[:3], cc[:3])
        if not np.all(np.isfinite(line)) or not np.all(np.isfinite(col)):
            continue
        jac = np.array([[line[1] - line[0], line[2] - line[0]], [col[1] - col[0], col[2] - col[0]]]) / JACOBIAN_STEP_PX
        start = np.array([line[0], col[0]])
        tpl = ortho.read(r - half, c - half, 2 * half + 1, 2 * half + 1)
        if float(tpl.std()) <= 0:
            continue
        coarse = _coarse(tpl, image, start, jac, search)
        if coarse is None:
            continue
        fine = correlate(tpl, image, coarse, jac, s.min_ncc)
        if fine is None:
            continue
        rows.append({"pred": start, "meas": fine[0], "ncc": fine[1], "lon": float(lon[0]), "lat": float(lat[0]), "h": float(h[0])})
    say(0.95, "consistency")
    if not rows:
        raise GcpError(f"no control point matched between {image.id!r} and {ortho.path} ({len(cands)} candidates)")
    keep, sigma = _consistent(np.array([x["pred"] for x in rows]), np.array([x["meas"] for x in rows]), image.lines, image.columns)
    kept = [x for x, ok in zip(rows, keep, strict=True) if ok]
    width = max(4, len(str(len(kept))))
    points, measurements = [], []
    sig = float(np.round(np.sqrt(np.mean(sigma**2)), 3))
    for n, x in enumerate(kept, start=1):
        pid = f"G{n:0{width}d}"
        points.append({"id": pid, "role": "gcp", "coordinates": [round(x["lon"], 9), round(x["lat"], 9), round(x["h"], 3)]})
        measurements.append({"image": image.id, "point": pid, "line": round(float(x["meas"][0]), 3), "column": round(float(x["meas"][1]), 3), "sigma_px": sig})
    offsets = np.array([x["meas"] - x["pred"] for x in kept])
    summary = {
        "image": image.id, "orthophoto": str(ortho.path), "dem": str(dem.path) if dem else None, "height_m": height_m,
        "candidates": len(cands), "correlated": len(rows), "removed_inconsistent": int((~keep).sum()), "control_points": len(kept),
        "sigma_px": {"line": round(float(sigma[0]), 3), "column": round(float(sigma[1]), 3)},
        "median_offset_px": {"line": round(float(np.median(offsets[:, 0])), 3), "column": round(float(np.median(offsets[:, 1])), 3)},
        "median_ncc": round(float(np.median([x["ncc"] for x in kept])), 3), "crs": GCP_CRS,
    }
    say(1.0, "done")
    return GcpResult(points, measurements, summary)


__all__ = ["GCP_CRS", "GcpError", "GcpResult", "OrientationError", "control_points_csv", "match_gcps"]
