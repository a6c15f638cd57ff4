#!/usr/bin/env python
"""Issue 7 experiment: per-image position-rotation models vs the orbit-attitude models vs the
pass-propagated models on a simulated PRISM triplet; regenerates the "orbit" section of
docs/experiments.md.

The triplets come from the physical scene simulator (orbit integrated with J2-J4 in the
Earth-fixed frame, attitude in the orbital frame with yaw steering). For each control
configuration (all 22 control points, 6, 4; the 20 check points unchanged) every image is
adjusted with each model; reported: sigma0, 3D check-point RMSE (intersection), and how far
the estimated line-0 position and velocity are from the simulated orbit (mean over the three
images). Header states are used as initial values only (no weights), so the state estimates
show what each model makes of the images; the "+ ephemeris" variants instead weight the
simulated state vectors (interpolated to each image's first line) as observations, and the
"+ attitude" variants also the simulated attitude samples; those two are also run without any
control point (direct georeferencing, control 0).

Usage (from the repository root, a few minutes)::

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
from solver.schema.job import load_job

sys.path.insert(0, str(Path(__file__).resolve().parent))
from doc_sections import replace_section  # noqa: E402

CONTROL = [None, 6, 4, 0]  # 0: direct georeferencing (ephemeris + attitude samples only)
LINEAR_RP = {"orders": {"omega": 1, "phi": 1}}  # roll and pitch linear in time (PASS default)
CONSTANT_RP = {"orders": {"omega": 0, "phi": 0}}  # roll and pitch constant (OA default)
# (label, model, model options, simulated ephemeris / attitude samples as weighted observations)
VARIANTS = [
    ("P2", "P2", {}, False, False),
    ("K2", "K2", {}, False, False),
    ("J2-2", "J2-2", {}, False, False),
    ("OA-K", "OA-K", {}, False, False),
    ("OA-J2", "OA-J2", {}, False, False),
    ("PASS-K", "PASS-K", {}, False, False),
    ("PASS-J2", "PASS-J2", {}, False, False),
    ("PASS-J2, constant roll/pitch", "PASS-J2", CONSTANT_RP, False, False),
    ("K2 + ephemeris", "K2", {}, True, False),
    ("OA-K + ephemeris", "OA-K", {}, True, False),
    ("OA-J2 + ephemeris", "OA-J2", {}, True, False),
    ("OA-J2, linear roll/pitch + ephemeris", "OA-J2", LINEAR_RP, True, False),
    ("PASS-J2, constant roll/pitch + ephemeris", "PASS-J2", CONSTANT_RP, True, False),
    ("PASS-J2 + ephemeris", "PASS-J2", {}, True, False),
    ("OA-J2, linear roll/pitch + ephemeris + attitude", "OA-J2", LINEAR_RP, True, True),
    ("PASS-J2 + ephemeris + attitude", "PASS-J2", {}, True, True),
]
EPHEMERIS = {"sigma_position_m": 10.0, "sigma_velocity_m_s": 0.05}  # the simulated state vectors as observations
ATTITUDE = {"sigma_deg": [0.002, 0.002, 0.002]}  # the simulated attitude samples (1 Hz, 0.002 deg noise)
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
    """Mean |position error| (m) and |velocity error| (m/s) at line 0 over the images (the
    report's ``state_line0``: every model's adjusted perspective-centre state, ECEF)."""
    dp, dv = [], []
    timgs = {t["id"]: t for t in truth["images"]}
    for im in rep["images"]:
        t = timgs[im["id"]]
        p_true = np.array(t["samples"]["position_ecef_m"][0])
        v_true = np.array(t["samples"]["velocity_ecef_m_s"][0])
        p = np.array(im["state_line0"]["position_ecef_m"])
        v = np.array(im["state_line0"]["velocity_ecef_m_s"])
        dp.append(np.linalg.norm(p - p_true))
        dv.append(np.linalg.norm(v - v_true))
    return float(np.mean(dp)), float(np.mean(dv))


def run(seeds: list[int]) -> str:
    rows: dict[tuple, list[dict]] = {}
    for seed in seeds:
        job, truth = simulate(seed)
        for n in CONTROL:
            base = with_control(job, n)
            for label, model, options, eph, att in VARIANTS:
                if n == 0 and not att:
                    continue  # no datum without control, or ephemeris and attitude
                j = copy.deepcopy(base)
                for im in j["images"]:
                    im["model"] = {"name": model, "options": copy.deepcopy(options)}
                if eph:
                    j = with_ephemeris(j)
                if att:
                    j.setdefault("options", {})["attitude"] = dict(ATTITUDE)
                key = (n, label)
                try:
                    rep = adjust_job(load_job(j))
                except JobError as exc:
                    rows.setdefault(key, []).append({"error": str(exc)[:80]})
                    continue
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
        "## Orbit models: position-rotation vs orbit-attitude vs pass-propagated on a simulated triplet",
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
        for model, *_, att in VARIANTS:
            if n == 0 and not att:
                continue
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
        "Reading. All models fit the images about equally with full control (sigma0, check-point RMSE), but "
        "the velocity of the position-rotation models (P2, K2, J2-2) is ~800 m/s off the simulated orbit: "
        "their angles are constant in the Earth-fixed/LGS frame while the real attitude turns with the orbit "
        "(~0.36 deg per image), and the adjustment absorbs that rotation into the trajectory. The orbit-attitude "
        "models (attitude relative to the orbital frame of the platform's own state) keep the velocity within "
        "6-12 m/s and converge in fewer iterations. The pass-propagated models (one integrated state for the "
        "whole triplet, PASS-K two-body, PASS-J2 with J2; attitude per camera, roll/pitch/yaw linear by default) "
        "keep it within 6-14 m/s, or ~2 m/s with constant roll and pitch: without an ephemeris a linear pitch "
        "drift and the along-track velocity are nearly interchangeable over 100 s, and the reported sigmas say "
        "so. The line-0 position stays weakly determined by the images alone (pitch vs along-track position): "
        "kilometres for every model. With 4 control points the per-image models lose the geometry (12-15 m "
        "check RMSE for K2/OA, hundreds of metres for P2) while the pass models, whose three images share one "
        "orbit, keep 4-4.5 m without any ephemeris. With the simulated ephemeris as weighted observations "
        "(10 m, 0.05 m/s: '+ ephemeris' rows) K2 fights it (sigma0 in the hundreds, check points ~1.2 km off): "
        "only a model whose attitude turns with the orbit can use the state vectors as observations. OA and "
        "PASS agree with it; with constant roll and pitch (the OA default) they end at sigma0 1.3-1.4 because the "
        "simulated attitude drifts (1e-6 rad/s in roll and pitch, 1e-5 in yaw, 1e-8 rad/s^2), with linear roll "
        "and pitch (the PASS default) at sigma0 ~1 with 2.2 m 3D check RMSE even from 4 control points; the pass "
        "model then has the state closest to the simulated orbit (~3 m, 0.01 m/s or better) in the fewest iterations. "
        "PASS-K and PASS-J2 differ by less than the noise over this 100-s arc (J2's effect is absorbed by the "
        "state); over a 15-min strip see docs/models.md section 12. With the simulated attitude samples as well "
        "(1 Hz, 0.002 deg noise, weighted with 0.002 deg: '+ attitude' rows) sigma0 stays at ~1, so the measured "
        "attitude agrees with both orbit-attitude and pass models, and the check points improve a little with "
        "control (4 control points: 2.1 instead of 2.2 m). Without any control point (control 0) the job is a "
        "direct georeferencing from the ephemeris and the attitude alone: ~27 m 3D (13 m planimetric, 22 m "
        "height), as expected from 0.002 deg (3.5e-5 rad, ~25 m at the ~700 km slant range) per sample and six "
        "samples per image; the simulation has no attitude-sensor misalignment, which real data would add.",
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
