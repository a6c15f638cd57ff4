"""Monte Carlo of the datum analysis' sigmas (solver/quality/datum.py): do the tie points as a
whole sit where the predicted sigma of their datum directions says?

A simulated RPC-SHIFT triplet (PRISM-like, 2.5 m pixels, tie points only) whose delivered RPCs
each carry an independent line and column offset drawn from the bias prior the job states
(0 +- PRIOR_PX on a0, b0 of every image): the RPCs' bias priors are then the datum, and the
error of the tie points' common height (the mean of adjusted minus true heights) over many
draws must have the standard deviation the analysis predicts (sigma_shift_height, a-priori
scale). Likewise the common east and north shifts. Each draw also has new image noise.

    python bench/bench_datum.py --runs 40

Prints per direction the RMS of (error / predicted sigma) over the runs (1 expected; with n
runs its own 95% band is about 1 +- 1.96 / sqrt(2 n)).
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np

from solver.api import run
from solver.simulate import presets
from solver.simulate.rpc import RpcSettings
from solver.simulate.scene import SceneSettings

PRIOR_PX = 10.0


def one(seed: int) -> dict[str, float]:
    rng = np.random.default_rng(1000 + seed)
    scene = presets.prism_triplet(SceneSettings(preset="prism-triplet", seed=seed, rpc=RpcSettings("RPC-SHIFT", {})),
                                  gcps=0, checks=0, tie_points=60)
    job, truth = scene.job(), scene.truth()
    for im in job["images"]:
        a0, b0 = rng.normal(0.0, PRIOR_PX, 2)
        im["rpc"]["line_off"] += a0  # the delivered RPC is off by (a0, b0) pixels
        im["rpc"]["samp_off"] += b0
        im["bias_prior"] = {"a0": {"value": 0.0, "sigma": PRIOR_PX}, "b0": {"value": 0.0, "sigma": PRIOR_PX}}
    rep = run(copy.deepcopy(job))
    true = {p["id"]: p for p in truth["points"]}
    from solver.geometry.geodesy import LocalFrame

    frame = LocalFrame.at(np.array(rep["frames"]["lgs"]["origin_ecef_m"])) if "lgs" in rep["frames"] else None
    err = []
    for t in rep["tie_points"]:
        err.append(np.array(t["lgs_m"]) - frame.to_lgs(np.array(true[t["id"]]["ecef_m"])))
    mean = np.mean(err, axis=0)
    sig = {d["direction"]: d["sigma_m"] for d in rep["quality"]["datum"]["directions"]}
    return {"shift_east": mean[0] / sig["shift_east"], "shift_north": mean[1] / sig["shift_north"],
            "shift_height": mean[2] / sig["shift_height"], "sigma_height_m": sig["shift_height"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=40)
    args = ap.parse_args()
    t0 = time.perf_counter()
    rows = [one(s) for s in range(1, args.runs + 1)]
    for key in ("shift_east", "shift_north", "shift_height"):
        z = np.array([r[key] for r in rows])
        print(f"{key:13s} RMS(error / sigma) = {np.sqrt(np.mean(z**2)):.3f}  mean {np.mean(z):+.3f}  (n = {len(z)})")
    print(f"predicted sigma of the common height: {np.median([r['sigma_height_m'] for r in rows]):.2f} m (median); "
          f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
