"""Heights from a DEM raster (GeoTIFF or any raster GDAL reads) for image-to-ground intersections.

The DEM's values are taken as ellipsoidal heights in metres (convert an orthometric DEM with its
geoid first, e.g. ``gdalwarp -t_srs EPSG:4979``); they are interpolated bilinearly between
pixel centres in the DEM's own CRS. Points outside the DEM or on no-data get NaN.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from solver.geometry.geodesy import transformer


class Dem:
    """A DEM held in memory: ``height(lon_deg, lat_deg)`` (WGS 84) -> ellipsoidal metres."""

    def __init__(self, path: Path | str):
        from solver.raster_gate import open_raster

        with open_raster(path) as gated:  # the raster gate: allowed formats, local files, no sidecar
            src = gated.dataset
            self.values = src.read(1, masked=True).astype(float).filled(np.nan)
            self.inverse = ~src.transform
            if src.crs is None:
                raise ValueError(f"{path}: the DEM has no CRS")
            self._to_dem = transformer("EPSG:4326", src.crs)
        finite = self.values[np.isfinite(self.values)]
        self.range_m = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)

    def height(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        x, y = self._to_dem.transform(np.asarray(lon, float), np.asarray(lat, float))
        a = self.inverse
        x, y = np.asarray(x), np.asarray(y)
        c = a.a * x + a.b * y + a.c - 0.5  # pixel-centre grid
        r = a.d * x + a.e * y + a.f - 0.5
        h, w = self.values.shape
        c0 = np.clip(np.floor(c).astype(int), 0, max(w - 2, 0))
        r0 = np.clip(np.floor(r).astype(int), 0, max(h - 2, 0))
        fc, fr = c - c0, r - r0
        inside = (c >= -0.5) & (c <= w - 0.5) & (r >= -0.5) & (r <= h - 0.5)
        fc, fr = np.clip(fc, 0.0, 1.0), np.clip(fr, 0.0, 1.0)
        c1, r1 = np.minimum(c0 + 1, w - 1), np.minimum(r0 + 1, h - 1)
        v = self.values
        out = (v[r0, c0] * (1 - fc) * (1 - fr) + v[r0, c1] * fc * (1 - fr) + v[r1, c0] * (1 - fc) * fr + v[r1, c1] * fc * fr)
        return np.where(inside, out, np.nan)
