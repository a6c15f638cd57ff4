"""Orthorectification timing, rigorous model vs fitted RPC through GDAL's warper, for a full
PRISM-size image (16000 lines x 14496 columns, 4 butted chips, simulated nadir scene seed 5,
adjusted with OA-J2), constant height and a DEM; and how far apart the two results are (mean
absolute grey-level difference of a smooth test pattern, and the RPC's own check-grid error).
Run by hand:

    .venv/bin/python bench/bench_ortho.py [--gsd 2.5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import from_origin

sys.path[:0] = [str(Path(__file__).resolve().parents[1]), str(Path(__file__).resolve().parents[1] / "tests")]  # the solver package first (tests/solver is a folder of tests, not it), then tests/utils: the model-consistent scenes

from utils.gis_scenes import prism_butted  # noqa: E402

from solver.geometry.geodesy import ecef_to_geodetic  # noqa: E402
from solver.gis.ortho import orthorectify  # noqa: E402
from solver.gis.rpc_export import image_rpcs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--gsd", type=float, default=2.5)
    ap.add_argument("--crs", default="EPSG:32722")
    args = ap.parse_args()
    t = time.perf_counter()
    scene, job, report, model = prism_butted()
    img = model.image(scene.images[0].id)
    print(f"scene simulated and adjusted in {time.perf_counter() - t:.1f} s; image {img.lines} x {img.columns}")
    d = Path(tempfile.mkdtemp(prefix="pba-bench-ortho-"))
    ll, cc = np.mgrid[0 : img.lines, 0 : img.columns].astype(np.float32)
    data = (128 + 60 * np.sin(ll / 37.0) * np.cos(cc / 53.0)).astype(np.uint8)
    del ll, cc
    with rasterio.open(d / "raw.tif", "w", driver="GTiff", width=img.columns, height=img.lines, count=1, dtype="uint8") as dst:
        dst.write(data, 1)
    del data
    llh = ecef_to_geodetic(np.array([p.ecef_m for p in scene.points]))
    lon0, lat1, step = llh[:, 0].min() - 0.3, llh[:, 1].max() + 0.3, 0.001
    n = int(0.6 / step) + 1
    lo, la = np.meshgrid(lon0 + (np.arange(n) + 0.5) * step, lat1 - (np.arange(n) + 0.5) * step)
    h = scene.terrain.height(lo.ravel(), la.ravel()).reshape(lo.shape).astype("float32")
    with rasterio.open(d / "dem.tif", "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs="EPSG:4326", transform=from_origin(lon0, lat1, step, step)) as dst:
        dst.write(h, 1)
    for label, kw in (("height 450 m", {"height_m": 450.0}), ("DEM", {"dem": d / "dem.tif", "dem_vertical": "ellipsoid"})):
        dem_range = (float(h.min()), float(h.max())) if "dem" in kw else None
        t = time.perf_counter()
        rpc = image_rpcs(model, img, dem_range)[0]
        t_fit = time.perf_counter() - t
        out = {}
        for method in ("rigorous", "rpc"):
            t = time.perf_counter()
            info = orthorectify(img, d / "raw.tif", d / f"o-{method}.tif", args.crs, args.gsd, method=method, rpc=rpc, **kw)
            dt = time.perf_counter() - t
            out[method] = d / f"o-{method}.tif"
            print(f"{label:<14} {method:<9} {dt:7.1f} s  ({info['width']} x {info['height']} px of {args.gsd} m)" + (f"  + RPC fit {t_fit:.1f} s" if method == "rpc" else ""))
        with rasterio.open(out["rigorous"]) as a, rasterio.open(out["rpc"]) as b:
            x, y = a.read(1).astype(np.float32), b.read(1).astype(np.float32)
        both = (x > 0) & (y > 0)
        print(f"{label:<14} rigorous vs rpc: mean |difference| {np.mean(np.abs(x[both] - y[both])):.2f} grey levels over {both.mean() * 100:.0f} % of the pixels; "
              f"whole-image RPC check grid RMS {rpc.fit['check_residuals']['rms_px']:.2f} px (max {rpc.fit['check_residuals']['max_px']:.2f})")


if __name__ == "__main__":
    main()
