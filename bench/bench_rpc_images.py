"""Simulated RPC images (issue 17): the delivered RPC's fit to the true geometry and the refined
RPC through GDAL, per preset and bias model. For each scene (``pba simulate`` presets, seed 7,
a known bias), with the report's bias set to the true one, the refined RPC read by GDAL
(rasterio's RPC transformer, corner convention corrected) is compared with the simulator's exact
projection at 500 random image positions x heights (the truth: ``true observed = RPC + bias``),
and with the adjusted model (the delivered RPC + the bias) itself. Run by hand:

    .venv/bin/python bench/bench_rpc_images.py
"""

from __future__ import annotations

import time

import numpy as np

from solver.geometry.geodesy import ecef_to_geodetic
from solver.gis.rpc_image import RpcImage, refined_rpc
from solver.gis.rpc_io import gdal_ground_to_image, gdal_rpc
from solver.simulate import presets
from solver.simulate.rpc import RpcSettings
from solver.simulate.scene import SceneSettings

BIASES = {
    "RPC-SHIFT": {"a0": 20.0, "b0": -12.0},
    "RPC-DRIFT": {"a0": 20.0, "a_line": 1e-4, "b0": -12.0, "b_line": -2e-5},
    "RPC-AFFINE": {"a0": 20.0, "a_line": 1e-4, "a_column": -3e-5, "b0": -12.0, "b_line": -2e-5, "b_column": 5e-5},
}
SCENES = {
    "prism-single nadir (4 chips)": lambda s: presets.prism_single(s, "nadir", 8, 2),
    "prism-single forward (butted)": lambda s: presets.prism_single(s, "forward", 8, 2, "butted"),
    "cbers-scene (1 chip)": lambda s: presets.cbers_scene(s, 8, 2),
}


def main() -> None:
    for label, make in SCENES.items():
        for model, bias in BIASES.items():
            t0 = time.perf_counter()
            scene = make(SceneSettings(preset="bench", seed=7, rpc=RpcSettings(model, bias)))
            t_sim = time.perf_counter() - t0
            (k, rpc), = scene.rpcs.items()
            im = scene.images[k]
            image = RpcImage(im.id, rpc, scene.settings.rpc.rpc_bias, model)
            hr = (scene.settings.terrain_min_m - 100.0, scene.settings.terrain_max_m + 100.0)
            t0 = time.perf_counter()
            refined = refined_rpc(image, hr)
            t_ref = time.perf_counter() - t0
            rng = np.random.default_rng(1)
            line, col = rng.uniform(0, im.camera.lines - 1, 500), rng.uniform(0, im.camera.columns - 1, 500)
            ground = im.image_to_ground(line, col, height_m=rng.uniform(*hr, 500))
            exact = im.ground_to_image(ground)
            llh = ecef_to_geodetic(ground)
            r, c = gdal_ground_to_image(gdal_rpc(refined), llh[:, 0], llh[:, 1], llh[:, 2])
            truth = np.hypot(r - 0.5 - exact.line, c - 0.5 - exact.column)
            ml, mc, _ = image.ground_to_image(ground)
            adj = np.hypot(r - 0.5 - ml, c - 0.5 - mc)
            chk = rpc.fit["check_residuals"]
            print(
                f"{label:<30} {model:<10} delivered check RMS {chk['rms_px']:.1e} max {chk['max_px']:.1e} | refined ({refined.fit['method']}) "
                f"GDAL vs adjusted RMS {np.sqrt(np.mean(adj**2)):.1e} max {adj.max():.1e}, vs truth RMS {np.sqrt(np.mean(truth**2)):.1e} "
                f"max {truth.max():.1e} | simulate {t_sim:.1f} s, refine {t_ref:.2f} s"
            )


if __name__ == "__main__":
    main()
