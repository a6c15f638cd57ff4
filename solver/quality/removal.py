"""The job without rejected observations (the re-adjustment after data snooping).

An image point is removed from ``observations``; a control point's survey is removed by
turning the point into a tie point (its image points stay). A tie point left with fewer than
two image points cannot be intersected: its last image point goes too (``collateral``).
"""

from __future__ import annotations

from solver.schema.job import Job


def _without_line_points(job: Job, removals: list[tuple]) -> tuple[Job, list[dict]]:
    """``job`` without the line image points ``("line_point", line id, image id, k)`` (k: the
    index in that image's ``points``; None: the fitted image line as a whole); a line image left
    with fewer than two points goes as a whole (collateral)."""
    drop: dict[tuple[str, str], set] = {}
    for r in removals:
        if r[0] == "line_point":
            drop.setdefault((r[1], r[2]), set()).add(r[3])
    if not drop:
        return job, []
    lines, collateral = [], []
    for gl in job.lines:
        obs = []
        for lo in gl.observations:
            gone = drop.get((gl.id, lo.image), set())
            if None in gone:
                continue
            if gone:
                pts = [q for k, q in enumerate(lo.points) if k not in gone]
                if len(pts) < 2:
                    collateral.append({"kind": "line_point", "line": gl.id, "image": lo.image, "point": None})
                    continue
                lo = lo.model_copy(update={"points": pts})
            obs.append(lo)
        lines.append(gl.model_copy(update={"observations": obs}))
    return job.model_copy(update={"lines": lines}), collateral


def _without_attitude_samples(job: Job, removals: list[tuple]) -> Job:
    """``job`` without the attitude samples ``("attitude_sample", image id, time_s)``: the sample
    of that image at that epoch, and the same sample (epoch and angles) in the images sharing it."""
    gone = [(r[1], r[2]) for r in removals if r[0] == "attitude_sample"]
    if not gone:
        return job
    images = {im.id: im for im in job.images}
    drop = set()
    for image, t in gone:
        for s in images[image].attitude:
            if abs(s.time_s - t) < 1e-9:
                drop.add((s.time_s, s.roll_deg, s.pitch_deg, s.yaw_deg))
    new = [
        im.model_copy(update={"attitude": [s for s in im.attitude if (s.time_s, s.roll_deg, s.pitch_deg, s.yaw_deg) not in drop]})
        for im in job.images
    ]
    return job.model_copy(update={"images": new})


def _without_state_priors(job: Job, removals: list[tuple]) -> Job:
    """``job`` without the weighted line-0 state of the images ``("state_prior", image id)``: the
    state the solver used (header or interpolated ephemeris) stays as the image's unweighted
    ``approx_state`` (it still initialises the model), its ephemeris goes."""
    from solver.observations.ephemeris import image_state

    samples = [(set(r[1]), r[2]) for r in removals if r[0] == "pass_sample"]
    if samples:  # a pass's ephemeris sample: from every image of the pass that carries it
        images = []
        for im in job.images:
            drop = [t for ids, t in samples if im.id in ids]
            if drop:
                im = im.model_copy(update={"ephemeris": [sv for sv in im.ephemeris if all(abs(sv.time_s - t) > 1e-6 for t in drop)]})
            images.append(im)
        job = job.model_copy(update={"images": images})
    gone = {r[1] for r in removals if r[0] == "state_prior"}
    if not gone:
        return job
    images = []
    for im in job.images:
        if im.id in gone:
            state = image_state(im, job.options)
            state = state.model_copy(update={"sigma_position_m": None, "sigma_velocity_m_s": None})
            im = im.model_copy(update={"approx_state": state, "ephemeris": []})
        images.append(im)
    return job.model_copy(update={"images": images})


def remove(job: Job, removals: list[tuple]) -> tuple[Job, list[dict]]:
    """``job`` without ``removals`` (each ``("observation", index in job.observations)``,
    ``("control", index in job.points)``, ``("line_point", line, image, k)``,
    ``("attitude_sample", image, time_s)``, ``("state_prior", image)`` or
    ``("pass_sample", pass image ids, time_s)``); also the image points (and line images) removed
    as collateral."""
    job, line_collateral = _without_line_points(job, removals)
    job = _without_attitude_samples(job, removals)
    job = _without_state_priors(job, removals)
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
    return job.model_copy(update={"points": points, "observations": [o for _k, o in kept]}), collateral + line_collateral


# candidates are put back with their sigmas times this: their weight (1e-6) leaves the solution
# that of the job without them (a 30-px blunder moves it by ~1e-5 px), while their residuals
# and cofactors give the tests of observations outside the adjustment (snooping.predicted_tests)
INFLATE = 1e3


def _rays(job: Job) -> dict[str, int]:
    count: dict[str, int] = {}
    for o in job.observations:
        count[o.point] = count.get(o.point, 0) + 1
    return count


def testable(current: Job, item: dict) -> bool:
    """Whether a removed observation (``item``: kind, obs, point) can be predicted from the
    adjustment of ``current``: its ground point must be determined without it (a control point
    in ``current``, or a tie point with two rays; a survey: its point with two rays)."""
    points = {p.id: p for p in current.points}
    p = points.get(item["point"])
    if p is None:
        return False
    rays = _rays(current).get(item["point"], 0)
    if item["kind"] == "image_point":
        return p.role == "gcp" or (p.role == "tie" and rays >= 2)
    return p.role == "tie" and rays >= 2


def whole_points(current: Job, items: list[dict]) -> set[str]:
    """Points that ``current`` no longer has and whose removed observations among ``items``
    determine them on their own (two rays, or a survey and a ray): those observations are
    tested together, against the final orientation (``snooping.predicted_test``, ``whole``)."""
    present = {p.id for p in current.points}
    rays: dict[str, int] = {}
    survey: set[str] = set()
    for it in items:
        if it["point"] in present:
            continue
        if it["kind"] == "image_point":
            rays[it["point"]] = rays.get(it["point"], 0) + 1
        else:
            survey.add(it["point"])
    return {p for p, n in rays.items() if n >= 2 or (n >= 1 and p in survey)}


def with_candidates(current: Job, original: Job, items: list[dict]) -> Job:
    """``current`` with the removed observations ``items`` put back with inflated sigmas
    (``INFLATE``): image points appended to ``observations`` (in the order of ``items``), a
    control point's survey restored from ``original``."""
    orig_points = {p.id: p for p in original.points}
    surveys = {it["point"] for it in items if it["kind"] == "control_point"}
    present = {p.id for p in current.points}
    gone = [orig_points[pid] for pid in dict.fromkeys(it["point"] for it in items) if pid not in present]
    points = []
    for p in list(current.points) + gone:
        if p.id in surveys:
            q = orig_points[p.id]
            p = q.model_copy(update={"sigma_m": tuple(s * INFLATE for s in q.sigma_m)})
        elif p.id not in present and p.role == "gcp":  # its survey is not a candidate: a tie point
            p = p.model_copy(update={"role": "tie", "coordinates": None, "sigma_m": None, "crs": None})
        points.append(p)
    obs = list(current.observations) + [
        it["obs"].model_copy(update={"sigma_px": it["obs"].sigma_px * INFLATE}) for it in items if it["kind"] == "image_point"
    ]
    return current.model_copy(update={"points": points, "observations": obs})


def reinstate(current: Job, original: Job, items: list[dict]) -> Job:
    """``current`` with ``items`` back as they were measured."""
    orig_points = {p.id: p for p in original.points}
    surveys = {it["point"] for it in items if it["kind"] == "control_point"}
    present = {p.id for p in current.points}
    points = [orig_points[p.id] if p.id in surveys else p for p in current.points]
    for pid in dict.fromkeys(it["point"] for it in items):
        if pid not in present:
            p = orig_points[pid]
            if p.role == "gcp" and pid not in surveys:
                p = p.model_copy(update={"role": "tie", "coordinates": None, "sigma_m": None, "crs": None})
            points.append(p)
    obs = list(current.observations) + [it["obs"] for it in items if it["kind"] == "image_point"]
    return current.model_copy(update={"points": points, "observations": obs})
