"""Raster access for matching: windows and decimated reads through GDAL (rasterio). An image
of at most :data:`WHOLE_MAX_PX` pixels is read whole at its first full-resolution window and
its windows are then slices of that array (the same values: a correlation reads a few thousand
small windows, each a GDAL call); a larger image is never held whole.

Pixel convention: our image coordinates (line, column) are those of pixel centres with the
top-left pixel's centre at (0, 0) (:mod:`solver.schema.job`), so the array index of a window
read at (row_off, col_off) is ``line - row_off``, ``column - col_off`` exactly.

Radiometry: band 1, 8 to 16 bits (integers) or floats. For feature detection a window is
stretched to 8 bits between the 0.5 and 99.5 percentiles of a decimated read of the whole
image (at most :data:`STATS_SIZE` pixels on its long side; GDAL takes an overview level when
the file has one); correlation works on the raw values (NCC is gain and offset invariant).

Threads: reads are serialised, one at a time in the process (:data:`_READ_LOCK`): a GDAL
dataset is not read from two threads at once, and the warnings filters a read sets aside are
global. The matching's detection thread (:mod:`solver.matching.keypoints`) spends most of its
time in SIFT, not in reads.
"""

from __future__ import annotations

import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

MAX_SIDE_PX = 1_000_000  # an image side beyond this is refused (no sensor delivers it)
MIN_SIDE_PX = 32  # a side below this holds no correlation template with its search (2 x 12 + 1 + 2 x 3 px)
STATS_SIZE = 1024  # long side of the decimated read for the 8-bit stretch
WHOLE_MAX_PX = 2048 * 2048  # at most 16 MB per image (4-byte pixels) held in memory
_READ_LOCK = threading.Lock()  # one raster read at a time (module docstring)
DTYPES = ("uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64")


class RasterError(ValueError):
    """An unusable raster (the message names the file and what is wrong with it)."""


@dataclass
class Raster:
    """One image's raster opened for windowed reads (band 1)."""

    path: Path
    lines: int
    columns: int
    dtype: str
    rpcs: dict[str, str] | None
    _dataset: Any = field(repr=False)  # solver.raster_gate.GatedRaster
    stretch: tuple[float, float] = (0.0, 255.0)
    nodata: float | None = None
    _whole: np.ndarray | None = field(default=None, repr=False)  # raw band 1 of a small image (WHOLE_MAX_PX)

    @classmethod
    def open(cls, path: str | Path) -> "Raster":
        """Open ``path`` through the raster gate (:mod:`solver.raster_gate`: an allowed format, a
        plain file inside the current space, its ``_RPC.TXT`` or ``.RPB`` beside it) and compute
        its 8-bit stretch; raises :class:`RasterError` for a missing, refused, unreadable,
        truncated or absurd file."""
        from solver.raster_gate import RPC_SIDECARS, RasterLimits, RasterRefused, RasterSpace, current_space, open_raster

        path = Path(path)
        space = current_space()
        if space.limits.max_side_px > MAX_SIDE_PX:
            space = RasterSpace(space.folders, RasterLimits(MAX_SIDE_PX, space.limits.max_pixel_bytes, space.limits.max_block_bytes))
        try:
            gated = open_raster(path, space, sidecars=RPC_SIDECARS)
        except RasterRefused as exc:
            raise RasterError(exc.message if exc.message.startswith(str(path)) else f"{path}: {exc.message}") from None
        ds = gated.dataset
        dtype = gated.header.dtype
        if dtype not in DTYPES:
            gated.close()
            raise RasterError(f"{path}: pixel type {dtype} is not supported (8 to 32-bit integers or floats)")
        if min(ds.height, ds.width) < MIN_SIDE_PX:
            gated.close()
            raise RasterError(f"{path}: {ds.width} x {ds.height} pixels is too small to match (at least {MIN_SIDE_PX} x {MIN_SIDE_PX})")
        try:
            rpcs = ds.rpcs.to_gdal() if ds.rpcs is not None else None
        except (KeyError, ValueError):
            rpcs = None
        r = cls(path, ds.height, ds.width, dtype, rpcs, gated, nodata=ds.nodata)
        try:
            r.stretch = r._percentiles()
        except BaseException:
            gated.close()
            raise
        return r

    def close(self) -> None:
        self._whole = None
        self._dataset.close()  # the gated raster: its dataset, descriptors and private folder

    def _read(self, **kw) -> np.ndarray:
        from rasterio.errors import RasterioError

        try:
            with _READ_LOCK, warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return self._dataset.dataset.read(1, **kw)
        except (RasterioError, OSError, ValueError) as exc:
            raise RasterError(f"{self.path}: cannot read its pixels (truncated or corrupt file?): {exc}") from None

    def _percentiles(self) -> tuple[float, float]:
        k = max(1, int(np.ceil(max(self.lines, self.columns) / STATS_SIZE)))
        small = self._read(out_shape=(max(1, self.lines // k), max(1, self.columns // k))).astype(np.float64)
        valid = np.isfinite(small)
        if self.nodata is not None:
            valid &= small != self.nodata
        if not valid.any():
            raise RasterError(f"{self.path}: no valid pixel (all nodata)")
        lo, hi = np.percentile(small[valid], [0.5, 99.5])
        return float(lo), float(max(hi, lo + 1e-6))

    def window(self, row0: int, col0: int, rows: int, cols: int) -> np.ndarray:
        """Raw values (float32) of ``rows`` x ``cols`` pixels from (row0, col0), clipped to the
        image (the array is smaller where the window leaves it)."""
        from rasterio.windows import Window

        r0, c0 = max(int(row0), 0), max(int(col0), 0)
        r1, c1 = min(int(row0) + int(rows), self.lines), min(int(col0) + int(cols), self.columns)
        if r1 <= r0 or c1 <= c0:
            return np.zeros((0, 0), np.float32)
        if self.lines * self.columns <= WHOLE_MAX_PX:
            whole = self._whole
            if whole is None:
                whole = self._whole = self._read()  # (read twice at worst, by two threads at once: the same values)
            return whole[r0:r1, c0:c1].astype(np.float32)
        return self._read(window=Window(c0, r0, c1 - c0, r1 - r0)).astype(np.float32)

    def decimated(self, row0: int, col0: int, rows: int, cols: int, k: int) -> tuple[np.ndarray, int, int]:
        """Raw values (float32) of the window decimated by ``k`` (the mean of k x k blocks; GDAL
        reads an overview level when the file has a suitable one), with the window's origin
        moved down to a multiple of ``k`` so that every window of an image shares one decimated
        grid. Returns (values, row origin, column origin): the decimated pixel (i, j) is centred
        on full-resolution (origin + k i + (k - 1) / 2, origin + k j + (k - 1) / 2)."""
        from rasterio.enums import Resampling
        from rasterio.windows import Window

        if k == 1:
            r0, c0 = max(int(row0), 0), max(int(col0), 0)
            return self.window(row0, col0, rows, cols), r0, c0
        r0, c0 = max(int(row0), 0) // k * k, max(int(col0), 0) // k * k
        r1 = min(int(row0) + int(rows), self.lines) // k * k
        c1 = min(int(col0) + int(cols), self.columns) // k * k
        if r1 <= r0 or c1 <= c0:
            return np.zeros((0, 0), np.float32), r0, c0
        out = self._read(window=Window(c0, r0, c1 - c0, r1 - r0), out_shape=((r1 - r0) // k, (c1 - c0) // k), resampling=Resampling.average)
        return out.astype(np.float32), r0, c0

    def to_8bit(self, values: np.ndarray) -> np.ndarray:
        """``values`` stretched to 0..255 (uint8) with the image's percentiles."""
        lo, hi = self.stretch
        return np.clip((values - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)
