"""DEM blunders (points on roofs, trees, water): does data snooping remove the DEM heights that
are off, and only those, and do the adjusted heights of those points stay with the truth?

A simulated PRISM triplet (PASS-J2, ephemeris weighted 2 m / 0.01 m/s, measured attitude, no
control point, 40 tie points) per seed, and a DEM degraded from the scene's true terrain (1"
cells, 3 m noise correlated over 1.5 cells, no bias), stated as sigma 3 m. Then ``--blunders``
tie points (every eighth) get a DEM that is off: every cell whose centre lies within
``--radius`` metres of the point is raised (a tree canopy or a building in a DSM: the DEM above
the point) or lowered (a point on a roof against a DTM) by ``--size`` metres, the sign
alternating. A radius of 1.5 cells puts the point on a plateau (its four neighbouring cells and
their neighbours all off); a radius of 0.75 cells raises only the cells next to the point, so
that the DEM has steep flanks within a cell of the point (the case where the point could slide
horizontally off the blunder instead of its DEM height being rejected).

Per seed: which DEM heights data snooping (``options.blunder_detection: {}``, the defaults)
removed, and the blundered points' height errors over their predicted sigmas and horizontal
shifts from the truth.

    python bench/bench_dem_blunders.py --seeds 8 --size 25 --radius 45 --gcps 4
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
from solver.geometry.dem import grid_from_job, grid_to_job, metres_per_degree
from solver.importers.compose import SourceFile, dem_section
from solver.simulate.dem import write_dem_of_truth

NOISE_M = 3.0


def scene(seed: int, work: Path, gcps: int = 0) -> tuple[dict, dict]:
    """The simulated triplet's job (``gcps`` control points) with its degraded DEM, and the truth."""
    out = work / f"tri{seed}.json"
    assert pba(["simulate", "prism-triplet", "-o", str(out), "--seed", str(seed), "--model", "PASS-J2",
                "--weight-ephemeris", "2,0.01", "--gcps", str(gcps), "--checks", "10", "--tie-points", "40"]) == 0
    job = json.loads(out.read_text())
    truth = json.loads(out.with_name(f"tri{seed}.truth.json").read_text())
    dem = write_dem_of_truth(truth, work / "dem.tif", NOISE_M, 100 + seed)
    job["dem"] = dem_section(SourceFile(dem.name, b"", path=str(dem)), NOISE_M, None, None)
    return job, truth


def with_blunders(job: dict, truth: dict, offsets: dict[str, float], radius_m: float, loss: str = "huber") -> dict:
    """``job`` whose DEM is off by ``offsets[point]`` metres at every cell centre within
    ``radius_m`` of the true position of each point named (a geographic grid)."""
    dem = grid_from_job(job["dem"]["grid"])
    a, _b, c, _d, e, f = dem.transform
    rows, cols = dem.values.shape
    lon_c = c + a * (np.arange(cols) + 0.5)
    lat_c = f + e * (np.arange(rows) + 0.5)
    true = {p["id"]: p for p in truth["points"]}
    values = dem.values.copy()
    for pid, off in offsets.items():
        p = true[pid]
        m_lon, m_lat = metres_per_degree(np.array([p["lat_deg"]]))
        dx = (lon_c - p["lon_deg"]) * m_lon[0]
        dy = (lat_c - p["lat_deg"]) * m_lat[0]
        near = np.hypot(dx[None, :], dy[:, None]) <= radius_m
        values[near] += off
    dem.values = values
    out = dict(job)
    out["dem"] = {**job["dem"], "grid": grid_to_job(dem), "loss": loss}
    out["options"] = {**job.get("options", {}), "blunder_detection": {}}
    return out


def blunder_offsets(job: dict, n: int, size_m: float) -> dict[str, float]:
    """Every eighth tie point of ``job``, the DEM raised and lowered by ``size_m`` in turn."""
    ties = [p["id"] for p in job["points"] if p["role"] == "tie"]
    return {pid: size_m * (1 if k % 2 == 0 else -1) for k, pid in enumerate(ties[3::8][:n])}


def one(seed: int, work: Path, n: int, size_m: float, radius_m: float, gcps: int = 0, loss: str = "huber") -> dict:
    job, truth = scene(seed, work, gcps)
    offsets = blunder_offsets(job, n, size_m)
    rep = run(with_blunders(job, truth, offsets, radius_m, loss))
    removed = {r["point"] for r in rep["quality"]["rejected"] if r["kind"] == "dem_height" and r.get("removed", True)}
    removed |= {m["point"] for g in rep["quality"]["not_identifiable"] for m in g["members"]
                if m["kind"] == "dem_height" and m.get("removed", True)}
    true = {p["id"]: p for p in truth["points"]}
    z, moved = {}, {}
    for p in rep["tie_points"]:
        t = true[p["id"]]
        z[p["id"]] = (p["height_m"] - t["height_m"]) / p["sigma_m"][2]
        m_lon, m_lat = metres_per_degree(np.array([t["lat_deg"]]))
        moved[p["id"]] = np.array([(p["lon_deg"] - t["lon_deg"]) * m_lon[0], (p["lat_deg"] - t["lat_deg"]) * m_lat[0]])
    others = [k for k in z if k not in offsets]
    # horizontal error against the block's common one (without control the whole block can be
    # tens of metres off horizontally; what a blunder could do is move its point relative to it)
    common = np.median([moved[k] for k in others], axis=0)
    shift = {k: float(np.hypot(*(v - common))) for k, v in moved.items()}
    return {"offsets": offsets, "removed": removed, "z": z, "shift": shift, "others": others, "common_m": float(np.hypot(*common)),
            "sigma0": rep["adjustment"]["sigma0_aposteriori"], "other_removals": [r for r in rep["quality"]["rejected"] if r["kind"] != "dem_height"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--blunders", type=int, default=4)
    ap.add_argument("--size", type=float, default=25.0, help="metres the DEM is off at a blundered point")
    ap.add_argument("--radius", type=float, default=45.0, help="metres around the point the DEM is off")
    ap.add_argument("--gcps", type=int, default=0, help="control points of the simulated block")
    ap.add_argument("--dem-loss", default="huber", choices=("huber", "cauchy", "none"), help="the DEM heights' robust loss (dem.loss)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    found = planted = false = 0
    zb, zo = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            r = one(seed, Path(tmp), args.blunders, args.size, args.radius, args.gcps, args.dem_loss)
            hit = r["removed"] & set(r["offsets"])
            wrong = r["removed"] - set(r["offsets"])
            found, planted, false = found + len(hit), planted + len(r["offsets"]), false + len(wrong)
            zb += [r["z"][p] for p in r["offsets"]]
            zo += [r["z"][p] for p in r["others"]]
            detail = ", ".join(f"{p} {r['offsets'][p]:+.0f} m: {'removed' if p in hit else 'KEPT'} z {r['z'][p]:+.2f} "
                               f"shift {r['shift'][p]:.1f} m" for p in r["offsets"])
            others_shift = np.median([r["shift"][p] for p in r["others"]])
            print(f"seed {seed}: {detail}; other DEM heights removed: {sorted(wrong) or 'none'}; "
                  f"other removals {len(r['other_removals'])}; sigma0 {r['sigma0']:.3f}; block's common horizontal error "
                  f"{r['common_m']:.0f} m, other points' median shift {others_shift:.1f} m")
    zb_, zo_ = np.array(zb), np.array(zo)
    print(f"detected {found}/{planted}, false removals {false}; blundered points max |z| {np.max(np.abs(zb_)):.2f}, "
          f"RMS z {np.sqrt(np.mean(zb_**2)):.2f}; other points RMS z {np.sqrt(np.mean(zo_**2)):.2f}; "
          f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
