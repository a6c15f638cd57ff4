"""Dry-run checks of a job: references, models, CRSs, image bounds, counts and degrees of freedom.

Cheap and free of numerical libraries beyond numpy/pyproj, so a server can call it in its own
process. Every problem found is reported at once, each with its location in the document.
The numerical rank check (which parameters the control geometry leaves undetermined) needs the
linearised problem and runs at the start of the adjustment (:mod:`solver.adjust`).
"""

from __future__ import annotations

import hashlib
from collections import Counter, defaultdict
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from pyproj.exceptions import ProjError

from solver.blocks import registry as blocks
from solver.blocks.platform import image_problems
from solver.errors import JobError, Problem
from solver.geometry.geodesy import UnknownCRSError, ecef_to_geodetic, parse_crs, to_ecef
from solver.geometry.sensor import camera_chip, chip_indices, in_image_columns
from solver.observations import registry
from solver.observations.ephemeris import image_state
from solver.platforms import get_model
from solver.schema.job import MAX_COMPARED_MODELS, Camera, ImageObservation, Job
from solver.schema.settings import JobSettings

# ellipsoidal heights of ground points: the deepest ocean trench to far above any aircraft
MIN_HEIGHT_M = -5e4
MAX_HEIGHT_M = 2e5


def _duplicates(items: list[Any], what: str, key: str) -> list[Problem]:
    counts = Counter(getattr(x, "id") for x in items)
    return [
        Problem("duplicate_id", f"{what} id {i!r} is used {n} times", (key,))
        for i, n in counts.items()
        if n > 1
    ]


def _duplicate_chips(cam: Camera, i: int) -> list[Problem]:
    """Chip ids must be unique within a camera (observations and IOP names refer to them).
    Chips may overlap and extend beyond the image (butted CCDs, :mod:`solver.geometry.sensor`)."""
    counts = Counter(c.id for c in cam.chips)
    return [
        Problem("duplicate_id", f"camera {cam.id!r}: chip id {c!r} is used {n} times", ("cameras", i, "chips"))
        for c, n in counts.items()
        if n > 1
    ]


def _column_problems(cam: Camera, o: ImageObservation, k: int) -> list[Problem]:
    """The observation's column in the delivered image, on its named chip or on some chip."""
    loc = ("observations", k)
    what = f"observation {k} ({o.point!r} in {o.image!r})"
    ncols = cam.columns or 0
    if not in_image_columns(cam, o.column):
        return [Problem("outside_image", f"{what}: column {o.column} is outside 0..{ncols - 1}", loc + ("column",))]
    ids = [c.id for c in cam.chips] if cam.chips else ["1"]
    if o.chip is not None and o.chip not in ids:
        return [Problem("unknown_chip", f"{what}: camera {cam.id!r} has no chip {o.chip!r} (chips: {', '.join(ids)})", loc + ("chip",))]
    try:
        camera_chip(cam, o.column, o.chip)
    except KeyError:
        if o.chip is not None:
            c = cam.chips[ids.index(o.chip)]
            msg = f"{what}: column {o.column} is not on chip {o.chip!r} (columns {c.first_column}..{c.first_column + c.columns - 1})"
            return [Problem("outside_chip", msg, loc + ("column",))]
        return [Problem("outside_image", f"{what}: column {o.column} is on no CCD chip of camera {cam.id!r}", loc + ("column",))]
    return []

def coordinate_problems(job: Job) -> list[Problem]:
    """Ground coordinates (points and line endpoints) that do not transform to ECEF or are not
    near the Earth's surface (ellipsoidal height outside MIN_HEIGHT_M..MAX_HEIGHT_M); a CRS
    whose transformation cannot be built (a missing geoid grid) is reported at the CRS."""
    by_crs: dict[str, list[tuple[tuple, tuple]]] = {}
    for j, p in enumerate(job.points):
        if p.coordinates is not None:
            by_crs.setdefault(p.crs or job.crs, []).append((("points", j, "coordinates"), p.coordinates))
    for k, gl in enumerate(job.lines):
        for e, xyz in enumerate(gl.endpoints):
            by_crs.setdefault(gl.crs or job.crs, []).append((("lines", k, "endpoints", e), xyz))
    out: list[Problem] = []
    for crs, items in by_crs.items():
        try:
            parse_crs(crs)
        except UnknownCRSError:
            continue  # reported as unknown_crs
        xyz = np.array([c for _, c in items], dtype=float)
        try:
            ecef = _ecef_rows(xyz, crs)
        except ProjError as exc:
            where = next((loc[:2] + ("crs",) for loc, _ in items if _crs_of(job, loc)), ("crs",))
            out.append(Problem("unusable_crs", f"CRS {crs!r} cannot be used: {exc}", where))
            continue
        h = np.full(len(items), np.nan)
        ok = np.all(np.isfinite(ecef), axis=1)
        if ok.any():
            h[ok] = ecef_to_geodetic(ecef[ok])[:, 2]
        for (loc, c), hq in zip(items, h):
            if not np.isfinite(hq):
                out.append(Problem("invalid_coordinates", f"coordinates {list(c)} cannot be transformed from {crs!r}", loc))
            elif not MIN_HEIGHT_M <= hq <= MAX_HEIGHT_M:
                out.append(
                    Problem(
                        "invalid_coordinates",
                        f"coordinates {list(c)} in {crs!r} are {hq:.6g} m from the ellipsoid: not a "
                        "ground point (check the CRS and the x/y order)",
                        loc,
                    )
                )
    return out


def _crs_of(job: Job, loc: tuple) -> str | None:
    return job.points[loc[1]].crs if loc[0] == "points" else job.lines[loc[1]].crs


def _ecef_rows(xyz: np.ndarray, crs: str) -> np.ndarray:
    """ECEF of each row (NaN rows where the transformation fails)."""
    try:
        return to_ecef(xyz, crs)
    except UnknownCRSError:  # some rows are out of the CRS's domain: find them
        rows = []
        for row in xyz:
            try:
                rows.append(to_ecef(row[None, :], crs)[0])
            except UnknownCRSError:
                rows.append(np.full(3, np.nan))
        return np.array(rows)


def comparison_problems(models: list[str], location: tuple[str | int, ...]) -> list[Problem]:
    """Problems of a list of models to compare (``location`` is where the list is): none, more
    than MAX_COMPARED_MODELS, unknown names, or one model named twice (aliases included)."""
    if not models:
        return [Problem("no_models", "a model comparison needs at least one model", location)]
    if len(models) > MAX_COMPARED_MODELS:
        return [
            Problem(
                "too_many_models",
                f"{len(models)} models to compare; at most {MAX_COMPARED_MODELS}",
                location,
            )
        ]
    out: list[Problem] = []
    seen: dict[str, int] = {}
    for i, name in enumerate(models):
        try:
            model = get_model(name)
        except KeyError as exc:
            out.append(Problem("unknown_model", str(exc.args[0]), (*location, i)))
            continue
        if model.name in seen:
            out.append(
                Problem(
                    "duplicate_model",
                    f"{name!r} is the model {model.name} already listed at position {seen[model.name]}",
                    (*location, i),
                )
            )
        seen.setdefault(model.name, i)
    return out


def _camera_problems(job: Job) -> list[Problem]:
    """Cameras still naming a library camera, and duplicate chips."""
    problems: list[Problem] = []
    for i, cam in enumerate(job.cameras):
        if cam.focal_mm is None:
            problems.append(
                Problem(
                    "camera_ref_unresolved",
                    f"camera {cam.id!r} refers to library camera {cam.ref.name!r} "  # type: ignore[union-attr]
                    "which must be resolved by the server before solving (pba job --camera NAME "
                    "writes a sensor preset's values into the job)",
                    ("cameras", i, "ref"),
                )
            )
            continue
        problems += _duplicate_chips(cam, i)
    return problems


def _image_problems(job: Job, cameras: dict[str, Camera]) -> tuple[list[Problem], int, list[dict[str, Any]]]:
    """Each image's model, options, initial values and initial position (the platform blocks'
    checks, :func:`solver.blocks.platform.image_problems`): (problems, unknowns of the images'
    own parameters, the per-image summary of the counts)."""
    problems: list[Problem] = []
    n_unknowns = 0
    image_info = []
    settings = JobSettings.of(job)
    for i, im in enumerate(job.images):
        issues, model, n_params = image_problems(job, i, cameras, lambda im=im: image_state(im, settings.blocks.ephemeris))
        problems += issues
        if n_params is not None:
            n_unknowns += n_params
            image_info.append({"id": im.id, "model": model.name, "n_parameters": n_params})
    return problems, n_unknowns, image_info


def _crs_problems(job: Job) -> list[Problem]:
    """Coordinate reference systems of the points that PROJ does not understand (once per CRS)."""
    problems: list[Problem] = []
    crs_checked: dict[str, bool] = {}
    for j, p in enumerate(job.points):
        crs = p.crs or job.crs
        if crs not in crs_checked:
            try:
                parse_crs(crs)
                crs_checked[crs] = True
            except UnknownCRSError as exc:
                crs_checked[crs] = False
                problems.append(Problem("unknown_crs", str(exc), ("points", j, "crs") if p.crs else ("crs",)))
    return problems


def _columns_on_chips(job: Job, images: dict, cameras: dict) -> np.ndarray:
    """Per observation: True where its column is on a chip of its image's camera (the rule of
    :func:`solver.geometry.sensor.camera_chip`, all observations of a camera at once); only the
    others go through :func:`_column_problems` for their located message."""
    by_camera: dict[str, list[int]] = defaultdict(list)
    for k, o in enumerate(job.observations):
        im = images.get(o.image)
        if im is not None and im.camera in cameras:
            by_camera[im.camera].append(k)
    on_chip = np.zeros(len(job.observations), dtype=bool)
    for cam_id, ks in by_camera.items():
        obs = [job.observations[k] for k in ks]
        found = chip_indices(cameras[cam_id], np.array([o.column for o in obs], dtype=float), [o.chip for o in obs])
        on_chip[ks] = found >= 0
    return on_chip


def _observation_problems(job: Job, cameras: dict[str, Camera]) -> tuple[list[Problem], dict[str, int], Counter[str]]:
    """References, duplicates and image bounds of the image points: (problems, the number of
    images that see each point, the adjusted observations per image).

    Array passes over all observations; only the observations with a problem get a message
    (the problems come out in the order of the observations, as a sequential check gives them:
    a measurement repeated in one image is reported from its second occurrence on, even when the
    first one is outside the image)."""
    observations = job.observations
    n = len(observations)
    image_pos = {im.id: i for i, im in enumerate(job.images)}
    point_pos = {p.id: j for j, p in enumerate(job.points)}
    ii = np.fromiter((image_pos.get(o.image, -1) for o in observations), dtype=np.int64, count=n)
    pp = np.fromiter((point_pos.get(o.point, -1) for o in observations), dtype=np.int64, count=n)
    found: list[tuple[int, int, Problem]] = []  # (observation, order within it, problem)
    for k in np.flatnonzero(ii < 0).tolist():
        o = observations[k]
        found.append((k, 0, Problem("unknown_image", f"observation {k} refers to unknown image {o.image!r}", ("observations", k, "image"))))
    for k in np.flatnonzero(pp < 0).tolist():
        o = observations[k]
        found.append((k, 1, Problem("unknown_point", f"observation {k} refers to unknown point {o.point!r}", ("observations", k, "point"))))
    valid = (ii >= 0) & (pp >= 0)
    pair = ii * max(len(job.points), 1) + pp
    first = np.full(n, -1, dtype=np.int64)
    vk = np.flatnonzero(valid)
    if len(vk):
        _, first_at, inverse = np.unique(pair[vk], return_index=True, return_inverse=True)
        first[vk] = vk[first_at][inverse.ravel()]
    duplicate = valid & (first != np.arange(n))
    for k in np.flatnonzero(duplicate).tolist():
        o = observations[k]
        found.append((k, 0, Problem("duplicate_observation", f"point {o.point!r} is measured twice in image {o.image!r}", ("observations", k))))
    # bounds: images whose camera says how many lines it has
    cam_of_image = [cameras.get(im.camera) for im in job.images]
    lines_of_image = np.array([c.lines if c is not None and c.lines is not None else np.nan for c in cam_of_image] + [np.nan], dtype=float)
    bounded = valid & ~duplicate & np.isfinite(lines_of_image[ii])
    line = np.fromiter((o.line for o in observations), dtype=float, count=n)
    outside = bounded & ~((line >= -0.5) & (line <= lines_of_image[ii] - 0.5))
    for k in np.flatnonzero(outside).tolist():
        o = observations[k]
        cam = cam_of_image[ii[k]]
        found.append(
            (
                k,
                0,
                Problem(
                    "outside_image",
                    f"observation {k} ({o.point!r} in {o.image!r}): line {o.line} is outside 0..{cam.lines - 1}",
                    ("observations", k, "line"),
                ),
            )
        )
    column_bad = np.zeros(n, dtype=bool)
    on_chip = _columns_on_chips(job, {im.id: im for im in job.images}, cameras)
    for k in np.flatnonzero(bounded & ~outside & ~on_chip).tolist():
        issues = _column_problems(cam_of_image[ii[k]], observations[k], k)
        if issues:
            column_bad[k] = True
            found += [(k, 0, issue) for issue in issues]
    accepted = valid & ~duplicate & ~outside & ~column_bad
    found.sort(key=lambda item: (item[0], item[1]))
    problems = [issue for _, _, issue in found]
    # distinct images per point; adjusted (not check) observations per image
    acc = np.flatnonzero(accepted)
    distinct = np.unique(pair[acc])
    per_point = np.bincount(distinct % max(len(job.points), 1), minlength=len(job.points)) if len(distinct) else np.zeros(len(job.points), dtype=np.int64)
    images_per_point = {job.points[j].id: int(c) for j, c in enumerate(per_point.tolist()) if c}
    not_check = np.array([p.role != "check" for p in job.points] + [False], dtype=bool)
    adjusted = acc[not_check[pp[acc]]]
    per_image = np.bincount(ii[adjusted], minlength=len(job.images)) if len(adjusted) else np.zeros(len(job.images), dtype=np.int64)
    obs_per_image: Counter[str] = Counter({job.images[i].id: int(c) for i, c in enumerate(per_image.tolist()) if c})
    return problems, images_per_point, obs_per_image


def _point_counts(job: Job, images_per_point: dict[str, int]) -> tuple[list[Problem], int, int]:
    """Tie points seen too rarely, and the observations and unknowns of the points:
    (problems, observations, unknowns)."""
    problems: list[Problem] = []
    n_obs = n_unknowns = 0
    weighted = JobSettings.of(job).blocks.control == "weighted"
    for j, p in enumerate(job.points):
        seen = images_per_point.get(p.id, 0)
        if p.role != "check":
            n_obs += 2 * seen
        if p.role == "tie":
            n_unknowns += 3
            if seen < 2:
                problems.append(
                    Problem(
                        "tie_point_underdetermined",
                        f"tie point {p.id!r} is seen in {seen} image(s); it needs at least two",
                        ("points", j),
                    )
                )
        elif p.role == "gcp" and weighted and p.sigma_m is not None:
            n_unknowns += 3
            n_obs += 3
    return problems, n_obs, n_unknowns


def collect_problems(job: Job) -> tuple[list[Problem], dict[str, Any]]:
    """All problems of a job plus the counts (observations, unknowns, dof) when computable."""
    problems: list[Problem] = []
    problems += _duplicates(job.cameras, "camera", "cameras")
    problems += _duplicates(job.images, "image", "images")
    problems += _duplicates(job.points, "point", "points")
    cameras = {c.id: c for c in job.cameras}
    problems += _camera_problems(job)
    image_issues, n_unknowns, image_info = _image_problems(job, cameras)
    problems += image_issues
    problems += _crs_problems(job)
    problems += coordinate_problems(job)
    models = JobSettings.of(job).procedures.models
    if models:
        problems += comparison_problems(list(models), ("options", "models"))
    obs_issues, images_per_point, obs_per_image = _observation_problems(job, cameras)
    problems += obs_issues
    n_obs = 0
    for kind in blocks.BLOCK_KINDS:  # the parameter blocks beyond each image's own (shared, cameras, passes, ...)
        issues, n_kind = kind.check(job)
        problems += issues
        n_unknowns += n_kind
    datum: set[str] = set()  # how the families' observations define the datum (family.Count)
    for family in registry.FAMILIES:
        issues, count = family.check(job)
        problems += issues
        n_obs += count.n_observations
        n_unknowns += count.n_unknowns
        obs_per_image.update(count.per_image)
        datum |= count.datum
    point_issues, n_point_obs, n_point_unknowns = _point_counts(job, images_per_point)
    problems += point_issues
    n_obs += n_point_obs
    n_unknowns += n_point_unknowns
    for i, im in enumerate(job.images):
        if obs_per_image[im.id] == 0:
            problems.append(
                Problem("image_without_observations", f"image {im.id!r} has no control or tie observations", ("images", i))
            )
    # direct georeferencing: weighted platform states and measured attitude define the datum
    # without ground control (whether they fix every parameter is the rank check's to say);
    # observed control lines and RPC images' a-priori bias values define it on their own
    direct = {"states", "attitude"} <= datum or "control" in datum
    if not any(p.role == "gcp" for p in job.points) and not direct:
        problems.append(
            Problem(
                "no_control",
                "the job has no control points (role gcp), no observed control lines and no weighted "
                "platform states with measured attitude (options.ephemeris or approx_state sigmas, "
                "and options.attitude): the datum is undefined",
                ("points",),
            )
        )
    dof = n_obs - n_unknowns
    if dof < 0:
        problems.append(
            Problem(
                "insufficient_observations",
                f"{n_obs} observations for {n_unknowns} unknowns: {-dof} more observation equations "
                "are needed (add control points or choose a model with fewer parameters)",
                ("observations",),
                {"n_observations": n_obs, "n_unknowns": n_unknowns},
            )
        )
    counts = {"n_observations": n_obs, "n_unknowns": n_unknowns, "dof": dof, "images": image_info}
    return problems, counts


def validate_job(job: Job) -> dict[str, Any]:
    """Dry run: ``{"valid", "problems", "n_observations", "n_unknowns", "dof", "images"}``."""
    problems, counts = collect_problems(job)
    return {"valid": not problems, "problems": [p.to_dict() for p in problems], **counts}


# packages whose code decides what a valid job is (the checks, the families', the models', the
# schema's): a validation made elsewhere is taken only when it ran this very code
CHECKING_CODE = ("engine/validate.py", "errors.py", "blocks", "observations", "platforms", "schema", "geometry")


@lru_cache(maxsize=1)
def fingerprint() -> str:
    """SHA-256 of the source of :data:`CHECKING_CODE`: names the code a validation ran."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for part in CHECKING_CODE:
        path = root / part
        for f in sorted([path] if path.is_file() else path.rglob("*.py")):
            digest.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes())
    return digest.hexdigest()


def validation_record(counts: dict[str, Any]) -> dict[str, Any]:
    """What a caller that validated a job hands to whoever solves it later (a server's
    submission to its worker): the counts and the :func:`fingerprint` of the checks."""
    return {"fingerprint": fingerprint(), "counts": counts}


@dataclass(frozen=True)
class ValidatedJob:
    """A job and the counts its validation gave (:func:`collect_problems`): what a caller that
    validated hands to what solves (a server's submission to its worker, a procedure to the
    adjustments it repeats), so the job is not checked again. A changed job is a new
    :class:`~solver.schema.job.Job` and is checked; :meth:`with_job` is for a copy that differs
    only in what validation does not look at (a procedure's own option)."""

    job: Job
    counts: dict[str, Any]

    def with_job(self, job: Job) -> "ValidatedJob":
        return ValidatedJob(job, self.counts)


def record_taken(record: dict[str, Any] | None) -> bool:
    """Whether a validation record (:func:`validation_record`) was made by this code (same fingerprint)."""
    return isinstance(record, dict) and record.get("fingerprint") == fingerprint() and isinstance(record.get("counts"), dict)


def handed(job: Job, record: dict[str, Any] | None) -> "Job | ValidatedJob":
    """``job`` with the counts of ``record`` when the record was made by this code, else ``job``
    as it is (checked when it is solved)."""
    return ValidatedJob(job, record["counts"]) if record_taken(record) else job  # type: ignore[index]


def validated(job: "Job | ValidatedJob") -> ValidatedJob:
    """``job`` validated: a :class:`ValidatedJob` as handed, or a job checked now
    (:class:`JobError` with every problem)."""
    return job if isinstance(job, ValidatedJob) else ValidatedJob(job, require_valid(job))


def job_of(job: "Job | ValidatedJob") -> Job:
    """The job itself, validated or not."""
    return job.job if isinstance(job, ValidatedJob) else job


def require_valid(job: Job) -> dict[str, Any]:
    """Raise :class:`JobError` with every problem, or return the counts."""
    problems, counts = collect_problems(job)
    if problems:
        raise JobError(problems)
    return counts


def planning_problems(job: Job) -> list[Problem]:
    """Planned points without coordinates (a pre-analysis projects every point)."""
    out = [
        Problem(
            "planned_point_without_coordinates",
            f"point {p.id!r}: a pre-analysis needs the planned coordinates of every point",
            ("points", i, "coordinates"),
        )
        for i, p in enumerate(job.points)
        if p.coordinates is None
    ]
    if not job.points:
        out.append(Problem("no_planned_points", "a pre-analysis needs planned points", ("points",)))
    return out
