"""RPC fit residuals per model kind (fit grid and independent check grid, RMS and max, px), and
through GDAL (rasterio's RPC transformer, corner convention corrected), on the GIS test scenes
(tests/utils/gis_scenes.py: 2400 x 2400 single-chip camera, nadir and 20 deg tilted, seed 5) and a
PRISM-like 4-chip butted nadir image (whole-image RPC and per-chip RPCs). Run by hand:

    .venv/bin/python bench/bench_rpc_fit.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1]), str(Path(__file__).resolve().parents[1] / "tests")]  # the solver package first (tests/solver is a folder of tests, not it), then tests/utils: the model-consistent scenes

from utils.gis_scenes import MODEL_KINDS, VIEWS, prism_butted, single_chip  # noqa: E402

from solver.geometry.geodesy import ecef_to_geodetic  # noqa: E402
from solver.gis.rpc_export import height_range  # noqa: E402
from solver.gis.rpc_fit import fit_image_rpc  # noqa: E402
from solver.gis.rpc_io import gdal_ground_to_image, gdal_rpc  # noqa: E402


def gdal_check(img, rpc, chip=None, offset=0.0, n=15):
    lo, hi = img.chip_range(chip) if chip is not None else (0.0, img.columns - 1.0)
    ll, cc = np.meshgrid(np.linspace(0, img.lines - 1, n), np.linspace(lo, hi, n), indexing="ij")
    hs = np.linspace(*rpc.fit["height_range_m"], 4)
    line, col = np.tile(ll.ravel(), len(hs)), np.tile(cc.ravel(), len(hs))
    llh = ecef_to_geodetic(img.image_to_ground(line, col, np.repeat(hs, n * n), chip=chip))
    r, c = gdal_ground_to_image(gdal_rpc(rpc), llh[:, 0], llh[:, 1], llh[:, 2])
    err = np.hypot(r - 0.5 - line, c - 0.5 + offset - col)
    return float(np.sqrt(np.mean(err**2))), float(err.max())


def row(label, rpc, gd):
    f, c = rpc.fit["fit_residuals"], rpc.fit["check_residuals"]
    print(f"{label:<34} fit RMS {f['rms_px']:.2e} max {f['max_px']:.2e} | check RMS {c['rms_px']:.2e} max {c['max_px']:.2e} | GDAL RMS {gd[0]:.2e} max {gd[1]:.2e}")


def main() -> None:
    for kind, name in MODEL_KINDS.items():
        for view, pitch in VIEWS.items():
            _s, _j, _r, model = single_chip(name, pitch)
            img = model.image("cam")
            t = time.perf_counter()
            rpc = fit_image_rpc(img, height_range(model))
            dt = time.perf_counter() - t
            row(f"{kind} ({name}) {view} [{dt:.1f} s]", rpc, gdal_check(img, rpc))
    scene, _j, _r, model = prism_butted()
    img = model.image(scene.images[0].id)
    hr = height_range(model)
    rpc = fit_image_rpc(img, hr)
    row("PRISM 4-chip whole image", rpc, gdal_check(img, rpc))
    for k in range(img.n_chips):
        rpc = fit_image_rpc(img, hr, chip=k)
        row(f"PRISM chip {k + 1}", rpc, gdal_check(img, rpc, chip=k))


if __name__ == "__main__":
    main()
