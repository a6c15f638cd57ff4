#!/usr/bin/env python
"""Reproduce seed 002's experiments on a simulated CBERS scene; regenerate docs/experiments.md.

Seed 002 (Medeiros & Tommaselli 2009) oriented one CBERS CCD scene with a polynomial platform
model (12 parameters: X, Y, Z, kappa quadratic; 8 parameters: linear; omega, phi held) from road
segments (equivalent planes model, with a pushbroom correction), from road-crossing points
(collinearity), and from both together, with 50 lines + 23 points, 30 lines + 15 points in a
good and in a poor distribution, and 10 lines + 15 points; accuracy from 8 check points.

Here the scene comes from the simulator (``solver/simulate/lines.py``: independent orbit with
J2-J4, attitude drift, no yaw steering, terrain; road segments projected exactly, each image
point at its own line time). Every configuration is adjusted with

* points only (collinearity of the control points),
* lines only: equivalent planes without correction, corrected once from the initial orientation
  (the paper's procedure), corrected and refreshed until it settles (iterated), and the
  rigorous model,
* points and lines together (equivalent planes iterated, rigorous).

Accuracy is measured at the 8 check points as the paper did (their image coordinates measured
with 0.5 px noise, E/N RMSE in GSD) and, to see past that measurement floor, at the same points
with error-free image coordinates ("orientation error", planimetric RMSE in metres). A Monte
Carlo over ``--replicates`` scenes separates systematic differences from the luck of one draw.

Usage (from the repository root; about a minute per 5 replicates)::

    .venv/bin/python scripts/experiments_seed002.py                 # rewrites the seed002 section
    .venv/bin/python scripts/experiments_seed002.py --replicates 2 --output /tmp/e.md
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from solver.api import run
from solver.errors import JobError
from solver.geometry.geodesy import from_ecef
from solver.simulate.lines import GRID, LineScene, LineSet, PointSet, cbers_settings
from solver.simulate.scene import SceneSettings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from doc_sections import replace_section  # noqa: E402

BEGIN, END = "<!-- BEGIN seed002 -->", "<!-- END seed002 -->"
NOISE_PX = 0.5  # control and check points: visual pointing
LINE_NOISE_PX = 0.3  # road edges: sub-pixel line extraction
GCP_SIGMA_M = 0.5  # GPS survey of points and road vertices
# poor distributions (region = line_lo, line_hi, column_lo, column_hi as fractions of the image)
POOR_LINES = (0.0, 0.55, 0.0, 1.0)  # roads in the upper 55 % only (paper: none in the lower part)
LOWER = (0.6, 1.0, 0.0, 1.0)  # points B: lower 40 %, where the poor roads are not
UPPER_LEFT = (0.0, 0.55, 0.0, 0.5)  # points C: upper left, where the poor roads are too


def scene_sets() -> tuple[list[PointSet], list[LineSet]]:
    """Check points on a grid (K, seed 002 Figure 6), well-spread control points (G), two poor
    point sets (B: lower 40 %, C: upper-left quarter), 50 well-spread roads (L, the first 30 and
    10 of them are the smaller good sets), and 30 poorly distributed roads (R: upper 55 % of the
    scene, mostly along two directions, several aligned). Poor roads and B points together cover
    the scene (the paper's experiment 6, test 1); poor roads and C points do not (test 2)."""
    points = [
        PointSet("K", "check", 8, GRID),
        PointSet("G", "gcp", 23),
        PointSet("B", "gcp", 15, LOWER),
        PointSet("C", "gcp", 15, UPPER_LEFT),
    ]
    lines = [
        LineSet("L", 50),
        LineSet("R", 30, POOR_LINES, directions_deg=(25.0, 115.0), spread_deg=8.0),
    ]
    return points, lines


def simulate(seed: int, yaw_steering: bool = False) -> LineScene:
    settings = cbers_settings(
        SceneSettings(preset="seed002", seed=seed, noise_px=NOISE_PX, gcp_sigma_m=GCP_SIGMA_M, name=f"seed002 seed {seed}", model="MT8")
    )
    points, lines = scene_sets()
    return LineScene(settings, points, lines, yaw_steering=yaw_steering, line_noise_px=LINE_NOISE_PX).simulate()


def base_job(scene: LineScene) -> dict[str, Any]:
    """The scene's job plus error-free twins of the check points (``T01``...): same ground
    point, true coordinates, noise-free image coordinates; they measure the orientation error."""
    job = scene.job()
    truth = from_ecef(np.array([p.ecef_m for p in scene.points]), scene.settings.crs)
    exact = {scene.points[o.point].id: o for o in scene.observations}
    image = job["images"][0]["id"]
    for i, p in enumerate(scene.points):
        if p.role != "check":
            continue
        tid = "T" + p.id[1:]
        job["points"].append({"id": tid, "role": "check", "coordinates": [float(x) for x in truth[i]]})
        o = exact[p.id]
        job["observations"].append({"image": image, "point": tid, "line": o.line, "column": o.column, "sigma_px": NOISE_PX})
    return job


class Config(NamedTuple):
    key: str
    model: str
    lines: str  # e.g. "L50", "L30", "R30", "L10", "" (none)
    points: str  # e.g. "G23", "G15", "B15", "C15"
    label: str


CONFIGS = [
    Config("A", "ON2", "L50", "G23", "50 lines + 23 points"),
    Config("B", "MT8", "L50", "G23", "50 lines + 23 points"),
    Config("C", "MT8", "L30", "G15", "30 lines + 15 points, both well distributed"),
    Config("D", "MT8", "R30", "B15", "30 lines + 15 points, both poorly distributed"),
    Config("E", "MT8", "L30", "B15", "30 good lines + 15 poorly distributed points"),
    Config("F", "MT8", "R30", "C15", "30 poor lines + 15 poor points (other distribution)"),
    Config("G", "MT8", "L10", "G15", "10 good lines + 15 good points"),
    Config("H", "MT8", "L10", "B15", "10 good lines + 15 poorly distributed points"),
]
# seed 002 Table 4: experiment -> configurations (tests)
EXPERIMENTS = [
    ("1", "ON2 (12 parameters)", ["A"], "separately"),
    ("2", "MT8 (8 parameters)", ["B"], "separately"),
    ("3", "MT8", ["C"], "separately"),
    ("4", "MT8", ["D"], "separately"),
    ("5", "MT8", ["C", "E"], "together"),
    ("6", "MT8", ["D", "F"], "together"),
    ("7", "MT8", ["G", "H"], "together"),
]
VARIANTS = [
    ("points", "points only", False, True, "rigorous", "iterated"),
    ("ep0", "lines: planes, no correction", True, False, "equivalent_planes", "none"),
    ("ep1", "lines: planes, corrected once", True, False, "equivalent_planes", "initial"),
    ("epi", "lines: planes, iterated", True, False, "equivalent_planes", "iterated"),
    ("rig", "lines: rigorous", True, False, "rigorous", "iterated"),
    ("c-epi", "both: planes, iterated", True, True, "equivalent_planes", "iterated"),
    ("c-rig", "both: rigorous", True, True, "rigorous", "iterated"),
]


def _ids(spec: str) -> set[str]:
    if not spec:
        return set()
    prefix, n = spec[0], int(spec[1:])
    return {f"{prefix}{k:02d}" for k in range(1, n + 1)}


def configure(job: dict[str, Any], cfg: Config, use_lines: bool, use_points: bool, line_model: str, correction: str, model: str | None = None) -> dict[str, Any]:
    """The job of one configuration and variant: chosen lines and control points, all checks."""
    j = copy.deepcopy(job)
    lines = _ids(cfg.lines) if use_lines else set()
    gcps = _ids(cfg.points) if use_points else set()
    j["lines"] = [gl for gl in j["lines"] if gl["id"] in lines]
    j["points"] = [p for p in j["points"] if p["role"] == "check" or p["id"] in gcps]
    keep = {p["id"] for p in j["points"]}
    j["observations"] = [o for o in j["observations"] if o["point"] in keep]
    for im in j["images"]:
        im["model"] = {"name": model or cfg.model}
    j["options"] = {"control": "weighted", "covariance": True, "line_model": line_model, "line_correction": correction}
    j["name"] = f"{job['name']} {cfg.key} {cfg.model}"
    return j


def measure(report: dict[str, Any]) -> dict[str, Any]:
    """Check-point RMSE as measured (K points, E/N in GSD) and the orientation error (T points)."""
    cp = report["checkpoints"]
    gsd = cp["gsd_m"]
    d = {"K": [], "T": []}
    for p in cp["points"]:
        d[p["id"][0]].append((p["discrepancy_m"]["e"], p["discrepancy_m"]["n"]))
    k = np.array(d["K"])
    t = np.array(d["T"])
    a = report["adjustment"]
    return {
        "e_gsd": float(np.sqrt(np.mean(k[:, 0] ** 2)) / gsd),
        "n_gsd": float(np.sqrt(np.mean(k[:, 1] ** 2)) / gsd),
        "orient_m": float(np.sqrt(np.mean(np.sum(t**2, axis=1)))),
        "sigma0": a["sigma0_aposteriori"],
        "chi2": bool(a["chi2"]["passed"]) if a["chi2"] else None,
        "settled": not any("did not settle" in w for w in report["warnings"]),
        "gsd_m": gsd,
    }


def run_scene(scene: LineScene, configs: list[Config] = CONFIGS, variants=VARIANTS, model: str | None = None) -> dict[tuple[str, str], dict]:
    """Every configuration and variant on one scene: {(config key, variant key): measures}."""
    job = base_job(scene)
    out = {}
    for cfg in configs:
        for key, _label, use_lines, use_points, lm, corr in variants:
            try:
                rep = run(configure(job, cfg, use_lines, use_points, lm, corr, model))
                out[cfg.key, key] = measure(rep)
            except JobError as exc:
                out[cfg.key, key] = {"error": exc.code}
    return out


def _cell(m: dict | None, what: str) -> str:
    if m is None:
        return "-"
    if "error" in m:
        return m["error"]
    flag = "" if m["settled"] else "†"
    if what == "gsd":
        return f"{m['e_gsd']:.2f} / {m['n_gsd']:.2f}{flag}"
    return f"{m['orient_m']:.1f}{flag}"


def table_single(res: dict, configs: list[str]) -> str:
    head = "| configuration | model | " + " | ".join(lbl for _k, lbl, *_ in VARIANTS) + " |"
    lines = [head, "|---|---|" + "---:|" * len(VARIANTS)]
    for c in configs:
        cfg = next(x for x in CONFIGS if x.key == c)
        for what, name in (("gsd", "check E / N (GSD)"), ("orient", "orientation error (m)")):
            cells = [_cell(res.get((c, k)), what) for k, *_ in VARIANTS]
            lines.append(f"| {c}: {cfg.label}, {name} | {cfg.model} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def monte_carlo(seeds: list[int], yaw: bool = False, configs: list[Config] = CONFIGS, variants=VARIANTS) -> dict:
    """Orientation error (m) per (model, config, variant) over the seeds: mean, sd, failures."""
    acc: dict[tuple[str, str, str], list[float]] = {}
    unsettled: dict[tuple[str, str, str], int] = {}
    chi2: dict[tuple[str, str, str], list[bool]] = {}
    for seed in seeds:
        scene = simulate(seed, yaw)
        for model in ("ON2", "MT8"):
            res = run_scene(scene, configs, variants, model)
            for (c, v), m in res.items():
                key = (model, c, v)
                if "error" in m:
                    acc.setdefault(key, []).append(math.nan)
                    continue
                acc.setdefault(key, []).append(m["orient_m"])
                unsettled[key] = unsettled.get(key, 0) + (0 if m["settled"] else 1)
                chi2.setdefault(key, []).append(bool(m["chi2"]))
    return {
        k: {
            "mean": float(np.nanmean(v)) if np.any(np.isfinite(v)) else math.nan,
            "sd": float(np.nanstd(v, ddof=1)) if np.sum(np.isfinite(v)) > 1 else 0.0,
            "median": float(np.nanmedian(v)) if np.any(np.isfinite(v)) else math.nan,
            "n": len(v),
            "errors": int(np.sum(~np.isfinite(v))),
            "unsettled": unsettled.get(k, 0),
            "chi2_pass": float(np.mean(chi2[k])) if chi2.get(k) else math.nan,
        }
        for k, v in acc.items()
    }


MC_CONFIGS = [c for c in CONFIGS if c.key != "B"]  # B is A with MT8: the Monte Carlo runs both models


def table_monte_carlo(mc: dict, configs: list[Config] = MC_CONFIGS) -> str:
    lines = ["| configuration | model | " + " | ".join(lbl for _k, lbl, *_ in VARIANTS) + " |", "|---|---|" + "---:|" * len(VARIANTS)]
    for cfg in configs:
        for model in ("ON2", "MT8"):
            cells = []
            for k, *_ in VARIANTS:
                s = mc.get((model, cfg.key, k))
                if s is None:
                    cells.append("-")
                    continue
                txt = f"{s['mean']:.1f} ± {s['sd']:.1f}"
                if s["unsettled"]:
                    txt += f" ({s['unsettled']}†)"
                if s["errors"]:
                    txt += f" ({s['errors']} failed)"
                cells.append(txt)
            key = "A/B" if cfg.key == "A" else cfg.key
            lines.append(f"| {key}: {cfg.label} | {model} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def table_yaw(mc_no: dict, mc_yaw: dict) -> str:
    lines = [
        "| platform | lines: planes, no correction | lines: planes, iterated | lines: rigorous |",
        "|---|---:|---:|---:|",
    ]
    for name, mc in (("no yaw steering (CBERS-like)", mc_no), ("yaw-steered", mc_yaw)):
        cells = [f"{mc[('ON2', 'A', v)]['mean']:.1f} ± {mc[('ON2', 'A', v)]['sd']:.1f}" for v in ("ep0", "epi", "rig")]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def crab_angle_deg(scene: LineScene) -> float:
    """Angle between the camera's x axis and the Earth-fixed velocity at the scene centre."""
    im = scene.images[0]
    t = np.array([im.centre_time_s])
    _r, v, m = im.frames(t)
    vx = v[0] / np.linalg.norm(v[0])
    x = m[0][0]
    # project both on the plane normal to the radial direction
    up = _r[0] / np.linalg.norm(_r[0])
    a = vx - (vx @ up) * up
    b = x - (x @ up) * up
    return float(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1, 1))))


def header_vs_adjusted(scene: LineScene) -> tuple[float, float, float]:
    """(header speed, adjusted footprint speed in m/s, kappa change in deg) for configuration A
    lines with the iterated correction: what 'corrected once' gets wrong."""
    from solver.adjust import prepare
    from solver.schema.job import load_job

    job = configure(base_job(scene), CONFIGS[0], True, False, "equivalent_planes", "iterated")
    rep = run(job)
    p = {q["name"]: q["value"] for q in rep["images"][0]["parameters"]}
    line_time = job["cameras"][0]["line_time_s"]
    header = float(np.linalg.norm(job["images"][0]["approx_state"]["velocity_ecef_m_s"]))
    initial = prepare(load_job(job)).images[0].coef()
    kappa0 = math.degrees(initial[20])
    return header, float(math.hypot(p["X1"], p["Y1"]) / line_time), float(p["kappa"] - kappa0)


def discussion(mc: dict, mc_yaw: dict, crab: float, gsd: float, speeds: tuple[float, float, float]) -> str:  # noqa: C901
    """Findings against the paper's, with this run's numbers (the qualitative words follow them)."""

    def m(model: str, c: str, v: str) -> float:
        return mc[model, c, v]["mean"]

    def times(a: float, b: float) -> str:
        return f"{a / b:.1f} times" if b > 0 else "-"

    ep_gain = m("ON2", "A", "ep0") / m("ON2", "A", "epi")
    yaw0, yaw1 = mc_yaw["ON2", "A", "ep0"]["mean"], mc_yaw["ON2", "A", "epi"]["mean"]
    rig_vs_ep = max(abs(m(md, "A", "rig") - m(md, "A", "epi")) for md in ("ON2", "MT8"))
    unsettled = sum(s["unsettled"] for (_md, _c, v), s in mc.items() if v in ("epi", "c-epi"))
    runs = sum(s["n"] for (_md, _c, v), s in mc.items() if v in ("epi", "c-epi"))
    worst_ep = max(
        ((md, c) for (md, c, v) in mc if v == "epi"), key=lambda k: m(k[0], k[1], "epi") - m(k[0], k[1], "rig")
    )
    chi_mt8, chi_on2 = mc["MT8", "A", "rig"]["chi2_pass"], mc["ON2", "A", "rig"]["chi2_pass"]
    d_pts = m("ON2", "D", "points"), m("MT8", "D", "points")
    f_comb, f_lines = m("ON2", "F", "c-rig"), m("ON2", "F", "rig")
    robust = all(m(md, c, "c-rig") <= min(m(md, c, "rig"), m(md, c, "points")) for md in ("ON2", "MT8") for c in ("G", "H"))
    out = [
        (
            f"- **The pushbroom correction {'matters' if ep_gain > 2 else 'matters little'}.** Without it "
            f"the equivalent planes model leaves an orientation error of {m('ON2', 'A', 'ep0'):.1f} m (ON2, 50 "
            f"lines) against {m('ON2', 'A', 'epi'):.1f} m with it ({times(m('ON2', 'A', 'ep0'), m('ON2', 'A', 'epi'))}; "
            f"MT8 {m('MT8', 'A', 'ep0'):.1f} against {m('MT8', 'A', 'epi'):.1f} m), and with 10 lines it "
            f"breaks down ({m('MT8', 'G', 'ep0'):.0f} m with MT8). The paper saw errors up to ten times larger "
            "without it (its Table 6). In the simulation the cause is the Earth-rotation skew: without yaw "
            f"steering the CCD stays across the inertial velocity, {crab:.1f} deg away from the ground track, "
            "so the scene is sheared against a frame image taken from one perspective centre and a road "
            "crossing the scan lines is rotated by up to that angle. On a yaw-steered platform the same lines "
            f"give {yaw0:.1f} m uncorrected and {yaw1:.1f} m corrected "
            f"({'no real difference' if yaw0 < 1.3 * yaw1 else times(yaw0, yaw1)}): what remains for the "
            "correction there is the small difference between the along-track scale of the scene and of a "
            "frame image and the attitude rates during one road. Whether CBERS-2 yaw-steered we could not "
            "establish; the paper's tenfold effect suggests a skewed scene like the simulated one."
        ),
        (
            f"- **Corrected once is not enough here.** Computed once from the initial orientation (the "
            f"paper's procedure) the correction gives {m('ON2', 'A', 'ep1'):.0f} m. The initial orientation is "
            "the header state vector with the nominal attitude, and both are wrong in exactly what the "
            "correction depends on (seed 002: 'only the errors in the variation' of the EOP). With omega and "
            "phi held, the polynomial model's camera does not pitch with the orbit, so its adjusted X1, Y1 "
            f"describe the footprint's speed, {speeds[1]:.0f} m/s, not the satellite's {speeds[0]:.0f} m/s "
            f"of the header ({100 * (1 - speeds[1] / speeds[0]):.0f} % less); and the adjusted kappa differs "
            f"from the nominal one (camera x axis along the velocity) by {abs(speeds[2]):.1f} deg, the crab "
            "angle. A correction computed from that start describes another scene. Recomputed from the "
            "solution until it settles (iterated) it converges; the paper's approximate EOP, from the "
            "ephemeris of a model fitted to its scene, were presumably much closer in their rates."
        ),
        (
            f"- **The rigorous model and the corrected equivalent planes agree** where both are well "
            f"determined: their mean orientation errors differ by at most {rig_vs_ep:.2f} m with 50 lines. At "
            "its fixed point the corrected model fits exactly the line through the pushbroom projections of "
            "the endpoints, which is what the rigorous model fits point by point. The rigorous model needs no "
            "refreshes, uses every measured point and gives the covariance of its own equations (the "
            "equivalent planes Jacobian is the frame camera's). The difference shows with weak control: "
            f"worst here configuration {worst_ep[1]} with {worst_ep[0]}, "
            f"{m(worst_ep[0], worst_ep[1], 'epi'):.1f} m against {m(worst_ep[0], worst_ep[1], 'rig'):.1f} m"
            + (
                f"; the iterated correction did not settle in {unsettled} of {runs} adjustments (marked †)"
                if unsettled
                else f"; the iterated correction settled in all {runs} adjustments"
            )
            + ". With omega or phi estimated (P, K models) the equivalent planes model is unreliable "
            "(tested on model-consistent data) and the report says so."
        ),
        (
            f"- **Polynomial order.** The paper found the first-order model (MT8) better for its scene. Here "
            f"the second-order model is {times(m('MT8', 'A', 'rig'), m('ON2', 'A', 'rig'))} more accurate "
            f"with 50 lines ({m('ON2', 'A', 'rig'):.1f} m against {m('MT8', 'A', 'rig'):.1f} m) and passes "
            f"the chi-square test in {100 * chi_on2:.0f}% of the scenes against {100 * chi_mt8:.0f}% for MT8: "
            "over the 113 km of a CBERS scene the satellite's height above the LGS plane changes by some "
            "300 m quadratically (Earth curvature), which a linear Z cannot follow. Where the control leaves "
            "part of the scene empty the 12 parameters extrapolate "
            f"{'worse' if d_pts[0] > d_pts[1] else 'no worse'}: the poorly distributed points alone give "
            f"{d_pts[0]:.1f} m with ON2 against {d_pts[1]:.1f} m with MT8. That, and 1 px-level "
            "measurements (the paper's a-posteriori sigma0 0.18 for sigma 1 px) that cannot see the "
            "curvature, may be the paper's situation."
        ),
        (
            f"- **Distribution matters more than amount.** With ON2, 30 poorly distributed lines give "
            f"{m('ON2', 'D', 'rig'):.1f} m and 15 poor points {m('ON2', 'D', 'points'):.1f} m, against "
            f"{m('ON2', 'C', 'rig'):.1f} m and {m('ON2', 'C', 'points'):.1f} m well distributed. The two poor "
            f"sets together cover the scene and give {m('ON2', 'D', 'c-rig'):.1f} m (the paper's experiment 6, "
            f"test 1: from 3.5 GSD to about 1 GSD); two poor sets on the same part of the scene give "
            f"{f_comb:.1f} m (test 2), {'no better than' if f_comb >= 0.95 * f_lines else 'little better than'} "
            f"the lines alone ({f_lines:.1f} m). MT8 shows the same order "
            f"({m('MT8', 'D', 'rig'):.1f}, {m('MT8', 'D', 'points'):.1f}, {m('MT8', 'D', 'c-rig'):.1f} m) "
            "above its model-error floor."
        ),
        (
            f"- **The combination is {'the most robust' if robust else 'robust'}.** 10 good lines alone give {m('ON2', 'G', 'rig'):.1f} m "
            f"(ON2) / {m('MT8', 'G', 'rig'):.1f} m (MT8); with 15 good points {m('ON2', 'G', 'c-rig'):.1f} / "
            f"{m('MT8', 'G', 'c-rig'):.1f} m; with 15 poorly distributed points {m('ON2', 'H', 'c-rig'):.1f} / "
            f"{m('MT8', 'H', 'c-rig'):.1f} m, where those points alone give {m('ON2', 'H', 'points'):.1f} / "
            f"{m('MT8', 'H', 'points'):.1f} m (the paper's experiment 7: a few well-oriented lines help poorly "
            "distributed points most). With many good lines the lines dominate: each road contributes tens "
            "of sub-pixel edge points."
            + (
                f" With MT8 the 10 lines even make 15 good points worse ({m('MT8', 'G', 'points'):.1f} m alone): "
                "with a model that cannot follow the trajectory, more control elsewhere moves the compromise."
                if m("MT8", "G", "c-rig") > m("MT8", "G", "points")
                else ""
            )
        ),
        (
            f"- **Magnitudes.** The check points' own measurement (0.5 px of {gsd:.1f} m) puts a floor of "
            f"about {0.5 * gsd:.0f} m per axis under the E/N RMSE, which is why those columns look alike "
            "(about 0.5 GSD, like the paper's reference values in its Table 3); the orientation-error columns "
            "remove that floor."
        ),
    ]
    return "\n".join(out)


def render(seed: int, res: dict, mc: dict, mc_yaw: dict, n_rep: int, elapsed: float, crab: float, gsd: float, speeds) -> str:
    parts = [
        BEGIN,
        "## Seed 002: straight lines, points and both on a CBERS scene",
        "",
        f"Regenerated by `.venv/bin/python scripts/experiments_seed002.py` (seed {seed}, {n_rep} Monte "
        f"Carlo replicates, {elapsed:.0f} s). Do not edit by hand.",
        "",
        "**Setup.** One simulated CBERS-like CCD scene (5812 x 5812 px, ~20 m GSD, 778 km sun-synchronous "
        "orbit integrated with J2-J4, attitude drift, no yaw steering; `solver/simulate/lines.py`), "
        "coordinates written in SAD69 / UTM 22S. Road segments of 1.5-6 km on the terrain are the "
        "straight lines: their image points (every ~5 px, each at its own line time) have 0.3 px "
        f"noise; control and check points 0.5 px; all ground coordinates {GCP_SIGMA_M} m survey noise "
        "(weighted). Sets: 8 check points near a 3 x 3 grid (paper Figure 6); 23 well-spread control "
        "points (the first 15 of them: 15 good); 15 poor points in the lower 40 % of the scene (B, where "
        "the poor roads are not) or in its upper-left quarter (C, where they are); 50 well-spread roads (the first 30 and 10: good subsets); 30 poor roads "
        "in the upper 55 %, mostly along two directions. Models: ON2 (= MT12, the paper's 12 "
        "parameters) and MT8 (8 parameters), omega = phi = 0 held. Columns: the adjustment's control. "
        "'check E / N': RMSE at the 8 check points as measured, in GSD (the paper's Figures 12-14); "
        "'orientation error': planimetric RMSE (m) at the same points with error-free image "
        "coordinates and coordinates, i.e. the error of the adjusted orientation alone. † : the "
        "iterated correction did not settle (a warning in the report).",
        "",
        "### Experiments 1-7 (one realisation, cf. paper Table 4 and Figures 12-14)",
        "",
    ]
    for num, model, configs, how in EXPERIMENTS:
        parts += [f"*Experiment {num} ({model}; lines and points {how}): configuration(s) {', '.join(configs)}*", ""]
    parts += [table_single(res, [c.key for c in CONFIGS]), ""]
    parts += [
        f"### Monte Carlo over {n_rep} simulated scenes: orientation error (m), mean ± sd, both models",
        "",
        table_monte_carlo(mc),
        "",
        "### The correction and the platform's yaw steering (configuration A, ON2, orientation error in m)",
        "",
        table_yaw(mc, mc_yaw),
        "",
        "### Discussion",
        "",
        discussion(mc, mc_yaw, crab, gsd, speeds),
        END,
    ]
    return "\n".join(parts) + "\n"


def write_section(path: Path, section: str) -> None:
    """Replace this script's section of the file between its markers, keep everything else."""
    replace_section(path, BEGIN, END, section)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=2009, help="seed of the headline realisation")
    ap.add_argument("--replicates", type=int, default=10, help="Monte Carlo scenes (seeds seed .. seed+N-1)")
    ap.add_argument("--output", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "experiments.md")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    n = max(1, args.replicates)
    scene = simulate(args.seed)
    res = run_scene(scene)
    seeds = list(range(args.seed, args.seed + n))
    mc = monte_carlo(seeds, configs=MC_CONFIGS)
    a_only = [c for c in CONFIGS if c.key == "A"]
    yaw_variants = [v for v in VARIANTS if v[0] in ("ep0", "epi", "rig")]
    mc_yaw = monte_carlo(seeds, yaw=True, configs=a_only, variants=yaw_variants)
    gsd = next(m["gsd_m"] for m in res.values() if "gsd_m" in m)
    speeds = header_vs_adjusted(scene)
    section = render(args.seed, res, mc, mc_yaw, n, time.perf_counter() - t0, crab_angle_deg(scene), gsd, speeds)
    write_section(args.output, section)
    print(f"wrote {args.output} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
