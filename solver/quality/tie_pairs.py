"""Tie points per image pair after data snooping (``quality.tie_pairs``; docs/report-contract.md).

For every pair of images that share tie points, in the job's image order: the tie points
measured in both images (``found``), those whose two image points both stay in the final
adjustment (``kept``) and those with one or both removed by data snooping (``removed``:
found = kept + removed). A tie point seen in three images counts in each of its three pairs.
With matched tie points (``pba match``) this says how many false matches survived the matching
and where: a pair with many removals had a repeated pattern or a poor search band.
"""

from __future__ import annotations

from typing import Any

from solver.schema.job import Job


def tie_pairs(job: Job, observations: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``[{"images": [a, b], "found", "kept", "removed"}]`` of ``job`` (the job before snooping),
    given the report's ``observations`` (entries with ``"rejected": true`` are the image points
    snooping removed)."""
    order = {im.id: k for k, im in enumerate(job.images)}
    ties = {p.id for p in job.points if p.role == "tie"}
    images_of: dict[str, set[str]] = {}
    for o in job.observations:
        if o.point in ties:
            images_of.setdefault(o.point, set()).add(o.image)
    rejected = {(o.get("image"), o.get("point")) for o in observations if o.get("rejected")}
    counts: dict[tuple[str, str], list[int]] = {}
    for point, images in images_of.items():
        ranked = sorted(images, key=order.__getitem__)
        for i, a in enumerate(ranked):
            for b in ranked[i + 1:]:
                row = counts.setdefault((a, b), [0, 0])
                row[0] += 1
                if (a, point) in rejected or (b, point) in rejected:
                    row[1] += 1
    return [
        {"images": [a, b], "found": found, "kept": found - removed, "removed": removed}
        for (a, b), (found, removed) in sorted(counts.items(), key=lambda kv: (order[kv[0][0]], order[kv[0][1]]))
    ]
