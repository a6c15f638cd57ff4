"""Monte Carlo of direct georeferencing from sensor metadata (no ground control), shared by the
readers' tests: a job fragment's images with tie and check points imaged by the exact models,
the metadata perturbed in each run exactly as the job's stochastic model says it errs, and the
check points' empirical 3-D RMSE over the runs against the RMSE the reports predict.

The perturbation follows the job's weights (docs/models.md sections 9, 10 and 12):

- ephemeris, per-image models (OA-*): each image's line-0 state is the observation, so one
  position error (``sigma_position_m`` per axis) and one velocity error
  (``sigma_velocity_m_s``) per image, added to every sample of its ephemeris;
- ephemeris, pass models (PASS-*): every distinct sample (by epoch) of a pass is an observation
  of the propagated orbit, so each sample independently (the same error for a sample that
  several images of the pass carry);
- attitude: every distinct sample of an attitude block independently (roll, pitch, yaw by
  their ``sigma_deg``), and with ``bias_sigma_deg`` one common error per block and angle added
  to all its samples; a pass model's block is the camera's (option ``attitude: camera``, the
  default), any other model's the image's. ``attitude_white=False`` leaves out the independent
  part, for fragments whose ``sigma_deg`` is the real samples' own scatter (the Maxar reader
  measures it from them): that noise is already in the samples, drawing it again would double it;
- image observations: each by its ``sigma_px``.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

SIGMA_PX = 0.05  # image observations' weight (and noise)


def imaged_points(models: dict[str, Any], ground: np.ndarray, sigma_px: float = SIGMA_PX,
                  margin_px: float = 0.0) -> tuple[list[dict], list[dict]]:
    """Points and observations of ``ground`` (n, 3: longitude, latitude, height) imaged by the
    exact models ``{image id: LinescanModel}``: the points every image sees (inside its lines and
    columns less ``margin_px``), alternately check and tie."""
    lc = {i: m.ground_to_image(ground) for i, m in models.items()}
    inside = np.ones(ground.shape[0], bool)
    for i, m in models.items():
        x = lc[i]
        inside &= np.all(np.isfinite(x), axis=1)
        inside &= (x[:, 0] >= margin_px) & (x[:, 0] <= m.lines - 1 - margin_px)
        inside &= (x[:, 1] >= margin_px) & (x[:, 1] <= m.columns - 1 - margin_px)
    keep = np.flatnonzero(inside)
    points, obs = [], []
    for j, k in enumerate(keep):
        pid = f"P{j}"
        points.append({"id": pid, "role": "check", "coordinates": [float(v) for v in ground[k]]} if j % 2 == 0
                      else {"id": pid, "role": "tie"})
        obs += [{"image": i, "point": pid, "line": float(lc[i][k, 0]), "column": float(lc[i][k, 1]), "sigma_px": sigma_px}
                for i in models]
    return points, obs


def stereo_points(models: dict[str, Any], keep: int = 24, seed: int = 3, tries: int = 40) -> tuple[list[dict], list[dict]]:
    """``keep`` points seen by every image (alternately check and tie, :func:`imaged_points`):
    the ground under ``tries`` random pixels of the first image at random heights (0-1000 m),
    imaged by the exact models ``{image id: LinescanModel}``."""
    m = next(iter(models.values()))
    rng = np.random.default_rng(seed)
    ground = m.image_to_ground(rng.uniform(0, m.lines - 1, tries), rng.uniform(0, m.columns - 1, tries), rng.uniform(0, 1000, tries))
    points, obs = imaged_points(models, ground)
    points = points[:keep]
    kept = {p["id"] for p in points}
    return points, [o for o in obs if o["point"] in kept]


def perturbed(base: dict[str, Any], obs: list[dict], g: np.random.Generator,
              attitude_white: bool = True) -> tuple[dict[str, Any], list[dict]]:
    """A copy of the fragment ``base`` and of ``obs`` with every observed quantity perturbed as
    the job's weights say (module docstring)."""
    doc = copy.deepcopy(base)
    o = doc["options"]
    sp, sv = o["ephemeris"]["sigma_position_m"], o["ephemeris"]["sigma_velocity_m_s"]
    sa = np.asarray(o["attitude"]["sigma_deg"], float) if attitude_white else np.zeros(3)
    sb = o["attitude"].get("bias_sigma_deg")
    block_bias: dict[str, np.ndarray] = {}
    pass_states: dict[tuple[str, float], tuple[np.ndarray, np.ndarray]] = {}
    pass_att: dict[tuple[str, float], np.ndarray] = {}
    for im in doc["images"]:
        model = im["model"]
        if model["name"].startswith("PASS"):
            pass_id = str(model.get("options", {}).get("pass", "1"))
            per_image = model.get("options", {}).get("attitude", "camera") == "image"
            block = f"image {im['id']}" if per_image else f"camera {pass_id} {im['camera']}"
            for e in im["ephemeris"]:
                key = (pass_id, e["time_s"])
                if key not in pass_states:
                    pass_states[key] = (g.normal(0, sp, 3), g.normal(0, sv, 3))
                dp, dv = pass_states[key]
                e["position_ecef_m"] = [float(x) for x in np.array(e["position_ecef_m"]) + dp]
                e["velocity_ecef_m_s"] = [float(x) for x in np.array(e["velocity_ecef_m_s"]) + dv]
        else:
            block = f"image {im['id']}"
            dp, dv = g.normal(0, sp, 3), g.normal(0, sv, 3)
            for e in im["ephemeris"]:
                e["position_ecef_m"] = [float(x) for x in np.array(e["position_ecef_m"]) + dp]
                e["velocity_ecef_m_s"] = [float(x) for x in np.array(e["velocity_ecef_m_s"]) + dv]
        if block not in block_bias:
            block_bias[block] = g.normal(0, 1, 3) * np.asarray(sb, float) if sb is not None else np.zeros(3)
        for s in im["attitude"]:
            key = (block, s["time_s"])
            if key not in pass_att:
                pass_att[key] = g.normal(0, 1, 3) * sa
            d = pass_att[key] + block_bias[block]
            s["roll_deg"] += float(d[0])
            s["pitch_deg"] += float(d[1])
            s["yaw_deg"] += float(d[2])
    noisy = [{**ob, "line": ob["line"] + float(g.normal(0, ob["sigma_px"])),
              "column": ob["column"] + float(g.normal(0, ob["sigma_px"]))} for ob in obs]
    return doc, noisy


def direct_georeferencing(base: dict[str, Any], points: list[dict], obs: list[dict], runs: int,
                          seed: int = 100, attitude_white: bool = True) -> dict[str, Any]:
    """``runs`` adjustments of the fragment ``base`` (without ``sensor_metadata``) with the
    points and observations, each perturbed by :func:`perturbed`: the check points' 3-D RMSE per
    run (empirical and predicted by the report), the ratio of their RMS over the runs, and the
    ratio's sampling spread (one standard deviation, from the runs' scatter of empirical /
    predicted mean square: ``std / (2 sqrt(runs))``, relative)."""
    from solver.api import run

    emp, pred = [], []
    for k in range(runs):
        doc, noisy = perturbed(base, obs, np.random.default_rng(seed + k), attitude_white)
        cp = run({"schema_version": "1.0", "name": "mc", "crs": "EPSG:4326", **doc, "points": points,
                  "observations": noisy})["checkpoints"]
        emp.append(cp["rmse_m"]["3d"])
        pred.append(cp["predicted_rmse_m"]["3d"])
    emp_a, pred_a = np.array(emp), np.array(pred)
    ms = np.mean(emp_a**2) / np.mean(pred_a**2)
    spread = float(np.std(emp_a**2 / pred_a**2, ddof=1) / np.mean(emp_a**2 / pred_a**2) / (2 * np.sqrt(runs)))
    return {"ratio": float(np.sqrt(ms)), "empirical_m": float(np.sqrt(np.mean(emp_a**2))),
            "predicted_m": float(np.sqrt(np.mean(pred_a**2))), "spread": spread, "runs": runs,
            "empirical_runs_m": emp, "predicted_runs_m": pred}
