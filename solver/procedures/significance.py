"""Significance analysis of the interior orientation (``options.self_calibration.significance_analysis``;
seed 001 Figure 14): drop, one at a time, the weakest interior-orientation parameter and
re-adjust (docs/models.md)."""

from __future__ import annotations

from typing import Any

from solver.procedures.single import Adjust
from solver.schema.job import Job


def significance_analysis(job: Job, adjust: Adjust, progress) -> dict[str, Any]:
    """Seed 001 Figure 14: adjust, drop the interior-orientation parameter whose |estimate| is
    smallest relative to its sigma if it is below its sigma, re-adjust; repeat. Every step is
    reported; the final report is that of the last adjustment (``adjust``: the adjustment with
    the analysis off)."""
    sc = job.options.self_calibration
    exclude = list(sc.exclude)
    steps = []
    report: dict[str, Any] = {}
    for step in range(200):
        lo = 1.0 - 0.5**step
        hi = 1.0 - 0.5 ** (step + 1)
        j = job.model_copy(
            update={"options": job.options.model_copy(update={"self_calibration": sc.model_copy(update={"exclude": list(exclude), "significance_analysis": False})})}
        )
        report = adjust(j, (lo, hi))
        weak = [
            (abs(p["value"]) / p["sigma"], cam["id"], p)
            for cam in report["cameras"]
            for p in cam["parameters"]
            if p["estimated"] and p["sigma"] and abs(p["value"]) < sc.significance_threshold * p["sigma"]
        ]
        cp = report["checkpoints"]["rmse_m"]
        entry = {
            "step": step,
            "sigma0": report["adjustment"]["sigma0_aposteriori"],
            "n_iop": sum(p["estimated"] for c in report["cameras"] for p in c["parameters"]),
            "check_rmse_m": cp,
            "dropped": None,
        }
        steps.append(entry)
        if not weak:
            break
        ratio, cam_id, p = min(weak, key=lambda w: w[0])
        entry["dropped"] = {"name": f"{cam_id}/{p['name']}", "value": p["value"], "sigma": p["sigma"], "ratio": ratio}
        exclude.append(f"{cam_id}/{p['name']}")
    report["parameter_analysis"] = {
        "rule": f"drop, one at a time, the parameter with the smallest |estimate|/sigma while below {sc.significance_threshold:g}",
        "steps": steps,
        "dropped": [s["dropped"]["name"] for s in steps if s["dropped"]],
        "correlated_pairs": [p for p in report["correlations"]["pairs"] if "IOP" in p.get("kinds", "")],
    }
    if progress is not None:
        progress(1.0, "significance analysis done", {})
    return report
