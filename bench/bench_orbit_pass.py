"""Pass-propagated vs per-image models on a simulated strip (one pass, N consecutive triplets).

Run by hand (never in CI)::

    .venv/bin/python bench/bench_orbit_pass.py [--triplets 20] [--tie-points 30000] [--models P2,OA-J2,PASS-J2,...]

Variants: P2, OA-J2, PASS-J2 (attitude per camera, roll, pitch, yaw linear: the defaults),
PASS-J2/image (attitude per image), PASS-J2/quadratic (per camera, quadratic over the pass). The strip comes
from the physical simulator (`pba simulate strip`: J2-J4 orbit, attitude in the
orbital frame with drift). Each model is adjusted three times: header states as initial values
only, with the simulated ephemeris weighted (10 m, 0.05 m/s), and with the simulated attitude
samples weighted as well (0.002 deg; orbit-attitude and pass models only). Prints iterations, solve and total
time (adjust_job, covariance and report included), sigma0, 3D check-point RMSE and the mean
distance of the line-0 state from the simulated orbit.
"""

from __future__ import annotations

import argparse
import copy
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from solver.adjust import adjust_job
from solver.schema.job import load_job

EPHEMERIS = {"sigma_position_m": 10.0, "sigma_velocity_m_s": 0.05}
ATTITUDE = {"sigma_deg": [0.002, 0.002, 0.002]}  # the simulated 1-Hz attitude samples (0.002 deg noise)
WEIGHTS = ("initial only", "ephemeris", "ephemeris + attitude")
QUADRATIC = {"omega": 2, "phi": 2, "kappa": 2}
# label -> (model, options)
VARIANTS = {
    "P2": ("P2", {}),
    "OA-J2": ("OA-J2", {}),
    "PASS-J2": ("PASS-J2", {}),  # attitude per camera, roll/pitch/yaw linear (the defaults)
    "PASS-J2/image": ("PASS-J2", {"attitude": "image"}),
    "PASS-J2/quadratic": ("PASS-J2", {"orders": QUADRATIC}),  # per camera, quadratic over the pass
}


def simulate(triplets: int, tie_points: int, seed: int) -> tuple[dict, dict]:
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "strip.json"
        cmd = [sys.executable, "-m", "solver.cli", "simulate", "strip", "--triplets", str(triplets),
               "--tie-points", str(tie_points), "--seed", str(seed), "-o", str(out)]
        subprocess.run(cmd, check=True, capture_output=True)
        return json.loads(out.read_text()), json.loads((Path(d) / "strip.truth.json").read_text())


def state_errors(rep: dict, truth: dict) -> tuple[float, float]:
    timgs = {t["id"]: t for t in truth["images"]}
    dp, dv = [], []
    for im in rep["images"]:
        t = timgs[im["id"]]["samples"]
        dp.append(np.linalg.norm(np.array(im["state_line0"]["position_ecef_m"]) - t["position_ecef_m"][0]))
        dv.append(np.linalg.norm(np.array(im["state_line0"]["velocity_ecef_m_s"]) - t["velocity_ecef_m_s"][0]))
    return float(np.mean(dp)), float(np.mean(dv))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--triplets", type=int, default=20)
    ap.add_argument("--tie-points", type=int, default=30000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--models", default=",".join(VARIANTS), help="labels of VARIANTS")
    args = ap.parse_args()
    t = time.perf_counter()
    job, truth = simulate(args.triplets, args.tie_points, args.seed)
    print(f"simulated {len(job['images'])} images, {len(job['observations'])} observations in {time.perf_counter() - t:.1f} s")
    print("model | weighted | iterations | solve s | total s | sigma0 | check RMSE 3D m | |dS0| m | |dv| m/s")
    for label in args.models.split(","):
        model, options = VARIANTS[label]
        for weights in WEIGHTS:
            eph = weights != "initial only"
            if weights.endswith("attitude") and model == "P2":
                continue  # Earth-fixed angles: measured attitude does not apply
            j = copy.deepcopy(job)
            for im in j["images"]:
                im["model"] = {"name": model, "options": copy.deepcopy(options)}
                if eph:
                    im.pop("approx_state", None)
            if eph:
                j.setdefault("options", {})["ephemeris"] = dict(EPHEMERIS)
            if weights.endswith("attitude"):
                j["options"]["attitude"] = dict(ATTITUDE)
            t0 = time.perf_counter()
            rep = adjust_job(load_job(j))
            total = time.perf_counter() - t0
            a = rep["adjustment"]
            r = rep["checkpoints"]["rmse_m"]
            rm = float(np.sqrt(r["e"] ** 2 + r["n"] ** 2 + r["u"] ** 2))
            dp, dv = state_errors(rep, truth)
            print(f"{label} | {weights} | {a['iterations']} | {a['solve_time_s']:.2f} | "
                  f"{total:.2f} | {a['sigma0_aposteriori']:.3f} | {rm:.2f} | {dp:.0f} | {dv:.2f}", flush=True)


if __name__ == "__main__":
    main()
