"""The terrain's height range for matching, narrowed by a DEM.

Without a DEM the range is the orientation's (the RPCs' whole range, or the job's points
+- 100 m: :mod:`solver.matching.orientation`), and matching searches all of it (each tile of a
large image narrowed by its neighbours' matches: :class:`solver.matching.features.TileHeights`).
With a DEM (``pba match --dem``), the range is the DEM's ellipsoidal heights under the images'
footprints (over the orientation's range) widened by :data:`DEM_MARGIN_M`, and each tile's the
DEM's heights under the tile (:class:`DemHeights`): shorter search bands, fewer candidates,
faster matching.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from solver.matching.orientation import MatchImage, OrientationError

DEM_MARGIN_M = 50.0  # the DEM's error (SRTM, Copernicus: 5-16 m) and what a sampled grid can miss between cells
MAX_SAMPLES_PER_SIDE = 513  # DEM samples per side of the images' footprint box (at most one per DEM cell)
FOOTPRINT_NODES = 9  # points per image edge for the footprint
TILE_SAMPLES_PER_SIDE = 9  # the fewest DEM samples per side of a tile's footprint


def _border_lon_lat(image: MatchImage, lo: tuple[float, float], hi: tuple[float, float], heights: tuple[float, ...],
                    nodes: int) -> np.ndarray:
    """(k, 2) longitude and latitude (degrees) of the border of the window ``lo``..``hi``
    (line, column; ``hi`` exclusive) of ``image`` on the ground at each of ``heights``,
    ``nodes`` points per edge; the points that reach the ground only."""
    from solver.geometry.geodesy import ecef_to_geodetic

    t = np.linspace(0.0, 1.0, nodes)
    l0, c0, l1, c1 = float(lo[0]), float(lo[1]), float(hi[0]) - 1.0, float(hi[1]) - 1.0
    line = np.concatenate([l0 + t * (l1 - l0), l0 + t * (l1 - l0), np.full(nodes, l0), np.full(nodes, l1)])
    col = np.concatenate([np.full(nodes, c0), np.full(nodes, c1), c0 + t * (c1 - c0), c0 + t * (c1 - c0)])
    with np.errstate(all="ignore"):
        llh = np.vstack([ecef_to_geodetic(image.model.image_to_ground(line, col, height_m=float(h))) for h in heights])
    return llh[np.all(np.isfinite(llh), axis=1), :2]


def _box(lon_lat: np.ndarray) -> tuple[float, float, float, float] | None:
    """(west, south, east, north) of the points, None without any."""
    if not len(lon_lat):
        return None
    return float(lon_lat[:, 0].min()), float(lon_lat[:, 1].min()), float(lon_lat[:, 0].max()), float(lon_lat[:, 1].max())


def footprint_lon_lat(images: list[MatchImage], heights: tuple[float, float]) -> tuple[float, float, float, float] | None:
    """(west, south, east, north) degrees of the images' borders on the ground at the lowest and
    the highest height; None when no border point reaches the ground."""
    return _box(np.vstack([_border_lon_lat(im, (0.0, 0.0), (im.lines, im.columns), heights, FOOTPRINT_NODES) for im in images]))


class DemHeights:
    """The DEM's ellipsoidal heights under a window of an image, +- :data:`DEM_MARGIN_M`: the
    window's border on the ground at the lowest and the highest height of ``heights`` (its
    footprint box), sampled about once per DEM cell (at least :data:`TILE_SAMPLES_PER_SIDE`
    per side); None where the DEM covers less than half of it."""

    def __init__(self, dem, heights: tuple[float, float]):
        self.dem, self.heights = dem, heights

    def __call__(self, image: MatchImage, lo: np.ndarray, hi: np.ndarray) -> tuple[float, float] | None:
        box = _box(_border_lon_lat(image, (lo[0], lo[1]), (hi[0], hi[1]), self.heights, 3))
        if box is None:
            return None
        h_lo, h_hi = _sampled_range(self.dem, box, need=0.5, least=TILE_SAMPLES_PER_SIDE)
        if h_lo is None or h_hi is None:
            return None
        return float(np.floor(h_lo - DEM_MARGIN_M)), float(np.ceil(h_hi + DEM_MARGIN_M))


def dem_height_range(images: list[MatchImage], heights: tuple[float, float], dem_path: Path, vertical: str | None = None) -> tuple[float, float]:
    """The DEM's ellipsoidal heights (its vertical datum from the file or ``vertical``) under the
    images' footprints over ``heights``, +- :data:`DEM_MARGIN_M`. Raises
    :class:`OrientationError` when the DEM cannot be read or does not cover the images."""
    return dem_heights(images, heights, dem_path, vertical)[0]


def dem_heights(images: list[MatchImage], heights: tuple[float, float], dem_path: Path, vertical: str | None = None) -> tuple[tuple[float, float], DemHeights]:
    """:func:`dem_height_range`, and the DEM's heights per window of an image over that range
    (:class:`DemHeights`)."""
    from solver.geometry.dem import DemError, read_dem
    from solver.geometry.vertical import VerticalDatumError

    box = footprint_lon_lat(images, heights)
    if box is None:
        raise OrientationError("the images' footprints do not reach the ground: no DEM range")
    try:
        dem = read_dem(dem_path, vertical, bounds_lon_lat=box)
    except (DemError, VerticalDatumError) as exc:
        raise OrientationError(f"--dem: {exc}") from None
    lo, hi = _sampled_range(dem, box)  # the terrain under the widest footprint ...
    if lo is not None:
        box = footprint_lon_lat(images, (lo, hi)) or box  # ... then under the footprint at the DEM's heights
    h_lo, h_hi = _sampled_range(dem, box, need=0.5)
    if h_lo is None:
        west, south, east, north = box
        raise OrientationError(f"--dem {Path(dem_path).name}: the DEM does not cover the images' footprints "
                               f"({west:.4f} to {east:.4f} E, {south:.4f} to {north:.4f} N)")
    whole = float(np.floor(h_lo - DEM_MARGIN_M)), float(np.ceil(h_hi + DEM_MARGIN_M))
    return whole, DemHeights(dem, whole)


def _sampled_range(dem, box: tuple[float, float, float, float], need: float = 0.0, least: int = 33) -> tuple[float | None, float | None]:
    """The lowest and highest ellipsoidal DEM height on a grid over ``box`` (about one sample per
    DEM cell, at least ``least`` per side); (None, None) when fewer than ``need`` of the samples
    have a height."""
    west, south, east, north = box
    size_m = max(east - west, north - south) * 111_000.0
    n = int(np.clip(np.ceil(size_m / max(dem.cell_m, 1e-3)) + 1, least, MAX_SAMPLES_PER_SIDE))
    lon, lat = np.meshgrid(np.linspace(west, east, n), np.linspace(south, north, n))
    h = dem.height(lon.ravel(), lat.ravel())
    h = h[np.isfinite(h)]
    if not h.size or h.size < need * lon.size:
        return None, None
    return float(h.min()), float(h.max())
