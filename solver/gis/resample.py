"""The image resampled to an ideal single-array camera of the adjusted orientation
(``pba resample``), with the RPC of that ideal geometry; and the per-chip sub-images.

The ideal camera: one straight line of ``columns`` pixels of the camera's pixel size, centred
on the principal point, at the chips' mean along-track position ``dx`` (so line numbers stay
close to the raw image's), the nominal focal length, no interior-orientation corrections; the
same platform and adjusted orientation as the image. Chips merged, offsets removed: the level of
a processed product, which one RPC fits to the accuracy of a single-chip camera.

Resampling: ideal pixel (L, C) -> its ray -> the ground at the job's mean point height -> the raw
image by the rigorous model (chips, IOP) -> bilinear sample. The mapping is computed on a grid
every ``GRID_STEP`` pixels and interpolated bilinearly. The height used matters little: the chips
see a ground point within a few lines of each other (PRISM: 1.5-3 px), a parallax of ~1e-3 px
per 100 m of height error.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from solver.geometry.geodesy import ecef_to_geodetic
from solver.gis.model import AdjustedImage
from solver.kernels import project, ray

GRID_STEP = 32


class IdealImage(AdjustedImage):
    """An adjusted image seen by the ideal single-array camera (module docstring)."""

    @property
    def n_chips(self) -> int:
        return 1

    def chip_range(self, k: int) -> tuple[float, float]:
        return 0.0, float(self.columns - 1)

    def _chip_constants(self, k: int) -> tuple[float, float, float]:
        cam = self.image.camera
        dx = float(np.mean([c.dx_mm for c in cam.chips])) if cam.chips else 0.0
        return dx, 0.0, (self.columns - 1) / 2.0

    def _oc(self, line: float, column: float) -> np.ndarray:
        cam = self.image.camera
        dx, dy, centre = self._chip_constants(0)
        x0, y0 = cam.principal_point_mm
        return np.array([line, column, 1.0, cam.focal_mm, cam.pixel_mm, dx - x0, dy - y0, centre, self.image.tau_per_line])

    def project_chip(self, ecef, k, line_guess=None):
        lgs = self.model.problem.frame.to_lgs(np.atleast_2d(ecef))
        img = self.image
        coef = img.coef()
        n = len(lgs)
        line, col, ok = np.empty(n), np.empty(n), np.zeros(n, bool)
        for i in range(n):
            g = (self.lines - 1) / 2.0 if line_guess is None else float(line_guess[i])
            out = project(img.kind, coef, img.kc, lgs[i].copy(), self._oc(g, 0.0), False)
            ok[i], line[i], col[i] = bool(out[0]), float(out[1]), float(out[2])
        return line, col, ok

    def ground_to_image(self, ecef):
        line, col, ok = self.project_chip(np.atleast_2d(ecef), 0)
        return np.where(ok, line, np.nan), np.where(ok, col, np.nan), np.where(ok, 0, -1)

    def rays(self, line, column, chip=None):
        line = np.atleast_1d(np.asarray(line, float))
        column = np.atleast_1d(np.asarray(column, float))
        frame = self.model.problem.frame
        img = self.image
        coef = img.coef()
        s = np.empty((len(line), 3))
        d = np.empty((len(line), 3))
        for i in range(len(line)):
            si, di = ray(img.kind, coef, img.kc, self._oc(float(line[i]), float(column[i])))
            s[i] = frame.to_ecef(si)
            d[i] = frame.vector_to_ecef(di)
        return s, d


def ideal_image(image: AdjustedImage) -> IdealImage:
    return IdealImage(image.model, image.image)


def ideal_to_raw(image: AdjustedImage, ideal: IdealImage, line: np.ndarray, column: np.ndarray, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Raw image positions of ideal image positions (through the ground at ``height_m``)."""
    ground = ideal.image_to_ground(line, column, height_m)
    raw_line, raw_col, _ = image.ground_to_image(ground)
    return raw_line, raw_col


def mean_point_height(image: AdjustedImage) -> float:
    pts = [p.xyz for p in image.model.problem.points if np.all(np.isfinite(p.xyz))]
    if not pts:
        return 0.0
    return float(np.mean(ecef_to_geodetic(image.model.problem.frame.to_ecef(np.array(pts)))[:, 2]))


def _nodes(n: int) -> np.ndarray:
    a = np.arange(0, n, GRID_STEP, dtype=float)
    return a if a[-1] == n - 1 else np.append(a, n - 1)


def resample_raster(image: AdjustedImage, raster: Path, output: Path, progress: Callable[[float, str], None] | None = None) -> IdealImage:
    """Write the ideal single-array image of ``raster`` (same size); returns the ideal image."""
    from scipy.ndimage import map_coordinates

    from solver.gis.ortho import _interp
    from solver.raster_gate import create_raster, open_raster

    say = progress or (lambda f, m: None)
    ideal = ideal_image(image)
    h = mean_point_height(image)
    with open_raster(raster) as gated:
        data = gated.dataset.read(1)
    if data.shape != (image.lines, image.columns):
        raise ValueError(f"{raster}: {data.shape[0]} x {data.shape[1]} pixels, the image has {image.lines} x {image.columns}")
    rs, cs = _nodes(image.lines), _nodes(image.columns)
    rr, cc = np.meshgrid(rs, cs, indexing="ij")
    say(0.0, "mapping the ideal grid")
    rl, rc = ideal_to_raw(image, ideal, rr.ravel(), cc.ravel(), h)
    gl, gc = rl.reshape(rr.shape), rc.reshape(rr.shape)
    say(0.3, "resampling")
    out = np.zeros_like(data)
    cols = np.arange(image.columns, dtype=float)
    block = max(1, 2_000_000 // image.columns)
    for r0 in range(0, image.lines, block):
        rows = np.arange(r0, min(r0 + block, image.lines), dtype=float)
        ll, lc = _interp(gl, rs, cs, rows, cols), _interp(gc, rs, cs, rows, cols)
        bad = ~(np.isfinite(ll) & np.isfinite(lc)) | (ll < -0.5) | (ll > image.lines - 0.5) | (lc < -0.5) | (lc > image.columns - 0.5)
        vals = map_coordinates(data, [np.nan_to_num(ll), np.nan_to_num(lc)], order=1, mode="nearest")
        vals[bad] = 0
        out[r0 : r0 + len(rows)] = vals
        say(0.3 + 0.7 * min(r0 + block, image.lines) / image.lines, "resampling")
    with create_raster(output, driver="GTiff", width=image.columns, height=image.lines, count=1, dtype=data.dtype, nodata=0, compress="deflate", tiled=True) as dst:
        dst.write(out, 1)
    return ideal


def write_chip_rasters(image: AdjustedImage, raster: Path, output: Path) -> list[tuple[int, Path]]:
    """The per-chip sub-images of ``raster`` (columns of each chip inside the image):
    ``<output stem>_<chip id>.tif``."""
    from rasterio.windows import Window

    from solver.gis.rpc_export import _chip_path
    from solver.raster_gate import create_raster, open_raster

    written = []
    with open_raster(raster) as gated:
        src = gated.dataset
        for k in range(image.n_chips):
            lo, hi = (int(v) for v in image.chip_range(k))
            chip_id = image.image.camera.chips[k].id if image.image.camera.chips else "1"
            data = src.read(1, window=Window(lo, 0, hi - lo + 1, src.height))
            path = _chip_path(Path(output), chip_id)
            with create_raster(path, driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype=data.dtype) as dst:
                dst.write(data, 1)
            written.append((k, path))
    return written
