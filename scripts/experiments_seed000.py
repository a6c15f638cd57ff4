#!/usr/bin/env python
"""Reproduce seed 000's experiments 1-32 on simulated PRISM images; regenerate docs/experiments.md.

Seed 000 (Rodrigues, Mitishita, Ferreira 2015) oriented a backward and a nadir PRISM image of
the same triplet with eight platform models (K1, K2, J2-1, J2-2, ON1, ON2, P1, P2) and two
control configurations over the same 23 points: 14 control / 9 check and 9 control / 14 check.
Here the images come from the scene simulator (independent orbit and attitude physics): one
simulated pass images the same 23 ground points with the backward and the nadir camera; each
image is then adjusted alone, as in the paper, with every model and both configurations.

The headline tables (laid out like the paper's Tables 4, 5, 8 and 9) are one realisation
(``--seed``); a Monte Carlo summary over ``--replicates`` independent scenes shows which
differences are systematic and which are the luck of one draw.

Usage (from the repository root; about half a minute)::

    .venv/bin/python scripts/experiments_seed000.py            # rewrites the seed000 section
    .venv/bin/python scripts/experiments_seed000.py --replicates 5 --output /tmp/e.md
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from solver.api import run
from solver.compare import compare_models
from solver.geometry.geodesy import LocalFrame, to_ecef
from solver.schema.job import load_job
from solver.simulate.attitude import opk_from_matrix
from solver.simulate.camera import prism_camera
from solver.simulate.scene import Group, Scene, SceneSettings

sys.path.insert(0, str(Path(__file__).resolve().parent))
from doc_sections import replace_section  # noqa: E402

MODELS = ["K1", "K2", "J2-1", "J2-2", "ON1", "ON2", "P1", "P2"]
VIEWS = ("backward", "nadir")
CONFIGS = ((14, 9), (9, 14))  # (control, check) over the same 23 points
BEGIN, END = "<!-- BEGIN seed000 -->", "<!-- END seed000 -->"
ON_TRUE = "ON1, true omega/phi held"
NOISE_PX = 0.5
GCP_SIGMA_M = 0.2

# Seed 000 Tables 5 and 9 (check-point RMSE X_L, Y_L in metres), for reference only.
PAPER_RMSE = {
    ("backward", 0): [(1.961, 1.468), (1.948, 1.502), (1.957, 1.101), (1.990, 1.116), (2.714, 2.442), (2.711, 2.386), (1.834, 2.350), (1.827, 2.452)],
    ("backward", 1): [(1.712, 2.764), (1.718, 2.725), (1.854, 2.860), (1.862, 2.856), (2.495, 16.190), (2.468, 16.051), (5.158, 3.871), (5.124, 4.666)],
    ("nadir", 0): [(0.937, 1.915), (1.100, 1.923), (1.062, 1.865), (1.125, 1.865), (1.640, 2.448), (1.614, 1.630), (0.765, 3.007), (0.789, 2.475)],
    ("nadir", 1): [(1.712, 2.767), (1.720, 2.728), (1.857, 2.863), (1.865, 2.859), (2.393, 2.433), (2.191, 2.620), (5.156, 3.872), (5.122, 4.667)],
}


def simulate_pair(seed: int) -> Scene:
    """One pass: the backward and nadir cameras see the same 23 ground points."""
    settings = SceneSettings(preset="seed000", seed=seed, noise_px=NOISE_PX, gcp_sigma_m=GCP_SIGMA_M, name=f"seed000 seed {seed}")
    group = Group([prism_camera(v) for v in VIEWS], CONFIGS[0][0], CONFIGS[0][1], 0)
    return Scene(settings, [group]).simulate()


def single_image_job(pair_job: dict[str, Any], view: str, n_control: int) -> dict[str, Any]:
    """The job of one image of the pair, with the first ``n_control`` control points as gcps.

    Control points are written in farthest-point order, so the first ones surround the rest.
    Control is held fixed (the paper's parametric adjustment of image observations only).
    """
    job = copy.deepcopy(pair_job)
    image = next(im for im in job["images"] if im["camera"] == f"prism-{view}")
    job["images"] = [image]
    job["cameras"] = [c for c in job["cameras"] if c["id"] == image["camera"]]
    job["observations"] = [o for o in job["observations"] if o["image"] == image["id"]]
    k = 0
    for p in job["points"]:
        if p["role"] == "tie":
            continue
        p["role"] = "gcp" if k < n_control else "check"
        p.pop("sigma_m", None)
        k += 1
    job["options"] = {"control": "fixed", "covariance": False}
    job["name"] = f"{pair_job['name']} {view} {n_control} control"
    return job


def run_experiments(seed: int) -> tuple[dict[tuple[str, int], dict[str, Any]], Scene]:
    """All 32 experiments on one simulated pass: {(view, config index): comparison report}."""
    scene = simulate_pair(seed)
    pair = scene.job()
    out = {}
    for view in VIEWS:
        for c, (n_control, _) in enumerate(CONFIGS):
            out[view, c] = compare_models(load_job(single_image_job(pair, view, n_control)), MODELS)
    return out, scene


def true_angles_deg(scene: Scene, view: str, job: dict[str, Any]) -> tuple[float, float]:
    """True (omega, phi) in degrees (solver convention) at the image's centre line, in the LGS
    the solver builds for ``job`` (east-north-up at the centroid of its gcps)."""
    im = next(i for i in scene.images if i.camera.id == f"prism-{view}")
    gcps = np.array([p["coordinates"] for p in job["points"] if p["role"] == "gcp"])
    lgs = LocalFrame.at_centroid(to_ecef(gcps, job["crs"]))
    _, _, m = im.frames(np.array([im.time_of_line((im.camera.lines - 1) / 2)]))
    omega, phi, _ = opk_from_matrix(m[0] @ lgs.rotation_ecef_to_lgs.T)
    return float(np.degrees(omega)), float(np.degrees(phi))


def on1_with_true_angles(scene: Scene, pair: dict[str, Any], view: str, n_control: int) -> dict[str, Any]:
    """ON1 with omega/phi held at their true values instead of (0, mounting pitch)."""
    job = single_image_job(pair, view, n_control)
    omega, phi = true_angles_deg(scene, view, job)
    job["images"][0]["model"] = {"name": "ON1", "options": {"omega_deg": omega, "phi_deg": phi}}
    return run(load_job(job))


def _rows(result: dict[str, Any]) -> list[dict[str, Any]]:
    rows = []
    for row in result["table"]:
        rep = result["reports"][row["model"]]
        if "error" in row:
            rows.append({"model": row["model"], "error": row["error"]})
            continue
        tt = rep["checkpoints"]["t_test"]
        chi = rep["adjustment"]["chi2"]
        rows.append(
            row
            | {"t_e": tt["e"]["statistic"], "t_n": tt["n"]["statistic"], "t_crit": tt["e"]["critical"], "t_dof": tt["e"]["dof"]}
            | {"chi2_lower": chi.get("critical_lower")}
        )
    return rows


def _exp_number(view: str, c: int, m: int) -> int:
    return (0 if view == "backward" else 16) + 8 * c + m + 1


def table_adjustment(results: dict, view: str) -> str:
    """Paper Tables 4 (backward) and 8 (nadir): chi-square and residual RMSE."""
    head = "| Exp. (model) | chi2 computed | chi2 theoretical (dof; 0.975) | RMSE x_s (mm) | RMSE y_s (mm) |"
    lines = []
    for c, (n_control, n_check) in enumerate(CONFIGS):
        lines += [f"\n*{n_control} control / {n_check} check points*\n", head, "|---|---:|---:|---:|---:|"]
        for m, r in enumerate(_rows(results[view, c])):
            label = f"{_exp_number(view, c, m)} ({r['model']})"
            if "error" in r:
                lines.append(f"| {label} | error: {r['error'][:60]} | | | |")
                continue
            flag = ""
            if not r["chi2_passed"]:
                flag = " (rejected: above)" if r["chi2_statistic"] > r["chi2_critical"] else f" (rejected: below {r['chi2_lower']:.2f})"
            lines.append(
                f"| {label} | {r['chi2_statistic']:.2f}{flag} | {r['chi2_critical']:.2f} ({r['dof']}) "
                f"| {r['rmse_x_mm']:.4f} | {r['rmse_y_mm']:.4f} |"
            )
    return "\n".join(lines)


def table_accuracy(results: dict, view: str) -> str:
    """Paper Tables 5/9 (check-point RMSE in the LGS) with Tables 6/10 (t-tests) alongside."""
    head = "| Exp. (model) | RMSE E (m) | RMSE N (m) | planimetric (m) | t E | t N | t (dof; 0.975) | paper X_L / Y_L (m) |"
    lines = []
    for c, (n_control, n_check) in enumerate(CONFIGS):
        lines += [f"\n*{n_control} control / {n_check} check points*\n", head, "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for m, r in enumerate(_rows(results[view, c])):
            label = f"{_exp_number(view, c, m)} ({r['model']})"
            px, py = PAPER_RMSE[view, c][m]
            if "error" in r:
                lines.append(f"| {label} | error | | | | | | {px:.3f} / {py:.3f} |")
                continue
            te = f"{abs(r['t_e']):.3f}" + ("*" if not r["t_test_e_passed"] else "")
            tn = f"{abs(r['t_n']):.3f}" + ("*" if not r["t_test_n_passed"] else "")
            lines.append(
                f"| {label} | {r['check_rmse_e_m']:.3f} | {r['check_rmse_n_m']:.3f} | {r['check_rmse_planimetric_m']:.3f} "
                f"| {te} | {tn} | {r['t_crit']:.3f} ({r['t_dof']}) | {px:.3f} / {py:.3f} |"
            )
    return "\n".join(lines)


def monte_carlo(seeds: list[int]) -> dict[tuple[str, int, str], dict[str, float]]:
    """Mean planimetric RMSE, chi-square pass rate and t-test pass rate per (view, config, model)."""
    acc: dict[tuple[str, int, str], list[tuple[float, bool, bool]]] = {}
    for seed in seeds:
        res, scene = run_experiments(seed)
        pair = scene.job()
        for view in VIEWS:
            for c, (n_control, _) in enumerate(CONFIGS):
                rep = on1_with_true_angles(scene, pair, view, n_control)
                a = rep["adjustment"]
                cp = rep["checkpoints"]
                acc.setdefault((view, c, ON_TRUE), []).append(
                    (
                        cp["rmse_m"]["planimetric"],
                        bool(a["chi2"]["passed"]),
                        bool(cp["t_test"]["e"]["passed"] and cp["t_test"]["n"]["passed"]),
                        a["chi2"]["statistic"] / a["dof"],
                        rep["images"][0]["residual_rmse"]["x_mm"],
                    )
                )
        for (view, c), result in res.items():
            for r in _rows(result):
                if "error" in r:
                    continue
                acc.setdefault((view, c, r["model"]), []).append(
                    (
                        r["check_rmse_planimetric_m"],
                        bool(r["chi2_passed"]),
                        bool(r["t_test_e_passed"] and r["t_test_n_passed"]),
                        r["chi2_statistic"] / r["dof"],
                        r["rmse_x_mm"],
                    )
                )
    out = {}
    for key, vals in acc.items():
        a = np.array(vals, dtype=float)
        out[key] = {
            "n": len(a),
            "plan_mean": a[:, 0].mean(),
            "plan_std": a[:, 0].std(ddof=1) if len(a) > 1 else 0.0,
            "chi2_pass": a[:, 1].mean(),
            "t_pass": a[:, 2].mean(),
            "chi2_per_dof": a[:, 3].mean(),
            "rmse_x_mm": a[:, 4],
        }
    return out


def table_monte_carlo(mc: dict, n: int) -> str:
    lines = [
        "| model | " + " | ".join(f"{v} {CONFIGS[c][0]}/{CONFIGS[c][1]}" for v in VIEWS for c in range(2)) + " |",
        "|---|" + "---:|" * 4,
    ]
    for m in MODELS + [ON_TRUE]:
        cells = []
        for v in VIEWS:
            for c in range(2):
                s = mc.get((v, c, m))
                cells.append("-" if s is None else f"{s['plan_mean']:.2f} ± {s['plan_std']:.2f} ({100 * s['chi2_pass']:.0f}%, {100 * s['t_pass']:.0f}%)")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def discussion(mc: dict, phi_backward_deg: float) -> str:  # noqa: C901 - one paragraph per finding
    """Findings against the paper's, with the numbers of this run (qualitative words follow them)."""

    def mean(v: str, c: int, models: list[str], key: str = "plan_mean") -> float:
        return float(np.mean([mc[v, c, m][key] for m in models if (v, c, m) in mc]))

    k, j2, on, p = ["K1", "K2"], ["J2-1", "J2-2"], ["ON1", "ON2"], ["P1", "P2"]
    good = k + j2 + p
    bk, bon, bp = mean("backward", 0, k), mean("backward", 0, on), mean("backward", 0, p)
    nk, non = mean("nadir", 0, k), mean("nadir", 0, on)
    rej_on_b = 1 - np.mean([mc["backward", c, m]["chi2_pass"] for c in range(2) for m in on])
    rej_on_n = 1 - np.mean([mc["nadir", c, m]["chi2_pass"] for c in range(2) for m in on])
    dj2 = max(abs(mc[v, c, a]["plan_mean"] - mc[v, c, b]["plan_mean"]) for v in VIEWS for c in range(2) for a, b in zip(k, j2))
    dxs = max(float(np.max(np.abs(mc[v, c, a]["rmse_x_mm"] - mc[v, c, b]["rmse_x_mm"]))) for v in VIEWS for c in range(2) for a, b in zip(k, j2))
    dk2 = max(abs(mc[v, c, "K1"]["plan_mean"] - mc[v, c, "K2"]["plan_mean"]) for v in VIEWS for c in range(2))
    loss = {(v, g): mean(v, 1, ms) - mean(v, 0, ms) for v in VIEWS for g, ms in (("P", p), ("K", k))}
    p_worse = all(loss[v, "P"] > loss[v, "K"] + 0.1 for v in VIEWS)
    lo = min(mc[v, c, m]["plan_mean"] for v in VIEWS for c in range(2) for m in good) / 2.5
    hi = max(mc[v, c, m]["plan_mean"] for v in VIEWS for c in range(2) for m in good) / 2.5
    chi_dof = float(np.mean([mc[v, c, m]["chi2_per_dof"] for v in VIEWS for c in range(2) for m in good]))
    t_pass = float(np.mean([mc[v, c, m]["t_pass"] for v in VIEWS for c in range(2) for m in good]))
    on_worse = bon > 1.2 * max(bk, bp) and rej_on_b > rej_on_n + 0.2
    out = [
        (
            f"- **ON models with absolute constraints {'degrade' if on_worse else 'do not clearly degrade'} off-nadir.** "
            f"Holding omega = 0 and phi = -23.8 deg on the backward image gives a mean planimetric "
            f"check RMSE of {bon:.2f} m (K models {bk:.2f} m, P models {bp:.2f} m, 14 control points); "
            f"the chi-square test rejects {100 * rej_on_b:.0f}% of the backward ON adjustments and "
            f"{100 * rej_on_n:.0f}% of the nadir ones (nadir: ON {non:.2f} m, K {nk:.2f} m). The paper "
            "found the same pattern (experiments 5, 6, 13, 14 against 21, 22, 29, 30). The simulation "
            "shows why: the held phi is the camera's mounting pitch, but the rotation from the LGS "
            "(tangent at the control centroid) to the camera also contains the Earth's curvature "
            "between the scene's vertical and the vertical under the satellite, some 300 km back "
            f"along the track: the truth gives phi = {phi_backward_deg:.2f} deg at the centre line. "
            "The position polynomials absorb most of that 2.6 deg error (omega/Y and phi/X are nearly "
            "interchangeable, as Orun and Natarajan argued) but not all of it. Holding the true "
            f"angles instead (row '{ON_TRUE}') gives {mean('backward', 0, [ON_TRUE]):.2f} m with "
            f"{100 * mc['backward', 0, ON_TRUE]['chi2_pass']:.0f}% chi-square passes, as good as the "
            "models that estimate them. At nadir the satellite is over the scene and the held zeros "
            "are nearly right."
        ),
        (
            f"- **J2 changes little within 6 s.** K and J2 models differ by at most {dj2:.3f} m in mean "
            f"planimetric RMSE and by at most {1000 * dxs:.2f} micrometres in the x_s residual RMSE of any "
            "single adjustment. Over one scene the J2 acceleration (about 0.01 m/s^2 at 700 km) moves "
            "the perspective centre by at most about 0.2 m, under a tenth of a GSD. The paper "
            "concluded the same (decimetre differences of either sign)."
        ),
        (
            f"- **Quadratic kappa adds little.** K1 and K2 differ by at most {dk2:.2f} m in mean "
            "planimetric RMSE; the simulated yaw drift is close to linear over one scene (the paper: "
            "decimetre differences)."
        ),
        (
            "- **Fewer control points.** Going from 14 to 9 control points changes the mean planimetric "
            f"RMSE of the P models by {loss['backward', 'P']:+.2f} m (backward) / {loss['nadir', 'P']:+.2f} m "
            f"(nadir) and of the K models by {loss['backward', 'K']:+.2f} m / {loss['nadir', 'K']:+.2f} m"
            + (
                ": the polynomial models suffer more, as in the paper (whose P1/P2 reached about 5 m "
                "in experiments 15, 16, 31 and 32), though much less. "
                if p_worse
                else ". Unlike the paper (whose P1/P2 reached about 5 m in experiments 15, 16, 31 and "
                "32), the polynomial models do not clearly suffer more here. "
            )
            + "Our 9 control points are chosen by farthest-point sampling, so they still surround the "
            "scene, which is kinder "
            "than the paper's second configuration."
        ),
        (
            f"- **Magnitudes and tests.** With 0.5 px simulated image noise the K, J2 and P models reach "
            f"{lo:.2f}-{hi:.2f} GSD (mean over the passes). Most of that is the check points' own "
            "measurement: one image and 0.5 px give about 1.25 m per axis at nadir, a floor of about "
            "1.8 m planimetric before any orientation error. The paper's 1-3 m with an a-priori "
            "sigma of 1 px (which would put the floor near 3.5 m) and chi-square values mostly below "
            "their degrees of freedom suggest its real measurements were better than 1 px. Here "
            f"chi-square/dof averages {chi_dof:.2f} for these models because the simulated noise is "
            f"exactly the stated sigma. Both t-tests pass in only {100 * t_pass:.0f}% of the "
            "adjustments, fewer than the nominal 95%: the check discrepancies of one image share that "
            "image's orientation error, so they are not the independent sample the test assumes; the "
            "paper's test has the same blind spot."
        ),
    ]
    return "\n".join(out)


def render(seed: int, results: dict, mc: dict, n_rep: int, elapsed_s: float, phi_backward_deg: float) -> str:
    parts = [
        BEGIN,
        "## Seed 000: platform models on single images",
        "",
        "Regenerated by `.venv/bin/python scripts/experiments_seed000.py` "
        f"(seed {seed}, {n_rep} Monte Carlo replicates, {elapsed_s:.0f} s). Do not edit by hand.",
        "",
        "**Setup.** One simulated ALOS-like descending pass over Presidente Prudente (independent "
        "orbit integration with J2-J4, yaw steering, attitude drift; `solver/simulate/`): the "
        "backward (-23.8 deg) and nadir PRISM-like cameras (16000 x 14496 px, four chips) image "
        "the same 23 ground points. Image noise 0.5 px (sigma 0.5 px in the adjustment), survey "
        "noise 0.2 m per axis; control held fixed; check points projected by inverse "
        "collinearity onto their known height and compared in the LGS (east = X_L, north = Y_L). "
        "Configuration 1: 14 control / 9 check; configuration 2: 9 control / 14 check (the same "
        "points, the 9 controls are the outermost). chi-square: a-posteriori vs a-priori variance "
        "at 0.975 with its degrees of freedom; t: bias test of the discrepancies (|t| > critical, "
        "marked *, means biased). The paper's values (Tables 5, 9) are given for reference; its "
        "data were real images, so only the pattern is comparable.",
        "",
        "### Backward image: adjustments (cf. paper Table 4)",
        table_adjustment(results, "backward"),
        "",
        "### Backward image: check-point accuracy and t-tests (cf. paper Tables 5, 6)",
        table_accuracy(results, "backward"),
        "",
        "### Nadir image: adjustments (cf. paper Table 8)",
        table_adjustment(results, "nadir"),
        "",
        "### Nadir image: check-point accuracy and t-tests (cf. paper Tables 9, 10)",
        table_accuracy(results, "nadir"),
        "",
        f"### Monte Carlo over {n_rep} simulated passes",
        "",
        "Mean ± standard deviation of the planimetric check RMSE (m); in brackets the share of "
        "adjustments passing the chi-square test and passing both t-tests.",
        "",
        table_monte_carlo(mc, n_rep),
        "",
        "### Discussion",
        "",
        discussion(mc, phi_backward_deg),
        END,
    ]
    return "\n".join(parts) + "\n"


def write_section(path: Path, section: str) -> None:
    """Replace this script's section of the file between its markers, keep everything else."""
    replace_section(path, BEGIN, END, section)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=2008, help="seed of the headline realisation")
    ap.add_argument("--replicates", type=int, default=50, help="Monte Carlo passes (seeds seed .. seed+N-1)")
    ap.add_argument("--output", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "experiments.md")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    results, scene = run_experiments(args.seed)
    mc = monte_carlo(list(range(args.seed, args.seed + max(1, args.replicates))))
    phi = true_angles_deg(scene, "backward", single_image_job(scene.job(), "backward", CONFIGS[0][0]))[1]
    section = render(args.seed, results, mc, max(1, args.replicates), time.perf_counter() - t0, phi)
    write_section(args.output, section)
    print(f"wrote {args.output} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
