"""The job without rejected observations (the re-adjustment after data snooping).

An image point is removed from ``observations``; a control point's survey is removed by
turning the point into a tie point (its image points stay). A tie point left with fewer than
two image points cannot be intersected: its last image point goes too (``collateral``).
"""

from __future__ import annotations

from solver.schema.job import Job


def remove(job: Job, removals: list[tuple]) -> tuple[Job, list[dict]]:
    """``job`` without ``removals`` (each ``("observation", index in job.observations)`` or
    ``("control", index in job.points)``); also the image points removed as collateral."""
    drop_obs = {i for kind, i in removals if kind == "observation"}
    demote = {i for kind, i in removals if kind == "control"}
    points = []
    for k, p in enumerate(job.points):
        if k in demote:
            p = p.model_copy(update={"role": "tie", "coordinates": None, "sigma_m": None, "crs": None})
        points.append(p)
    kept = [(k, o) for k, o in enumerate(job.observations) if k not in drop_obs]
    roles = {p.id: p.role for p in points}
    count: dict[str, int] = {}
    for _k, o in kept:
        count[o.point] = count.get(o.point, 0) + 1
    collateral = [{"image": o.image, "point": o.point} for _k, o in kept if roles.get(o.point) == "tie" and count[o.point] < 2]
    kept = [(k, o) for k, o in kept if not (roles.get(o.point) == "tie" and count[o.point] < 2)]
    used = {o.point for _k, o in kept}
    points = [p for p in points if p.role != "tie" or p.id in used]
    return job.model_copy(update={"points": points, "observations": [o for _k, o in kept]}), collateral
