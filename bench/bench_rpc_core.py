"""Issue 17 done-when numbers: RPC bias models on simulated prism-triplets (run by hand).

    .venv/bin/python bench/bench_rpc_core.py [--seeds 1,2,3]

For each seed: (1) every image an RPC image with the known bias of each model (a0 = 20,
b0 = -12 px, a_line = 1e-4, a_column = -3e-5, b_line = 2e-5, b_column = 5e-5 px/px as the model
allows), 4 control points (8 for RPC-AFFINE): normalised errors (estimate - truth) / sigma;
(2) RPC-DRIFT with 4 control points vs the rigorous model (K2) on the same scene and points;
(3) one rigorous + two RPC-DRIFT images vs the all-rigorous block, the preset's control.
Check-point RMSE in metres (planimetric, 3D).
"""

from __future__ import annotations

import argparse

import numpy as np

from solver import api
from solver.geometry.rpc import BIAS_MODELS
from solver.simulate import presets
from solver.simulate.rpc import RpcSettings
from solver.simulate.scene import SceneSettings

BIAS = {"a0": 20.0, "a_line": 1e-4, "a_column": -3e-5, "b0": -12.0, "b_line": 2e-5, "b_column": 5e-5}


def job(seed: int, model: str | None, images=None, **kw) -> dict:
    rpc = RpcSettings(model, {k: BIAS[k] for k in BIAS_MODELS[model]}, images) if model else None
    return presets.prism_triplet(SceneSettings(preset="prism-triplet", seed=seed, rpc=rpc), **kw).job()


def rmse(rep: dict) -> tuple[float, float]:
    r = rep["checkpoints"]["rmse_m"]
    return r["planimetric"], float(np.sqrt(r["e"] ** 2 + r["n"] ** 2 + r["u"] ** 2))


def points_of(doc: dict) -> list:
    return sorted((p["id"], p["role"], tuple(np.round(p.get("coordinates") or (0, 0, 0), 6))) for p in doc["points"])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="1,2,3")
    seeds = [int(s) for s in ap.parse_args().seeds.split(",")]
    z: dict[str, list[float]] = {m: [] for m in BIAS_MODELS}
    for seed in seeds:
        for model in BIAS_MODELS:
            rep = api.run(job(seed, model, gcps=8 if model == "RPC-AFFINE" else 4))
            for e in rep["images"]:
                z[model] += [(p["value"] - BIAS[p["name"]]) / p["sigma"] for p in e["parameters"]]
            print(f"seed {seed} {model}: check RMSE plan/3D {rmse(rep)[0]:.3f} / {rmse(rep)[1]:.3f} m", flush=True)
        drift_doc, rig_doc = job(seed, "RPC-DRIFT", gcps=4), job(seed, None, gcps=4)
        same = points_of(drift_doc) == points_of(rig_doc)
        d, r = rmse(api.run(drift_doc)), rmse(api.run(rig_doc))
        print(f"seed {seed} 4 gcp: RPC-DRIFT {d[0]:.3f} / {d[1]:.3f} m, K2 {r[0]:.3f} / {r[1]:.3f} m "
              f"(ratio {d[0] / r[0]:.3f} / {d[1] / r[1]:.3f}; same points {same})", flush=True)
        mixed_doc, rig_doc = job(seed, "RPC-DRIFT", images=[2, 3]), job(seed, None)
        same = points_of(mixed_doc) == points_of(rig_doc)
        m, r = rmse(api.run(mixed_doc)), rmse(api.run(rig_doc))
        print(f"seed {seed} mixed (K2 + 2 RPC-DRIFT) {m[0]:.3f} / {m[1]:.3f} m, all K2 {r[0]:.3f} / {r[1]:.3f} m "
              f"(ratio {m[0] / r[0]:.3f} / {m[1] / r[1]:.3f}; same points {same})", flush=True)
    for model, v in z.items():
        a = np.array(v)
        print(f"{model}: n {len(a)}, RMS z {np.sqrt(np.mean(a**2)):.2f}, max |z| {np.abs(a).max():.2f}, "
              f"share within 3 sigma {np.mean(np.abs(a) < 3):.3f}")


if __name__ == "__main__":
    main()
