"""Check points: coordinates from the adjusted orientation, discrepancies and their statistics.

Check points never enter the adjustment. Each is computed from its image observations with the
adjusted exterior orientation:

* ``mono`` (seen in one image): inverse collinearity: the pixel's ray intersected with the
  horizontal plane of the LGS at the point's known height (seed 000);
* ``intersection`` (seen in two or more images): least-squares photogrammetric intersection,
  minimising the weighted image residuals (seed 001).

Discrepancies are estimated - known, in the LGS (east, north, up), metres.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from solver.engine.packed_tables import current_tables, records
from solver.kernels import all_observation_blocks, ray, ray_cam
from solver.report.statistics import axis_summary, shapiro_wilk, t_test
from solver.state import AdjustmentState


def _ray(problem: AdjustmentState, r: int):
    obs = problem.obs
    img = problem.images[obs.img[r]]
    if img.camera is None:  # RPC image: the line of sight through the RPC's height range
        return ray(img.kind, img.coef(), img.kc, obs.oc[r])
    cam = problem.cameras[obs.cam[r]]
    if not cam.has_iop:  # as the adjustment's kernels: the chip's offsets are in oc, and a camera
        return ray(img.kind, img.coef(), img.kc, obs.oc[r])  # beyond MAX_CHIPS chips has no IOP vector for the rest
    k = obs.chip_idx[r]
    return ray_cam(img.kind, img.coef(), img.kc, obs.oc[r], cam.values(), int(k), cam.chip_len_mm[k])


def _intersect(problem: AdjustmentState, rows: np.ndarray, start: np.ndarray, tables) -> np.ndarray:
    """Gauss-Newton on the point alone (orientation held), on the weighted image residuals."""
    img_tab, cam_tab, img_p, cam_p = tables
    rec = records(problem, rows)
    zeros = np.zeros(len(rows), dtype=np.int64)
    x = start.copy()
    for _ in range(20):
        res, _jf, _fc, jpt, _ok = all_observation_blocks(
            rec, img_tab, cam_tab, img_p, cam_p, x[None, :], zeros, np.ones(1, dtype=np.bool_),
            np.zeros(len(problem.images), dtype=np.int64), np.zeros(len(cam_tab), dtype=np.int64),
            np.zeros(max(len(problem.passes), 1), dtype=np.int64), 76,
        )
        step = np.linalg.lstsq(jpt.reshape(-1, 3), -res.ravel(), rcond=None)[0]
        x += step
        if np.linalg.norm(step) < 1e-7:
            break
    return x


def compute_checkpoints(problem: AdjustmentState, alpha: float, gsd_m: float | None) -> dict[str, Any]:
    obs = problem.obs
    points_out = []
    disc: dict[str, list[float]] = {"e": [], "n": [], "u": [], "planimetric": []}
    methods = set()
    tables = current_tables(problem)
    for p in problem.points:
        if p.role != "check" or p.known_lgs is None:
            continue
        rows = np.flatnonzero(obs.pt == p.index)
        if len(rows) == 0:
            continue
        if len(rows) == 1:
            s, d = _ray(problem, rows[0])
            lam = (p.known_lgs[2] - s[2]) / d[2]
            est = s + lam * d
            method = "mono"
        else:
            starts = []
            for r in rows:
                s, d = _ray(problem, r)
                starts.append(s + d * ((p.known_lgs[2] - s[2]) / d[2]))
            est = _intersect(problem, rows, np.mean(starts, axis=0), tables)
            method = "intersection"
        methods.add(method)
        dd = est - p.known_lgs
        plan = float(np.hypot(dd[0], dd[1]))
        disc["e"].append(float(dd[0]))
        disc["n"].append(float(dd[1]))
        disc["planimetric"].append(plan)
        if method == "intersection":
            disc["u"].append(float(dd[2]))
        points_out.append(
            {
                "id": p.id,
                "method": method,
                "images": [problem.images[obs.img[r]].id for r in rows],
                "known_lgs_m": [float(x) for x in p.known_lgs],
                "estimated_lgs_m": [float(x) for x in est],
                "discrepancy_m": {
                    "e": float(dd[0]),
                    "n": float(dd[1]),
                    "u": float(dd[2]) if method == "intersection" else None,
                    "planimetric": plan,
                },
            }
        )
    arrays = {k: np.array(v) for k, v in disc.items()}
    mean, std, rmse = axis_summary(arrays)
    # planimetric RMSE is sqrt(rmse_e^2 + rmse_n^2); its "mean" is the mean planimetric length
    if rmse["e"] is not None:
        rmse["planimetric"] = float(np.hypot(rmse["e"], rmse["n"]))

    def in_gsd(d: dict) -> dict | None:
        if not gsd_m:
            return None
        return {k: (None if v is None else v / gsd_m) for k, v in d.items()}

    method = None
    if methods:
        method = "intersection" if "intersection" in methods else "mono"
    return {
        "method": method,
        "n": len(points_out),
        "gsd_m": gsd_m,
        "points": points_out,
        "mean_m": mean,
        "std_m": std,
        "rmse_m": rmse,
        "mean_gsd": in_gsd(mean),
        "rmse_gsd": in_gsd(rmse),
        "t_test": {k: t_test(arrays[k], alpha) for k in ("e", "n", "u")},
        "shapiro_wilk": {k: shapiro_wilk(arrays[k], alpha) for k in ("e", "n", "u")},
    }
