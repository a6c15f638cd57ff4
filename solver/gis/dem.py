"""Heights from a DEM raster for image-to-ground intersections, orthoimages and RPC fit grids.

The DEM is read like the adjustment's (:func:`solver.geometry.dem.read_dem`: the raster gate,
bilinear between cell centres in the DEM's own CRS) and its heights are converted to WGS 84
ellipsoidal heights by its vertical datum (:mod:`solver.geometry.vertical`): taken from the
file's CRS (a compound CRS with a vertical part, or a 3D geographic CRS) or from the caller
(``--dem-vertical ellipsoid | egm96 | egm2008 | EPSG:code``), never assumed. SRTM and the
Copernicus DEM hold heights above a geoid (EGM96, EGM2008), up to 107 m from the ellipsoidal
ones. Points outside the DEM or next to no-data get NaN.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from solver.geometry.dem import Dem as _Grid
from solver.geometry.dem import DemError, read_dem
from solver.geometry.vertical import VerticalDatumError

__all__ = ["Dem", "DemError", "VerticalDatumError"]

RANGE_NODES = 25  # nodes per axis at which the geoid undulation is taken for the height range


class Dem:
    """A DEM held in memory: ``height(lon_deg, lat_deg)`` (WGS 84) -> ellipsoidal metres.

    ``vertical``: the DEM's vertical datum where its file does not state it
    (:func:`solver.geometry.vertical.resolve`). Raises :class:`DemError` (unreadable, no CRS)
    or :class:`VerticalDatumError` (no datum stated, contradictory, geoid grid missing)."""

    def __init__(self, path: Path | str, vertical: str | None = None):
        self.grid: _Grid = read_dem(path, vertical)
        self.vertical = self.grid.vertical

    def height(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Ellipsoidal heights (metres) at WGS 84 longitudes and latitudes (degrees)."""
        return self.grid.height(np.asarray(lon, float), np.asarray(lat, float))

    def undulation_grid(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Ellipsoidal minus the DEM's own heights (metres) at WGS 84 positions: 0 for an
        ellipsoidal DEM, the geoid undulation N otherwise."""
        return self.vertical.undulation(np.asarray(lon, float), np.asarray(lat, float))

    @property
    def range_m(self) -> tuple[float, float]:
        """The lowest and highest ellipsoidal height the DEM can give (metres): its values'
        range plus the range of the undulation over its extent (on a RANGE_NODES grid; the
        geoid varies over hundreds of kilometres, so this envelope is tight within centimetres
        on a scene)."""
        low, high = self.grid.range_m
        if self.vertical.ellipsoidal:
            return low, high
        rows, cols = self.grid.values.shape
        a, b, c, d, e, f = self.grid.transform
        cc, rr = np.meshgrid(np.linspace(0, cols, RANGE_NODES), np.linspace(0, rows, RANGE_NODES))
        x, y = c + a * cc + b * rr, f + d * cc + e * rr
        from solver.geometry.geodesy import transformer

        lon, lat = transformer(self.grid.crs, "EPSG:4326").transform(x.ravel(), y.ravel())
        n = self.undulation_grid(np.asarray(lon), np.asarray(lat))
        return low + float(n.min()), high + float(n.max())
