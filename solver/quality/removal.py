"""The job without rejected observations (the re-adjustment after data snooping).

An image point is removed from ``observations``; a control point's survey is removed by
turning the point into a tie point (its image points stay); an observation family's
observations are removed by the family (``without``, :mod:`solver.observations.registry`). A tie point left with fewer than
two image points cannot be intersected: its last image point goes too (``collateral``).
"""

from __future__ import annotations

from dataclasses import dataclass

from solver.observations import registry
from solver.schema.job import ImageObservation, Job


@dataclass
class Candidate:
    """A removed image point (``obs``: its measurement) or control point's survey (``obs``
    None), of ``point``: what the reinstatement puts back (:func:`with_candidates`, :func:`reinstate`)."""

    kind: str  # image_point | control_point
    obs: ImageObservation | None
    point: str


def remove(job: Job, removals: list[tuple]) -> tuple[Job, list[dict]]:
    """``job`` without ``removals``: the core's ``("observation", index in job.observations)``
    and ``("control", index in job.points)``, and the observation families' own (each family's
    ``without``, in the registry's order: ``("line_point", line, image, k)``,
    ``("attitude_sample", image, time_s)``, ``("state_prior", image)``,
    ``("pass_sample", pass image ids, time_s)``, ...); also the image points (and a family's
    observations, e.g. line images) removed as collateral."""
    family_collateral: list[dict] = []
    for family in registry.FAMILIES:
        job, gone = family.without(job, removals)
        family_collateral += gone
    drop_obs = {r[1] for r in removals if r[0] == "observation"}
    demote = {r[1] for r in removals if r[0] == "control"}
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
    return job.model_copy(update={"points": points, "observations": [o for _k, o in kept]}), collateral + family_collateral


# candidates are put back with their sigmas times this: their weight (1e-6) leaves the solution
# that of the job without them (a 30-px blunder moves it by ~1e-5 px), while their residuals
# and cofactors give the tests of observations outside the adjustment (snooping.predicted_tests)
INFLATE = 1e3


def _rays(job: Job) -> dict[str, int]:
    count: dict[str, int] = {}
    for o in job.observations:
        count[o.point] = count.get(o.point, 0) + 1
    return count


def testable(current: Job, item: Candidate) -> bool:
    """Whether a removed observation (``item``: kind, obs, point) can be predicted from the
    adjustment of ``current``: its ground point must be determined without it (a control point
    in ``current``, or a tie point with two rays; a survey: its point with two rays)."""
    points = {p.id: p for p in current.points}
    p = points.get(item.point)
    if p is None:
        return False
    rays = _rays(current).get(item.point, 0)
    if item.kind == "image_point":
        return p.role == "gcp" or (p.role == "tie" and rays >= 2)
    return p.role == "tie" and rays >= 2


def whole_points(current: Job, items: list[Candidate]) -> set[str]:
    """Points that ``current`` no longer has and whose removed observations among ``items``
    determine them on their own (two rays, or a survey and a ray): those observations are
    tested together, against the final orientation (``snooping.predicted_test``, ``whole``)."""
    present = {p.id for p in current.points}
    rays: dict[str, int] = {}
    survey: set[str] = set()
    for it in items:
        if it.point in present:
            continue
        if it.kind == "image_point":
            rays[it.point] = rays.get(it.point, 0) + 1
        else:
            survey.add(it.point)
    return {p for p, n in rays.items() if n >= 2 or (n >= 1 and p in survey)}


def with_candidates(current: Job, original: Job, items: list[Candidate]) -> Job:
    """``current`` with the removed observations ``items`` put back with inflated sigmas
    (``INFLATE``): image points appended to ``observations`` (in the order of ``items``), a
    control point's survey restored from ``original``."""
    orig_points = {p.id: p for p in original.points}
    surveys = {it.point for it in items if it.kind == "control_point"}
    present = {p.id for p in current.points}
    gone = [orig_points[pid] for pid in dict.fromkeys(it.point for it in items) if pid not in present]
    points = []
    for p in list(current.points) + gone:
        if p.id in surveys:
            q = orig_points[p.id]
            p = q.model_copy(update={"sigma_m": tuple(s * INFLATE for s in q.sigma_m)})
        elif p.id not in present and p.role == "gcp":  # its survey is not a candidate: a tie point
            p = p.model_copy(update={"role": "tie", "coordinates": None, "sigma_m": None, "crs": None})
        points.append(p)
    obs = list(current.observations) + [
        it.obs.reweighted(it.obs.sigma_px * INFLATE) for it in items if it.kind == "image_point"
    ]
    return current.model_copy(update={"points": points, "observations": obs})


def reinstate(current: Job, original: Job, items: list[Candidate]) -> Job:
    """``current`` with ``items`` back as they were measured."""
    orig_points = {p.id: p for p in original.points}
    surveys = {it.point for it in items if it.kind == "control_point"}
    present = {p.id for p in current.points}
    points = [orig_points[p.id] if p.id in surveys else p for p in current.points]
    for pid in dict.fromkeys(it.point for it in items):
        if pid not in present:
            p = orig_points[pid]
            if p.role == "gcp" and pid not in surveys:
                p = p.model_copy(update={"role": "tie", "coordinates": None, "sigma_m": None, "crs": None})
            points.append(p)
    obs = list(current.observations) + [it.obs for it in items if it.kind == "image_point"]
    return current.model_copy(update={"points": points, "observations": obs})
