"""Monte Carlo of DEM heights as observations (solver/observations/dem_heights.py): do the
adjusted tie heights follow the truth within their predicted sigmas?

A simulated PRISM triplet (PASS-J2, ephemeris weighted 2 m / 0.01 m/s, measured attitude, no
control point, 40 tie points) per seed, and a DEM degraded from the scene's true terrain (1"
cells, 3 m noise correlated over 1.5 cells, no bias), stated as sigma 3 m. Per seed: the tie
points' height errors over their predicted sigmas (the report's a-posteriori sigmas); over all
seeds their RMS (1 expected; 0.8-1.25 the aim) and the variance factor.

    python bench/bench_dem.py --seeds 8
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from solver.api import run
from solver.cli import main as pba
from solver.importers.compose import SourceFile, dem_section
from solver.simulate.dem import write_dem_of_truth

NOISE_M = 3.0


def one(seed: int, work: Path) -> tuple[np.ndarray, float]:
    out = work / f"tri{seed}.json"
    assert pba(["simulate", "prism-triplet", "-o", str(out), "--seed", str(seed), "--model", "PASS-J2",
                "--weight-ephemeris", "2,0.01", "--gcps", "0", "--checks", "10", "--tie-points", "40"]) == 0
    job = json.loads(out.read_text())
    truth = json.loads(out.with_name(f"tri{seed}.truth.json").read_text())
    dem = write_dem_of_truth(truth, work / "dem.tif", NOISE_M, 100 + seed)
    job["dem"] = dem_section(SourceFile(dem.name, b"", path=str(dem)), NOISE_M, None, None)
    rep = run(job)
    true = {p["id"]: p for p in truth["points"]}
    z = np.array([(p["height_m"] - true[p["id"]]["height_m"]) / p["sigma_m"][2] for p in rep["tie_points"]])
    return z, rep["adjustment"]["sigma0_aposteriori"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()
    t0 = time.perf_counter()
    zs, s0 = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, args.seeds + 1):
            z, sigma0 = one(seed, Path(tmp))
            zs.append(z)
            s0.append(sigma0)
            print(f"seed {seed}: RMS(height error / sigma) {np.sqrt(np.mean(z**2)):.3f}, mean {np.mean(z):+.3f}, sigma0 {sigma0:.3f}")
    allz = np.concatenate(zs)
    print(f"all {len(allz)} tie heights over {args.seeds} seeds: RMS(error / sigma) = {np.sqrt(np.mean(allz**2)):.3f}; "
          f"median sigma0 {np.median(s0):.3f}; {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
