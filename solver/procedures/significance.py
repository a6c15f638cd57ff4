"""Significance analysis of the interior orientation (``options.self_calibration.significance_analysis``;
seed 001 Figure 14): drop, one at a time, the weakest interior-orientation parameter and
re-adjust (docs/models.md)."""

from __future__ import annotations

from typing import Any

from solver.engine.validate import ValidatedJob, job_of
from solver.procedures.single import Adjust
from solver.report.solution import Solution
from solver.schema.job import Job
from solver.schema.settings import JobSettings


def significance_analysis(job: Job | ValidatedJob, adjust: Adjust, progress) -> Solution:
    """Seed 001 Figure 14: adjust, drop the interior-orientation parameter whose |estimate| is
    smallest relative to its sigma if it is below its sigma, re-adjust; repeat. Every step is
    reported; the final report is that of the last adjustment (``adjust``: the adjustment with
    the analysis off)."""
    job = job_of(job)
    sc = JobSettings.from_options(job.options).blocks.self_calibration
    exclude = list(sc.exclude)
    steps = []
    dropped: list[str] = []
    solution: Solution | None = None
    for step in range(200):
        lo = 1.0 - 0.5**step
        hi = 1.0 - 0.5 ** (step + 1)
        j = job.model_copy(
            update={"options": job.options.model_copy(update={"self_calibration": sc.model_copy(update={"exclude": list(exclude), "significance_analysis": False})})}
        )
        solution = adjust(j, (lo, hi))
        cameras = solution.cameras()
        weak = [
            (abs(p.value) / p.sigma, cam.id, p)
            for cam in cameras
            for p in cam.parameters
            if p.estimated and p.sigma and abs(p.value) < sc.significance_threshold * p.sigma
        ]
        entry: dict[str, Any] = {
            "step": step,
            "sigma0": solution.sigma0,
            "n_iop": sum(p.estimated for c in cameras for p in c.parameters),
            "check_rmse_m": solution.check_rmse_m(),
            "dropped": None,
        }
        steps.append(entry)
        if not weak:
            break
        ratio, cam_id, p = min(weak, key=lambda w: w[0])
        entry["dropped"] = {"name": f"{cam_id}/{p.name}", "value": p.value, "sigma": p.sigma, "ratio": ratio}
        dropped.append(f"{cam_id}/{p.name}")
        exclude.append(f"{cam_id}/{p.name}")
    solution.set_section("parameter_analysis", {
        "rule": f"drop, one at a time, the parameter with the smallest |estimate|/sigma while below {sc.significance_threshold:g}",
        "steps": steps,
        "dropped": dropped,
        "correlated_pairs": solution.interior_correlations(),
    })
    if progress is not None:
        progress(1.0, "significance analysis done", {})
    return solution
