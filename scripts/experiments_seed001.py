#!/usr/bin/env python
"""Reproduce seed 001's experiments 1-4 on simulated PRISM triplets; regenerate docs/experiments.md.

Seed 001 (Rodrigues, Mitishita, Ferreira, Tommaselli 2017) adjusted two neighbouring PRISM
triplets of one pass with the UCL Kepler model, 40 tie points per triplet and weighted state
corrections, without and with self-calibration of the cameras' interior orientation (IOP):

1. triplet n.1 without IOP;                  2. triplet n.1 with IOP estimation;
3. triplet n.2 without IOP;                  4. triplet n.2 with the IOP of experiment 2.

Here one simulated pass (``solver/simulate``, independent orbit and attitude physics) images two
neighbouring areas with the backward, nadir and forward cameras; the cameras differ from the
nominal ones written in the job by known IOP errors (``--iop-errors default``: df 1.7-2.4 mm,
chip shifts a0/b0 of 0.02-0.03 mm on chips 1, 3, 4, a1/b1 of a few ppm; x0, y0, k1, k2, sy and
the bending are zero). Triplet 1 has 22 control, 20 check and 40 tie points, triplet 2 21 / 24
/ 40 (seed 001 section 6). Model K2; ephemeris (60 s, 1 m noise) interpolated to the first line,
positions weighted at 10 m, velocities free (docs/models.md section 9: the position-rotation
models' velocity is not the orbit's); control weighted with its 0.2 m survey sigma; 0.5 px.

Experiment 2 follows the paper (Figure 14): every IOP kind estimated (df, K1, K2, and per chip
a0, b0, a1, b1 and the bending delta, also of the master chip; a0, b0 weighted at 1.5 px, a1, b1
at 300 ppm, chip 2 the master), then the significance analysis drops, one at a time, the
parameter whose |estimate| is below its sigma (``self_calibration.significance_analysis``).
Two variants show what the rule lets through: 2b estimates only df, a0, b0; 2c applies the same
one-at-a-time analysis with the bending weighted (1e-3 rad) and a 3-sigma threshold. Experiment 4
reuses the cameras exported from 2 (``solver.observations.interior.camera_from_report``) as fixed values; 4b and 4c
reuse 2b's and 2c's; 4w reuses 2b's as weighted observations with their covariance.

Usage (from the repository root; a few minutes)::

    .venv/bin/python scripts/experiments_seed001.py              # rewrites the seed001 section
    .venv/bin/python scripts/experiments_seed001.py --replicates 2 --output /tmp/e.md
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from solver.api import run
from solver.observations.interior import camera_from_report
from solver.schema.job import load_job
from solver.simulate.camera import prism_camera
from solver.simulate.scene import Group, Scene, SceneSettings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from doc_sections import replace_section  # noqa: E402

BEGIN, END = "<!-- BEGIN seed001 -->", "<!-- END seed001 -->"
VIEWS = ("backward", "nadir", "forward")
TRIPLETS = ((22, 20, 40), (21, 24, 40))  # (control, check, tie) of triplets n.1 and n.2
NOISE_PX = 0.5
GCP_SIGMA_M = 0.2
EPHEMERIS = {"sigma_position_m": 10.0}
MODEL = "K2"
FULL = ["df", "k1", "k2", "a0", "b0", "a1", "b1", "delta", "delta@2"]  # delta@2: the master chip's bending
SIMPLE = ["df", "a0", "b0"]
STRICT_K = 3.0
STRICT_SIGMAS = {"delta": 1e-3}  # rad: a sagitta of 0.45 px at the ends of a PRISM chip
AXES = ("e", "n", "u")

# Seed 001 Tables 7 and 9: mean and RMSE of the check-point discrepancies (XL, YL, ZL), metres.
PAPER = {
    1: {"mean": (-0.0776, -0.0028, -3.3045), "rmse": (1.4808, 1.8279, 5.1204)},
    2: {"mean": (-0.2712, -0.4271, -1.5886), "rmse": (1.2376, 1.1683, 3.7642)},
    3: {"mean": (-0.2936, -1.5743, 1.9034), "rmse": (2.8500, 2.1704, 5.4814)},
    4: {"mean": (-0.3160, 0.5742, 0.2137), "rmse": (1.4102, 2.1995, 3.7334)},
}
LABELS = {
    "1": "1: triplet 1, no IOP",
    "2": "2: triplet 1, IOP (paper: all, significance |x| < sigma dropped)",
    "2b": "2b: triplet 1, IOP df, a0, b0",
    "2c": "2c: triplet 1, IOP (all, bending weighted 1e-3 rad, |x| < 3 sigma dropped)",
    "3": "3: triplet 2, no IOP",
    "4": "4: triplet 2, IOP of 2 fixed",
    "4b": "4b: triplet 2, IOP of 2b fixed",
    "4c": "4c: triplet 2, IOP of 2c fixed",
    "4w": "4w: triplet 2, IOP of 2b weighted (covariance)",
}


def simulate_pass(seed: int, iop_errors: Any = "default") -> Scene:
    """One pass over two neighbouring areas, each seen by the three cameras."""
    settings = SceneSettings(
        preset="seed001", seed=seed, noise_px=NOISE_PX, gcp_sigma_m=GCP_SIGMA_M, model=MODEL, iop_errors=iop_errors, name=f"seed001 seed {seed}"
    )
    groups = [Group([prism_camera(v) for v in VIEWS], g, c, t) for g, c, t in TRIPLETS]
    return Scene(settings, groups).simulate()


def triplet_job(scene_job: dict[str, Any], truth: dict[str, Any], k: int) -> dict[str, Any]:
    """The job of triplet ``k`` (0 or 1): its three images, points and observations."""
    job = copy.deepcopy(scene_job)
    group = {p["id"]: p["group"] for p in truth["points"]}
    images = [im for im in job["images"] if im["id"].endswith(f"-{k + 1:02d}")]
    ids = {im["id"] for im in images}
    job["images"] = images
    job["points"] = [p for p in job["points"] if group[p["id"]] == k]
    job["observations"] = [o for o in job["observations"] if o["image"] in ids]
    job["options"] = {"ephemeris": dict(EPHEMERIS)}
    job["name"] = f"{scene_job['name']} triplet {k + 1}"
    return job


def _timed_run(job: dict[str, Any]) -> tuple[dict[str, Any], float]:
    t0 = time.perf_counter()
    rep = run(load_job(job))
    return rep, time.perf_counter() - t0


def with_self_calibration(job: dict[str, Any], estimate: list[str], **extra: Any) -> dict[str, Any]:
    doc = copy.deepcopy(job)
    doc["options"]["self_calibration"] = {"estimate": list(estimate), **extra}
    return doc


def strict_analysis(job: dict[str, Any], k: float) -> tuple[dict[str, Any], dict[str, Any], list[str], float]:
    """The paper's one-at-a-time analysis with threshold ``k`` sigma (via ``exclude``) and the
    bending weighted; returns the last job, its report, the dropped names and the time."""
    exclude: list[str] = []
    t0 = time.perf_counter()
    while True:
        doc = with_self_calibration(job, FULL, exclude=list(exclude), sigmas=dict(STRICT_SIGMAS))
        rep = run(load_job(doc))
        weak = [
            (abs(p["value"]) / p["sigma"], f"{cam['id']}/{p['name']}")
            for cam in rep.get("cameras", [])
            for p in cam["parameters"]
            if p["estimated"] and p["sigma"] and abs(p["value"]) < k * p["sigma"]
        ]
        if not weak:
            return doc, rep, exclude, time.perf_counter() - t0
        exclude.append(min(weak)[1])


def reuse_cameras(job: dict[str, Any], calib_job: dict[str, Any], calib_report: dict[str, Any], weighted: bool) -> dict[str, Any]:
    """``job`` with its cameras replaced by those exported from a self-calibration."""
    doc = copy.deepcopy(job)
    cams = []
    for cam in doc["cameras"]:
        if not any(c["id"] == cam["id"] for c in calib_report.get("cameras", [])):
            cams.append(cam)
            continue
        exported = camera_from_report(calib_job, calib_report, cam["id"])
        exported["iop_use"] = "weighted" if weighted else "fixed"
        if not weighted:
            exported.pop("iop_covariance", None)
        cams.append(exported)
    doc["cameras"] = cams
    if weighted:  # the reused covariance is the only constraint on the re-estimated values
        doc["options"]["self_calibration"] = {"estimate": list(SIMPLE), "sigmas": {"a0": None, "b0": None}}
    return doc


def run_pass(seed: int) -> dict[str, Any]:
    """Experiments 1-4 (and variants) on one simulated pass."""
    scene = simulate_pass(seed)
    sjob, truth = scene.job(), scene.truth()
    t1, t2 = triplet_job(sjob, truth, 0), triplet_job(sjob, truth, 1)
    out: dict[str, Any] = {"truth_cameras": truth["cameras"], "reports": {}, "times": {}}
    r, out["times"]["1"] = _timed_run(t1)
    out["reports"]["1"] = r
    j2 = with_self_calibration(t1, FULL, significance_analysis=True)
    r, out["times"]["2"] = _timed_run(j2)
    out["reports"]["2"] = r
    r, out["times"]["2-all-once"] = _timed_run(with_self_calibration(t1, FULL))
    j2b = with_self_calibration(t1, SIMPLE)
    r, out["times"]["2b"] = _timed_run(j2b)
    out["reports"]["2b"] = r
    j2c, r, excl, out["times"]["2c"] = strict_analysis(t1, STRICT_K)
    out["reports"]["2c"] = r
    out["strict_dropped"] = excl
    r, out["times"]["3"] = _timed_run(t2)
    out["reports"]["3"] = r
    out["reports"]["4"], out["times"]["4"] = _timed_run(reuse_cameras(t2, j2, out["reports"]["2"], weighted=False))
    out["reports"]["4b"], out["times"]["4b"] = _timed_run(reuse_cameras(t2, j2b, out["reports"]["2b"], weighted=False))
    out["reports"]["4c"], out["times"]["4c"] = _timed_run(reuse_cameras(t2, j2c, out["reports"]["2c"], weighted=False))
    out["reports"]["4w"], out["times"]["4w"] = _timed_run(reuse_cameras(t2, j2b, out["reports"]["2b"], weighted=True))
    return out


# -- summaries -----------------------------------------------------------------------------------
def iop_vs_truth(report: dict[str, Any], truth_cameras: dict[str, Any]) -> list[dict[str, Any]]:
    rows = []
    for cam in report.get("cameras", []):
        tr = truth_cameras[cam["id"]]["iop"]
        for p in cam["parameters"]:
            if p["estimated"]:
                true = tr[p["name"]]
                z = abs(p["value"] - true) / p["sigma"] if p["sigma"] else float("nan")
                rows.append({"camera": cam["id"], "name": p["name"], "value": p["value"], "sigma": p["sigma"], "unit": p["unit"], "true": true, "z": z})
    return rows


def _zero_simulated(name: str, true: float) -> bool:
    """Parameters simulated as zero, or too small to matter (a1/b1 of a few ppm move an image
    point by under 0.01 px)."""
    return true == 0.0 or name.split("@")[0] in ("a1", "b1")


def summarise(passes: list[dict[str, Any]]) -> dict[str, Any]:
    keys = ["1", "2", "2b", "2c", "3", "4", "4b", "4c", "4w"]
    s: dict[str, Any] = {}
    for k in keys:
        reps = [p["reports"][k] for p in passes]
        rmse = np.array([[r["checkpoints"]["rmse_m"][a] for a in AXES] for r in reps])
        s[k] = {
            "rmse_mean": rmse.mean(axis=0),
            "rmse_sd": rmse.std(axis=0, ddof=1) if len(reps) > 1 else np.zeros(3),
            "sigma0": float(np.mean([r["adjustment"]["sigma0_aposteriori"] for r in reps])),
            "time": float(np.mean([p["times"][k] for p in passes])),
        }
        if k in ("2", "2b", "2c"):
            rows = [row for p in passes for row in iop_vs_truth(p["reports"][k], p["truth_cameras"])]
            real = [r for r in rows if not _zero_simulated(r["name"], r["true"])]
            spurious = [r for r in rows if _zero_simulated(r["name"], r["true"])]
            s[k] |= {
                "n_kept": len(rows) / len(passes),
                "within3": float(np.mean([r["z"] < 3 for r in rows])) if rows else float("nan"),
                "real_within3": float(np.mean([r["z"] < 3 for r in real])) if real else float("nan"),
                "n_spurious": len(spurious) / len(passes),
                "spurious_kinds": Counter(r["name"].split("@")[0] for r in spurious),
                "n_real": len(real) / len(passes),
            }
    s["2-all-once"] = {"time": float(np.mean([p["times"]["2-all-once"] for p in passes]))}
    s["steps"] = float(np.mean([len(p["reports"]["2"]["parameter_analysis"]["steps"]) for p in passes]))
    s["improved"] = {
        (a, b): float(np.mean([p["reports"][b]["checkpoints"]["rmse_m"]["u"] < p["reports"][a]["checkpoints"]["rmse_m"]["u"] for p in passes]))
        for a, b in (("1", "2"), ("1", "2b"), ("1", "2c"), ("3", "4"), ("3", "4b"), ("3", "4c"), ("3", "4w"))
    }
    return s


# -- tables --------------------------------------------------------------------------------------
def table_discrepancies(rep_by_exp: dict[str, dict[str, Any]], exps: list[str]) -> str:
    """Seed 001 Tables 7 / 9: mean and RMSE of the discrepancies, with Shapiro-Wilk."""
    lines = [
        "| experiment | mean XL | mean YL | mean ZL | RMSE XL | RMSE YL | RMSE ZL | Shapiro-Wilk p (XL, YL, ZL) | sigma0 | paper RMSE XL / YL / ZL |",
        "|---|---:|---:|---:|---:|---:|---:|---|---:|---:|",
    ]
    for k in exps:
        r = rep_by_exp[k]
        cp = r["checkpoints"]
        sw = cp["shapiro_wilk"]
        swt = ", ".join(f"{sw[a]['p_value']:.2f}" + ("" if sw[a]["passed"] else "*") for a in AXES)
        paper = PAPER.get(int(k)) if k.isdigit() else None
        pt = " / ".join(f"{x:.2f}" for x in paper["rmse"]) if paper else "-"
        lines.append(
            f"| {LABELS[k]} | {cp['mean_m']['e']:+.2f} | {cp['mean_m']['n']:+.2f} | {cp['mean_m']['u']:+.2f} "
            f"| {cp['rmse_m']['e']:.2f} | {cp['rmse_m']['n']:.2f} | {cp['rmse_m']['u']:.2f} | {swt} "
            f"| {r['adjustment']['sigma0_aposteriori']:.2f} | {pt} |"
        )
    return "\n".join(lines)


def table_iop(report: dict[str, Any], truth_cameras: dict[str, Any]) -> str:
    """Seed 001 Table 5: the IOP kept by the significance analysis, with the simulated truth."""
    lines = ["| camera | IOP | estimate | sigma | simulated | |estimate - simulated| / sigma |", "|---|---|---:|---:|---:|---:|"]
    for row in iop_vs_truth(report, truth_cameras):
        flag = "" if row["z"] < 3 else " **"
        lines.append(
            f"| {row['camera']} | {row['name']} ({row['unit']}) | {row['value']:.4g} | {row['sigma']:.2g} | {row['true']:.4g} | {row['z']:.1f}{flag} |"
        )
    return "\n".join(lines)


def table_correlations(report: dict[str, Any], kinds: tuple[str, ...], limit: int = 15) -> str:
    pairs = [p for p in report["correlations"]["pairs"] if p.get("kinds") in kinds]
    if not pairs:
        return f"(no pair above {report['correlations']['threshold']})"
    lines = ["| parameter | parameter | rho |", "|---|---|---:|"]
    for p in pairs[:limit]:
        lines.append(f"| {p['a']} | {p['b']} | {p['rho']:+.2f} |")
    if len(pairs) > limit:
        lines.append(f"| ... {len(pairs) - limit} more | | |")
    return "\n".join(lines)


def table_monte_carlo(s: dict[str, Any]) -> str:
    lines = [
        "| experiment | RMSE XL (m) | RMSE YL (m) | RMSE ZL (m) | sigma0 | IOP kept | of which simulated ~0 | IOP within 3 sigma of truth | time (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for k in ("1", "2", "2b", "2c", "3", "4", "4b", "4c", "4w"):
        v = s[k]
        rm = " | ".join(f"{m:.2f} ± {d:.2f}" for m, d in zip(v["rmse_mean"], v["rmse_sd"]))
        extra = "| - | - | -"
        if "n_kept" in v:
            extra = f"| {v['n_kept']:.1f} | {v['n_spurious']:.1f} | {100 * v['within3']:.0f}%"
        lines.append(f"| {LABELS[k]} | {rm} | {v['sigma0']:.2f} {extra} | {v['time']:.2f} |")
    return "\n".join(lines)


def discussion(s: dict[str, Any], n: int) -> str:
    e1, e2, e2b, e2c = (s[k]["rmse_mean"] for k in ("1", "2", "2b", "2c"))
    e3, e4, e4b, e4c, e4w = (s[k]["rmse_mean"] for k in ("3", "4", "4b", "4c", "4w"))
    sp = s["2"]["spurious_kinds"]
    kinds = ", ".join(f"{k} {v / n:.1f}" for k, v in sp.most_common())
    imp = s["improved"]
    return "\n".join(
        [
            (
                f"- **Self-calibration removes the camera errors.** Without IOP the nominal cameras leave "
                f"RMSE {e1[0]:.2f} / {e1[1]:.2f} / {e1[2]:.2f} m (XL / YL / ZL, triplet 1) and sigma0 "
                f"{s['1']['sigma0']:.1f}: the simulated df of ~2 mm and chip shifts of 4 px cannot be absorbed "
                f"by the platform model. Estimating df, a0 and b0 (2b) brings it to {e2b[0]:.2f} / {e2b[1]:.2f} / "
                f"{e2b[2]:.2f} m (ZL better in {100 * imp[('1', '2b')]:.0f}% of the {n} passes), "
                f"{100 * s['2b']['within3']:.0f}% of the estimates within 3 sigma of the simulated values. Its "
                f"sigma0 {s['2b']['sigma0']:.2f} (instead of ~1) comes mostly from the prior: seed 001's 1.5 px on "
                "a0 and b0 against simulated shifts of 3-4 px."
            ),
            (
                f"- **The paper's significance rule keeps too much.** Dropping a parameter only while "
                f"|estimate| < sigma (experiment 2, {s['steps']:.0f} adjustments on average) keeps "
                f"{s['2']['n_kept']:.1f} IOP per triplet, {s['2']['n_spurious']:.1f} of them simulated as zero or "
                f"negligible (per triplet: {kinds}); only {100 * s['2']['within3']:.0f}% of the kept estimates lie "
                "within 3 sigma of the truth, because the spurious ones are strongly correlated with each other "
                "and with the EOP (bending of chip 1 in the backward and forward cameras with rho near -1; the "
                "correlation tables below) and each passes the 1-sigma test alone. The heights pay: ZL "
                f"{e2[2]:.2f} m against {e2b[2]:.2f} m for 2b. The bending is the culprit: unweighted, a chip's "
                "delta is determined to about 0.01 rad (a sagitta of several pixels) and pairs of them trade "
                "with the heights. Weighting delta at 1e-3 rad and dropping parameters below 3 sigma (2c) keeps "
                f"{s['2c']['n_kept']:.1f} IOP ({s['2c']['n_spurious']:.1f} spurious, "
                f"{100 * s['2c']['within3']:.0f}% within 3 sigma), ZL {e2c[2]:.2f} m. The paper also kept the "
                "bending of the nadir master chip and found a0 of chips 1 and 4 correlated with kappa (its "
                "Tables 5, 8)."
            ),
            (
                f"- **Reuse on the second triplet.** Experiment 3 (no IOP) gives {e3[0]:.2f} / {e3[1]:.2f} / {e3[2]:.2f} m; "
                f"reusing experiment 2's cameras fixed (4) {e4[0]:.2f} / {e4[1]:.2f} / {e4[2]:.2f} m, 2b's fixed (4b) "
                f"{e4b[0]:.2f} / {e4b[1]:.2f} / {e4b[2]:.2f} m, 2c's fixed (4c) {e4c[0]:.2f} / {e4c[1]:.2f} / {e4c[2]:.2f} m, "
                f"2b's weighted by their covariance and re-estimated (4w) {e4w[0]:.2f} / {e4w[1]:.2f} / {e4w[2]:.2f} m: "
                "a calibration from one triplet helps the next, as in the paper (ZL better than experiment 3 in "
                f"{100 * imp[('3', '4')]:.0f}% / {100 * imp[('3', '4b')]:.0f}% / {100 * imp[('3', '4c')]:.0f}% / "
                f"{100 * imp[('3', '4w')]:.0f}% of the passes), the more so the fewer spurious parameters it carries."
            ),
            (
                "- **Magnitudes.** Only the pattern is comparable with the paper. Its data were real images "
                "with control from orthophotos and a DTM (errors under 1 m and 2.5 m for 90% of the points) and "
                "a nominal camera that already held a calibration; here the control has 0.2 m noise, the image "
                "measurements 0.5 px, and the nominal camera misses the whole simulated df and the 3-4 px chip "
                "shifts, so experiment 1 is worse and experiment 2b better than the paper's."
            ),
        ]
    )


def render(seed: int, head: dict[str, Any], s: dict[str, Any], n: int, elapsed_s: float) -> str:
    r2 = head["reports"]["2"]
    dropped = r2["parameter_analysis"]["dropped"]
    parts = [
        BEGIN,
        "## Seed 001: triplet bundle adjustment with self-calibration (experiments 1-4)",
        "",
        "Regenerated by `.venv/bin/python scripts/experiments_seed001.py` "
        f"(seed {seed}, {n} simulated passes, {elapsed_s:.0f} s). Do not edit by hand.",
        "",
        "**Setup.** One simulated ALOS-like pass (`solver/simulate`) images two neighbouring areas "
        "with the backward, nadir and forward PRISM-like cameras. The simulated cameras differ from "
        "the nominal ones written in the jobs by known IOP (`--iop-errors default`: df 2.0 / 2.4 / "
        "1.7 mm, chip shifts a0, b0 of 0.02-0.03 mm (3-4 px) on chips 1, 3, 4, a1, b1 of 2-4 ppm; "
        "x0, y0, k1, k2, sy and every bending delta zero; chip 2 the master). Triplet 1: 22 control, "
        "20 check, 40 tie points; triplet 2: 21 / 24 / 40, every point in all three images. K2 model; "
        "ephemeris every 60 s (1 m noise) interpolated to each first line, positions weighted at 10 m, "
        "velocities free (docs/models.md section 9); control weighted with its 0.2 m survey sigma; "
        "image noise 0.5 px. Check points by least-squares intersection of their three rays, "
        "discrepancies in the LGS (XL east, YL north, ZL up); Shapiro-Wilk at 5% (* = normality "
        "rejected). Experiment 2 as in the paper (Figure 14): all IOP kinds estimated with seed 001's "
        "weights (a0, b0 1.5 px; a1, b1 300 ppm), then the significance analysis. The paper's values "
        "(real images) are given for reference.",
        "",
        f"### Triplet 1: experiments 1 and 2 (cf. paper Table 7), pass seed {seed}",
        "",
        table_discrepancies(head["reports"], ["1", "2", "2b", "2c"]),
        "",
        f"### Experiment 2: significant IOP after the analysis (cf. paper Table 5), pass seed {seed}",
        "",
        f"{len(r2['parameter_analysis']['steps'])} adjustments; dropped in this order: "
        + (", ".join(f"`{d}`" for d in dropped) if dropped else "none")
        + ". Estimates more than 3 sigma from the simulated value are marked **.",
        "",
        table_iop(r2, head["truth_cameras"]),
        "",
        "Correlations above 0.75 between IOP (cf. paper Table 6):",
        "",
        table_correlations(r2, ("IOP-IOP",)),
        "",
        "Correlations above 0.75 between IOP and EOP (cf. paper Table 8):",
        "",
        table_correlations(r2, ("EOP-IOP", "IOP-EOP")),
        "",
        "For comparison, experiment 2b (df, a0, b0) on the same pass:",
        "",
        table_iop(head["reports"]["2b"], head["truth_cameras"]),
        "",
        f"### Triplet 2: experiments 3 and 4 (cf. paper Table 9), pass seed {seed}",
        "",
        table_discrepancies(head["reports"], ["3", "4", "4b", "4c", "4w"]),
        "",
        f"### Over {n} simulated passes",
        "",
        "Mean ± standard deviation of the check-point RMSE; 'IOP kept': estimated parameters in the "
        "final adjustment per triplet, 'simulated ~0': those whose simulated value is zero (or a1/b1 "
        "of a few ppm, under 0.01 px); time: one adjustment (2, 2c: the whole analysis; one adjustment "
        f"with every IOP takes {s['2-all-once']['time']:.2f} s).",
        "",
        table_monte_carlo(s),
        "",
        "### Discussion",
        "",
        discussion(s, n),
        END,
    ]
    return "\n".join(parts) + "\n"


def write_section(path: Path, section: str) -> None:
    """Replace this script's section of the file between its markers, keep everything else."""
    replace_section(path, BEGIN, END, section)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=2008, help="seed of the headline pass")
    ap.add_argument("--replicates", type=int, default=10, help="simulated passes (seeds seed .. seed+N-1)")
    ap.add_argument("--output", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "experiments.md")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    n = max(1, args.replicates)
    passes = [run_pass(seed) for seed in range(args.seed, args.seed + n)]
    s = summarise(passes)
    write_section(args.output, render(args.seed, passes[0], s, n, time.perf_counter() - t0))
    print(f"wrote {args.output} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
