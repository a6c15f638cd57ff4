"""Orthorectification of an image's raster with its adjusted orientation (``pba ortho``).

Output: a GeoTIFF in the chosen CRS with square pixels of ``gsd`` (CRS units), north up,
covering the image's footprint; bilinear resampling; 0 is no-data. Heights: a constant
ellipsoidal height or a DEM (:class:`solver.gis.dem.Dem`: its vertical datum from the file or
the caller, its heights converted to ellipsoidal ones).

Two methods, measured against each other (bench/bench_ortho.py):

- ``rigorous``: the adjusted rigorous model maps the output pixel centres to the image on a grid
  of nodes every ``GRID_STEP`` output pixels, at two heights spanning the DEM (or the one
  height); every pixel's image position is interpolated bilinearly between the nodes and
  linearly in its own height (the DEM resampled bilinearly onto the output grid by GDAL; the
  mapping is smooth: the interpolation error is far below a pixel); the raster is then sampled
  bilinearly, pixel centres at integer positions as in our convention
  (:func:`solver.gis.ortho_kernel.sample_block`).
- ``rpc``: the RPC fitted to the adjusted model (:mod:`solver.gis.rpc_fit`) and GDAL's warper
  (rasterio's ``reproject`` with ``rpcs``, ``RPC_HEIGHT`` or ``RPC_DEM``), the same as
  ``gdalwarp -rpc -to RPC_DEM=dem.tif -t_srs EPSG:.... -tr G G -r bilinear``.

``rigorous`` is the default of ``pba ortho``: exact for every image (a raw multi-chip image's
whole-image RPC is off by the chip jumps, ~0.9 px RMS on PRISM), faster than GDAL's warper with
a DEM and 1.8x slower at a constant height on a PRISM-size image (bench/bench_ortho.py).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np
from affine import Affine

from solver.geometry.geodesy import ecef_to_geodetic, geodetic_to_ecef, transformer
from solver.gis.model import AdjustedImage
from solver.gis.rpc_image import RpcImage

if TYPE_CHECKING:
    from solver.gis.dem import Dem

GRID_STEP = 32
Progress = Callable[[float, str], None]


def _bounds(image: AdjustedImage, crs: str, heights: tuple[float, float], gsd: float):
    to_crs = transformer("EPSG:4326", crs)
    t = np.linspace(0.0, 1.0, 16)
    L, C = image.lines - 1.0, image.columns - 1.0
    line = np.concatenate([0 * t, t * L, L + 0 * t, t * L])
    col = np.concatenate([t * C, C + 0 * t, t * C, 0 * t])
    xs, ys = [], []
    for h in heights:
        llh = ecef_to_geodetic(image.image_to_ground(line, col, h))
        x, y = to_crs.transform(llh[:, 0], llh[:, 1])
        xs.append(x)
        ys.append(y)
    x, y = np.concatenate(xs), np.concatenate(ys)
    ok = np.isfinite(x) & np.isfinite(y)
    x0, x1 = np.floor(x[ok].min() / gsd) * gsd, np.ceil(x[ok].max() / gsd) * gsd
    y0, y1 = np.floor(y[ok].min() / gsd) * gsd, np.ceil(y[ok].max() / gsd) * gsd
    return x0, y1, int(round((x1 - x0) / gsd)), int(round((y1 - y0) / gsd))


def _nodes(n: int) -> np.ndarray:
    a = np.arange(0, n, GRID_STEP, dtype=float)
    return a if a[-1] == n - 1 else np.append(a, n - 1)


def _interp(grid: np.ndarray, rs: np.ndarray, cs: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(rs, rows, side="right") - 1, 0, max(len(rs) - 2, 0))
    j = np.clip(np.searchsorted(cs, cols, side="right") - 1, 0, max(len(cs) - 2, 0))
    i1, j1 = np.minimum(i + 1, len(rs) - 1), np.minimum(j + 1, len(cs) - 1)
    fr = ((rows - rs[i]) / np.where(rs[i1] > rs[i], rs[i1] - rs[i], 1.0))[:, None]
    fc = ((cols - cs[j]) / np.where(cs[j1] > cs[j], cs[j1] - cs[j], 1.0))[None, :]
    return (grid[np.ix_(i, j)] * (1 - fr) * (1 - fc) + grid[np.ix_(i, j1)] * (1 - fr) * fc + grid[np.ix_(i1, j)] * fr * (1 - fc) + grid[np.ix_(i1, j1)] * fr * fc)


@contextmanager
def _ellipsoidal_dem(path: Path | None, dem: "Dem | None") -> Iterator[Path | None]:
    """The DEM file GDAL's RPC transformer is to read: ``path`` itself when its heights are
    ellipsoidal, else a temporary GeoTIFF of its heights converted to ellipsoidal ones (its
    horizontal CRS only), removed afterwards."""
    if path is None or dem is None or dem.vertical.ellipsoidal:
        yield path
        return
    import tempfile

    from solver.geometry.dem import ellipsoidal_grid
    from solver.raster_gate import create_raster

    grid = dem.grid
    values = ellipsoidal_grid(grid).astype(np.float32)
    a, b, c, d, e, f = grid.transform
    with tempfile.TemporaryDirectory(prefix="pba-dem-") as tmp:
        out = Path(tmp) / "dem_ellipsoidal.tif"
        with create_raster(out, driver="GTiff", width=values.shape[1], height=values.shape[0], count=1, dtype="float32",
                           crs=grid.crs.to_wkt(), transform=Affine(a, b, c, d, e, f), nodata=np.nan) as dst:
            dst.write(values, 1)
        yield out


def orthorectify(
    image: AdjustedImage,
    raster: Path,
    output: Path,
    crs: str,
    gsd: float,
    height_m: float | None = None,
    dem: Path | None = None,
    method: str = "rigorous",
    progress: Progress | None = None,
    rpc=None,
    dem_vertical: str | None = None,
) -> dict:
    """Write the orthoimage; returns its size, transform origin and the method used.
    ``dem_vertical``: the DEM's vertical datum where its file does not state it
    (:class:`solver.gis.dem.Dem`; its heights are converted to ellipsoidal ones)."""
    import rasterio
    from rasterio.transform import from_origin

    from solver.gis.dem import Dem
    from solver.raster_gate import LOCAL, create_raster, open_raster

    if (height_m is None) == (dem is None):
        raise ValueError("give exactly one of --height and --dem")
    dem_obj = Dem(dem, dem_vertical) if dem is not None else None
    heights = dem_obj.range_m if dem_obj is not None else (height_m, height_m)
    say = progress or (lambda f, m: None)
    with open_raster(raster) as gated:
        data = gated.dataset.read(1)
        dtype = data.dtype
    if isinstance(image, RpcImage):  # no camera: the raster gives the image's size
        image = image.with_size(*data.shape)
    x0, y1, nx, ny = _bounds(image, crs, heights, gsd)
    transform = from_origin(x0, y1, gsd, gsd)
    if data.shape != (image.lines, image.columns):
        raise ValueError(f"{raster}: {data.shape[0]} x {data.shape[1]} pixels, the image has {image.lines} x {image.columns}")
    out = np.zeros((ny, nx), dtype=dtype)
    say(0.0, f"{nx} x {ny} pixels ({method})")
    if method == "rpc":
        from rasterio.warp import Resampling, reproject

        from solver.gis.rpc_io import gdal_rpc

        with _ellipsoidal_dem(dem, dem_obj) as dem_path, open_raster(dem_path, None if dem_path == dem else LOCAL) if dem_path is not None else nullcontext() as gated_dem:
            # GDAL's transformer opens RPC_DEM itself: it is given the gate's private name of the
            # DEM the gate opened (the same file, checked), never the caller's path; the heights
            # are ellipsoidal already (GDAL's own vertical shift would need its own geoid grid;
            # a converted copy is our own temporary file, opened in the local space)
            opts = ({"RPC_DEM": gated_dem.gdal_name, "RPC_DEM_APPLY_VDATUM_SHIFT": "FALSE"} if gated_dem is not None
                    else {"RPC_HEIGHT": float(height_m)})
            reproject(data, out, rpcs=gdal_rpc(rpc), src_crs="EPSG:4326", dst_transform=transform, dst_crs=crs, resampling=Resampling.bilinear, src_nodata=None, dst_nodata=0, **opts)
        say(1.0, "done")
    elif method == "rigorous":
        from solver.gis.ortho_kernel import sample_block

        to_geo = transformer(crs, "EPSG:4326")
        rs, cs = _nodes(ny), _nodes(nx)
        rr, cc = np.meshgrid(rs, cs, indexing="ij")
        lon, lat = to_geo.transform(x0 + (cc.ravel() + 0.5) * gsd, y1 - (rr.ravel() + 0.5) * gsd)
        grids = []
        for h in sorted({heights[0], heights[1]}):
            line, col, _ = image.ground_to_image(geodetic_to_ecef(np.column_stack([lon, lat, np.full(len(lon), h)])))
            grids.append((line.reshape(rr.shape), col.reshape(rr.shape)))
        grids.append(grids[-1])
        say(0.2, "grid projected")
        dem_heights = None
        if dem_obj is not None:
            from rasterio.warp import Resampling, reproject

            dem_heights = np.full((ny, nx), np.nan, dtype=np.float64)
            with open_raster(dem) as gated_dem:
                reproject(rasterio.band(gated_dem.dataset, 1), dem_heights, dst_transform=transform, dst_crs=crs, resampling=Resampling.bilinear, dst_nodata=np.nan)
            if not dem_obj.vertical.ellipsoidal:  # the DEM's own heights to ellipsoidal ones: + N, smooth over the nodes
                n_nodes = dem_obj.undulation_grid(np.asarray(lon), np.asarray(lat)).reshape(rr.shape)
                dem_heights += _interp(n_nodes, rs, cs, np.arange(ny, dtype=float), np.arange(nx, dtype=float))
            say(0.3, "DEM on the output grid")
        empty = np.zeros((1, 1))
        block = max(1, 4_000_000 // max(nx, 1))
        for r0 in range(0, ny, block):
            r1 = min(r0 + block, ny)
            hb = dem_heights[r0:r1] if dem_heights is not None else empty
            sample_block(data, grids[0][0], grids[0][1], grids[1][0], grids[1][1], GRID_STEP, ny, nx, r0, hb, float(heights[0]), float(heights[1]), 0.5 if np.issubdtype(dtype, np.integer) else 0.0, out[r0:r1])
            say(0.3 + 0.7 * r1 / ny, "resampling")
    else:
        raise ValueError(f"unknown method {method!r} (rigorous or rpc)")
    with create_raster(output, driver="GTiff", width=nx, height=ny, count=1, dtype=dtype, crs=crs, transform=transform, nodata=0, compress="deflate", tiled=True) as dst:
        dst.write(out, 1)
    return {"width": nx, "height": ny, "origin": [x0, y1], "gsd": gsd, "crs": crs, "method": method}
