#!/usr/bin/env python
"""Issue 7 experiment: per-image position-rotation models vs the orbit-attitude models on a
simulated PRISM triplet; regenerates the "orbit" section of docs/experiments.md.

The triplets come from the physical scene simulator (orbit integrated with J2-J4 in the
Earth-fixed frame, attitude in the orbital frame with yaw steering). For each control
configuration (all 22 control points, 6, 4; the 20 check points unchanged) every image is
adjusted with each model; reported: sigma0, 3D check-point RMSE (intersection), and how far
the estimated line-0 position and velocity are from the simulated orbit (mean over the three
images). Header states are used as initial values only (no weights), so the state estimates
show what each model makes of the images.

Usage (from the repository root, about a minute)::

    .venv/bin/python scripts/experiments_orbit_models.py [--seeds 1,2,3] [--output docs/experiments.md]
"""

from __future__ import annotations

import argparse
import copy
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from solver.adjust import adjust_job
from solver.errors import JobError
from solver.geodesy import LocalFrame
from solver.job import load_job

sys.path.insert(0, str(Path(__file__).resolve().parent))
from doc_sections import replace_section  # noqa: E402

MODELS = ["P2", "K2", "J2-2", "OA-K", "OA-J2"]
CONTROL = [None, 6, 4]
EPHEMERIS = {"sigma_position_m": 10.0, "sigma_velocity_m_s": 0.05}  # the simulated state vectors as observations
EPH_MODELS = ["K2", "OA-K"]
BEGIN, END = "<!-- BEGIN orbit -->", "<!-- END orbit -->"


def simulate(seed: int) -> tuple[dict, dict]:
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "job.json"
        subprocess.run([sys.executable, "-m", "solver.cli", "simulate", "prism-triplet", "--seed", str(seed), "-o", str(out)], check=True, capture_output=True)
        return json.loads(out.read_text()), json.loads((Path(d) / "job.truth.json").read_text())


def with_control(job: dict, n: int | None) -> dict:
    j = copy.deepcopy(job)
    if n is None:
        return j
    gcps = [p["id"] for p in j["points"] if p["role"] == "gcp"][:n]
    drop = {p["id"] for p in j["points"] if p["role"] == "gcp" and p["id"] not in gcps}
    j["points"] = [p for p in j["points"] if p["id"] not in drop]
    j["observations"] = [o for o in j["observations"] if o["point"] not in drop]
    return j


def with_ephemeris(job: dict) -> dict:
    """The images' simulated state vectors (1 m / 1 mm/s noise) interpolated to the first line
    become weighted observations of the state (10 m, 0.05 m/s) instead of mere initial values."""
    j = copy.deepcopy(job)
    for im in j["images"]:
        im.pop("approx_state", None)
    j.setdefault("options", {})["ephemeris"] = dict(EPHEMERIS)
    return j


def state_errors(rep: dict, truth: dict) -> tuple[float, float]:
    """Mean |position error| (m) and |velocity error| (m/s) at line 0 over the images."""
    frame = LocalFrame.at(np.array(rep["frames"]["lgs"]["origin_ecef_m"]))
    dp, dv = [], []
    timgs = {t["id"]: t for t in truth["images"]}
    for im in rep["images"]:
        t = timgs[im["id"]]
        p_true = np.array(t["samples"]["position_ecef_m"][0])
        v_true = np.array(t["samples"]["velocity_ecef_m_s"][0])
        par = {p["name"]: p["value"] for p in im["parameters"]}
        if im["frame"] == "ECEF":
            p = np.array([par["X0"], par["Y0"], par["Z0"]])
            v = np.array([par["ux"], par["uy"], par["uz"]])
        else:  # LGS polynomial: X1 in m/line
            p = frame.to_ecef(np.array([par["X0"], par["Y0"], par["Z0"]]))
            lt = 0.00037
            v = frame.vector_to_ecef(np.array([par["X1"], par["Y1"], par["Z1"]]) / lt)
        dp.append(np.linalg.norm(p - p_true))
        dv.append(np.linalg.norm(v - v_true))
    return float(np.mean(dp)), float(np.mean(dv))


def run(seeds: list[int]) -> str:
    rows = {}
    for seed in seeds:
        job, truth = simulate(seed)
        for n in CONTROL:
            base = with_control(job, n)
            for model in MODELS:
                j = copy.deepcopy(base)
                for im in j["images"]:
                    im["model"] = {"name": model, "options": {}}
                key = (n, model)
                try:
                    rep = adjust_job(load_job(j))
                except JobError as exc:
                    rows.setdefault(key, []).append({"error": str(exc)[:80]})
                    continue
                if model in EPH_MODELS:
                    je = with_ephemeris(j)
                    repe = adjust_job(load_job(je))
                    re_ = repe["checkpoints"]["rmse_m"]
                    dpe, dve = state_errors(repe, truth)
                    rows.setdefault((n, model + " + ephemeris"), []).append({
                        "sigma0": repe["adjustment"]["sigma0_aposteriori"],
                        "rmse3d": float(np.sqrt(re_["e"] ** 2 + re_["n"] ** 2 + re_["u"] ** 2)),
                        "plan": re_["planimetric"], "u": re_["u"], "dp": dpe, "dv": dve,
                        "iters": repe["adjustment"]["iterations"],
                    })
                r = rep["checkpoints"]["rmse_m"]
                dp, dv = state_errors(rep, truth)
                rows.setdefault(key, []).append({
                    "sigma0": rep["adjustment"]["sigma0_aposteriori"],
                    "rmse3d": float(np.sqrt(r["e"] ** 2 + r["n"] ** 2 + r["u"] ** 2)),
                    "plan": r["planimetric"], "u": r["u"], "dp": dp, "dv": dv,
                    "iters": rep["adjustment"]["iterations"],
                })
    lines = [
        BEGIN,
        "## Orbit models (issue 7): position-rotation vs orbit-attitude on a simulated triplet",
        "",
        f"Regenerated by `scripts/experiments_orbit_models.py` (seeds {', '.join(map(str, seeds))}; mean over seeds). "
        "Simulated PRISM triplet (physical simulator: J2-J4 orbit, attitude in the orbital frame), 20 check "
        "points by intersection, 40 tie points, 0.5 px; header states as initial values only. "
        "|dS0|, |dv|: distance of the estimated line-0 position / velocity from the simulated orbit, mean over the 3 images.",
        "",
        "| control | model | sigma0 | check RMSE 3D m | planimetric m | height m | |dS0| m | |dv| m/s | iterations |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for n in CONTROL:
        for model in MODELS + [m + " + ephemeris" for m in EPH_MODELS]:
            res = rows[(n, model)]
            ok = [r for r in res if "error" not in r]
            label = "22 (all)" if n is None else str(n)
            if not ok:
                lines.append(f"| {label} | {model} | {res[0]['error']} | | | | | | |")
                continue
            m = {k: float(np.mean([r[k] for r in ok])) for k in ok[0]}
            lines.append(
                f"| {label} | {model} | {m['sigma0']:.3f} | {m['rmse3d']:.2f} | {m['plan']:.2f} | {m['u']:.2f} | "
                f"{m['dp']:.0f} | {m['dv']:.2f} | {m['iters']:.0f} |"
            )
    lines += [
        "",
        "Reading: all models fit the images about equally (sigma0, check-point RMSE), but the velocity of the "
        "position-rotation models (P2, K2, J2-2) is ~800 m/s off the simulated orbit: their angles are constant "
        "in the Earth-fixed/LGS frame while the real attitude turns with the orbit (~0.36 deg per image), and "
        "the adjustment absorbs that rotation into the trajectory. The orbit-attitude models (attitude relative "
        "to the orbital frame computed from the platform's own state) keep the velocity within a few m/s with "
        "full control, and converge in fewer iterations. The line-0 position stays weakly determined by the "
        "images alone for every model (pitch and along-track position are nearly interchangeable; km-level "
        "sigmas), which the ephemeris as a weighted observation resolves; with 4 control points nothing is "
        "well determined. The pass-propagated model of issue 7 (one integrated state for all images of a pass) "
        "is not implemented yet. With the simulated ephemeris as weighted observations (10 m, 0.05 m/s: "
        "'+ ephemeris' rows), K2 fights the ephemeris (sigma0 in the hundreds, check points off by "
        "hundreds of metres) while OA-K stays consistent with it (sigma0 near 1, state within metres "
        "and a few cm/s of the simulated orbit): only a model whose attitude turns with the orbit can "
        "use the state vectors as observations, and with them 4 control points give ~3 m check-point "
        "RMSE instead of 12-15 m. OA-K + ephemeris ends at sigma0 1.3-1.4 (chi-square rejected): the "
        "simulated attitude drifts (1e-6 rad/s in roll and pitch, 1e-5 in yaw) beyond the model's "
        "constant roll and pitch; with `orders` {omega: 1, phi: 1} (linear roll and pitch) it fell to 1.08 on "
        "seed 1, with 1.19 m planimetric / 1.98 m height check-point RMSE.",
        END,
        "",
    ]
    return "\n".join(lines)


def write_section(path: Path, section: str) -> None:
    """Replace this script's section of the file between its markers, keep everything else."""
    replace_section(path, BEGIN, END, section)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--output", type=Path, default=Path("docs/experiments.md"))
    args = ap.parse_args()
    section = run([int(s) for s in args.seeds.split(",")])
    write_section(args.output, section)
    print(section)


if __name__ == "__main__":
    main()
