"""The processes the server offers: one table, one entry per process (what it is, how its
input is checked and counted, how a worker runs it), and their OGC descriptions.

``bundle-adjustment`` adjusts one job (``solver.api.run``); ``model-comparison`` adjusts the
same observations with several platform models (``solver.api.compare``); ``preanalysis``
predicts the precision of a planned block before anything is measured
(``solver.api.preanalyse``); ``match`` finds tie points in the rasters of the job's images
(``solver.matching.run``, docs/matching.md). All take the job document as input ``job`` and
return one output ``report`` (docs/report-contract.md; for ``match`` the tie points).

Nothing outside this module branches on a process id: the routes, the job use cases
(:mod:`service.jobs`) and the worker (:mod:`service.execution`) look the process up in
:data:`PROCESSES` and call its ``count``, ``check`` and ``run``. A new process is one
:class:`Process` entry in :data:`PROCESSES`. The solver is imported inside the functions only
(the API process validates through ``solver.api`` and never loads the adjustment).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import TYPE_CHECKING, Any, Callable, Literal

from pydantic import ValidationError

from service.errors import InvalidInput, NoSuchProcess
from service.problems import job_error_entries, problem_entries, pydantic_errors
from service.schemas import InputDescription, Link, OutputDescription, ProcessDescription
from solver.errors import JobError, Problem
from solver.schema.job import Job

if TYPE_CHECKING:
    from service.schemas import ExecuteInputs
    from service.settings import Settings

BUNDLE_ADJUSTMENT = "bundle-adjustment"
MODEL_COMPARISON = "model-comparison"
PREANALYSIS = "preanalysis"
MATCH = "match"
VERSION = "1.0.0"
JOB_POINTER = ("inputs", "job")
"""Where the job document sits in an execute request (JSON pointers of problems start here)."""

Progress = Callable[..., None]
Cancel = Callable[[], bool]


@dataclass(frozen=True)
class Caller:
    """Who submits, as a process's check needs it: the user's name (their image folder) and
    the server's settings (image root, upload bound)."""

    user_name: str
    settings: Settings


@dataclass(frozen=True)
class Checked:
    """A job accepted by a process's check: the document to store (``{"job": ...}`` plus the
    process's other inputs) and the validation summary (counts, images) answered to clients."""

    document: dict[str, Any]
    summary: dict[str, Any]


@dataclass(frozen=True)
class JobCost:
    """What a job will cost a worker, in the unit its work grows with: ``observations`` for an
    adjustment (and a pre-analysis's planned observations), ``pixels`` (width x height of every
    raster, from their headers) for a matching. The queue's lane comes from it
    (:func:`service.lanes.is_small`)."""

    unit: Literal["observations", "pixels"]
    amount: int


def _cost_by_count(count: Callable[[Job], int]) -> Callable[[Job, dict[str, Any]], JobCost]:
    def cost(job: Job, _document: dict[str, Any]) -> JobCost:
        return JobCost("observations", count(job))

    return cost


@dataclass(frozen=True)
class Process:
    """One process of the table.

    ``count(job)``: the observations the job is measured by against the users' limits.
    ``cost(job, document)``: what the checked job will cost a worker (:class:`JobCost`; the
    queue's lane; default: ``count`` in observations). ``check(job, inputs, caller)``: the job (camera references resolved)
    and the other inputs checked as this process needs them; raises :class:`InvalidInput` with
    pointers into the request. ``run(document, progress, cancel)``: in a worker, the report of
    a stored document (``progress``/``cancel`` as in ``solver.api``); the document is the run's
    to consume: an adjustment takes its ``job`` out and hands it over (``solver.api.Handover``),
    so that the worker does not hold the parsed document for the whole solve. ``tables``: the CSV
    tables of its results (``/jobs/{id}/results/{table}.csv``, service.report_csv).
    """

    id: str
    title: str
    description: str
    report_title: str
    count: Callable[[Job], int]
    check: Callable[[Job, ExecuteInputs, Caller], Checked]
    run: Callable[[dict[str, Any], Progress, Cancel], dict[str, Any]]
    cost: Callable[[Job, dict[str, Any]], JobCost] | None = None
    extra_inputs: Callable[[], dict[str, InputDescription]] = field(default=lambda: {})
    tables: tuple[str, ...] = ("observations", "checkpoints", "parameters")

    def cost_of(self, job: Job, document: dict[str, Any]) -> JobCost:
        """The job's cost (``cost``, else its ``count`` in observations)."""
        return (self.cost or _cost_by_count(self.count))(job, document)


def _problems_error(problems: list[dict[str, Any]], where: tuple[str, ...]) -> InvalidInput:
    """InvalidInput listing solver problem dicts (the first five in the detail)."""
    detail = "; ".join(str(p.get("message", "")) for p in problems[:5]) or "the job is not valid"
    return InvalidInput(detail, problem_entries(problems, where))


def _refuse_models(inputs: ExecuteInputs) -> None:
    """InvalidInput when ``inputs.models`` is given to a process that takes none (or the
    match process's inputs to another process)."""
    if inputs.models:
        raise InvalidInput(
            "models is an input of model-comparison only",
            [
                {
                    "pointer": "/inputs/models",
                    "code": "unexpected",
                    "message": "not an input of this process",
                }
            ],
        )
    _refuse_match_inputs(inputs)


def _refuse_match_inputs(inputs: ExecuteInputs) -> None:
    for name in ("images", "heights_m", "match"):
        if getattr(inputs, name) is not None:
            raise InvalidInput(
                f"{name} is an input of the match process only",
                [{"pointer": f"/inputs/{name}", "code": "unexpected", "message": "not an input of this process"}],
            )


def _job_document(job: Job) -> dict[str, Any]:
    return {"job": job.model_dump(mode="json", exclude_unset=False)}


def _adjustment_summary(job: Job) -> dict[str, Any]:
    """The solver's dry run of an adjustment (counts, degrees of freedom); InvalidInput with
    every problem otherwise."""
    import solver.api

    try:
        summary = solver.api.validate(job)
    except JobError as exc:
        raise InvalidInput(str(exc), job_error_entries(exc, JOB_POINTER)) from None
    except ValidationError as exc:
        raise InvalidInput(
            "the job does not match the schema", pydantic_errors(exc.errors(), JOB_POINTER)
        ) from None
    if not summary.get("valid", False):
        raise _problems_error(summary.get("problems", []), JOB_POINTER)
    return summary


def _observations(job: Job) -> int:
    return len(job.observations)


def _check_adjustment(job: Job, inputs: ExecuteInputs, _caller: Caller) -> Checked:
    """The solver's dry run; its counts are stored with the document (``validation``) and
    handed to the worker, which does not check the job again (solver.api.run)."""
    import solver.api

    _refuse_models(inputs)
    summary = _adjustment_summary(job)
    return Checked({**_job_document(job), "validation": solver.api.validation_record(summary)}, summary)


def _run_adjustment(document: dict[str, Any], progress: Progress, cancel: Cancel) -> dict[str, Any]:
    import solver.api

    # the job is taken out of the worker's document and handed over: the solver frees it once parsed
    return solver.api.run(
        solver.api.Handover(document.pop("job")), progress=progress, cancel=cancel, validated=document.get("validation")
    )


def _compared_models(job: Job, inputs: ExecuteInputs) -> list[str]:
    """The models a comparison compares (``inputs.models``, else the job's options.models),
    checked; InvalidInput pointing at whichever gave them."""
    from solver.engine.validate import comparison_problems  # not solver.compare: that loads the adjustment (numba)

    models = list(inputs.models or job.options.models)
    if not models:
        raise InvalidInput(
            "a model comparison needs the models to compare",
            [
                {
                    "pointer": "/inputs/models",
                    "code": "missing",
                    "message": "give inputs.models or the job's options.models",
                }
            ],
        )
    where = ("inputs", "models") if inputs.models else (*JOB_POINTER, "options", "models")
    problems = [p.to_dict() for p in comparison_problems(models, ())]
    if problems:
        raise _problems_error(problems, where)
    return models


def _check_comparison(job: Job, inputs: ExecuteInputs, _caller: Caller) -> Checked:
    _refuse_match_inputs(inputs)
    models = _compared_models(job, inputs)
    summary = _adjustment_summary(job)
    return Checked({**_job_document(job), "models": models}, summary)


def _run_comparison(document: dict[str, Any], progress: Progress, cancel: Cancel) -> dict[str, Any]:
    import solver.api

    models = document.get("models") or document["job"].get("options", {}).get("models", [])
    return solver.api.compare(
        solver.api.Handover(document.pop("job")), models, progress=progress, cancel=cancel,
        validated=document.get("validation"),
    )


def _comparison_inputs() -> dict[str, InputDescription]:
    return {
        "models": InputDescription(
            title="Platform models",
            description="models to compare (default: the job's options.models)",
            minOccurs=0,
            maxOccurs=1,
            schema={
                "type": "array",
                "minItems": 1,
                "items": {"type": "string", "enum": model_names()},
            },
        )
    }


def _planned_observations(job: Job) -> int:
    """Every planned point may be observed in every image."""
    return len(job.points) * len(job.images)


def _check_preanalysis(job: Job, inputs: ExecuteInputs, _caller: Caller) -> Checked:
    """Planned points carry coordinates and no observations: the adjustment's own checks
    (observations per point, degrees of freedom) do not apply before the planning."""
    import solver.api

    _refuse_models(inputs)
    problems = [p.to_dict() for p in solver.api.preanalysis_problems(job)]
    if problems:
        raise _problems_error(problems, JOB_POINTER)
    summary = {
        "valid": True,
        "problems": [],
        "planned_points": len(job.points),
        "images": [{"id": im.id, "model": im.model.name} for im in job.images],
    }
    return Checked(_job_document(job), summary)


def _run_preanalysis(document: dict[str, Any], progress: Progress, cancel: Cancel) -> dict[str, Any]:
    import solver.api

    return solver.api.preanalyse(document["job"])


def _check_match(job: Job, inputs: ExecuteInputs, caller: Caller) -> Checked:
    """The rasters (service.rasters: inside the caller's image folder, or bounded uploads GDAL
    reads), one per image of the job named; the orientation itself is the worker's to use."""
    from service.rasters import stated_sizes, stored_rasters

    if inputs.models:
        _refuse_models(inputs)
    if not inputs.images:
        raise InvalidInput(
            "the match process needs the rasters of at least two of the job's images",
            [{"pointer": "/inputs/images", "code": "missing", "message": "give inputs.images"}],
        )
    ids = {im.id for im in job.images}
    for k, im in enumerate(inputs.images):
        if im.id not in ids:
            message = f"the job has no image {im.id!r} (its images: {', '.join(sorted(ids))})"
            raise InvalidInput(message, [{"pointer": f"/inputs/images/{k}/id", "code": "unknown_image", "message": message}])
    heights = inputs.heights_m
    if heights is not None and not (math.isfinite(heights[0]) and math.isfinite(heights[1]) and heights[0] < heights[1]):
        message = "heights_m: MIN must be below MAX (ellipsoidal metres)"
        raise InvalidInput(message, [{"pointer": "/inputs/heights_m", "code": "invalid", "message": message}])
    from service.raster_checks import Refusal, pool

    s = caller.settings
    checks = pool(s.raster_check_processes, s.raster_check_timeout_s, s.raster_checks_per_user)

    def run(pointer: str, shown: str, name: str, *args: Any) -> Any:  # outside the request thread, timed
        return checks.run(caller.user_name, Refusal(pointer, shown), name, *args)

    rasters = stored_rasters(inputs.images, s.image_root, caller.user_name, s.max_image_upload_bytes,
                             s.max_upload_pixel_bytes, s.max_raster_pixel_bytes, stated_sizes(job), run)
    document = {
        **_job_document(job),
        "images": rasters,
        "image_root": str(s.image_root) if s.image_root is not None else None,
        "image_folder": caller.user_name,
        "heights_m": list(heights) if heights is not None else None,
        "match": inputs.match.model_dump() if inputs.match is not None else None,
        "max_pixel_bytes": max(s.max_upload_pixel_bytes, s.max_raster_pixel_bytes),
    }
    summary = {"valid": True, "problems": [], "images": [{"id": r["id"], "source": "path" if "path" in r else "upload"} for r in rasters]}
    return Checked(document, summary)


def _match_cost(_job: Job, document: dict[str, Any]) -> JobCost:
    """The pixels of the job's rasters (their headers' width x height, stored at the check):
    a matching's work grows with them, not with the job's observations."""
    return JobCost("pixels", sum(int(r["pixels"]) for r in document["images"]))


def _run_match(document: dict[str, Any], progress: Progress, cancel: Cancel) -> dict[str, Any]:
    """Uploads written to a temporary directory, server paths checked again, then the
    matching (solver.matching.run), every raster opened through the raster gate inside the
    job's space only: the user's image folder and the job's own temporary folder."""
    import base64
    import os
    import tempfile
    from pathlib import Path

    from service.rasters import MAX_SIDE_PX, resolve, user_folder
    from solver.matching.features import MatchSettings
    from solver.matching.run import run_matching
    from solver.raster_gate import RasterLimits, RasterSpace, confined

    root = Path(document["image_root"]) if document.get("image_root") else None
    with tempfile.TemporaryDirectory(prefix="pba-match-") as tmp:
        folders = [Path(os.path.realpath(tmp))]
        if root is not None:
            try:
                folders.insert(0, user_folder(root, document["image_folder"]))
            except ValueError as exc:
                raise JobError(Problem("unusable_raster", str(exc), ())) from None
        space = RasterSpace(tuple(folders), RasterLimits(MAX_SIDE_PX, document.get("max_pixel_bytes")))
        rasters = []
        for k, r in enumerate(document["images"]):
            if "path" in r:
                try:
                    path = resolve(root, document["image_folder"], r["path"], k)
                except InvalidInput as exc:  # the file changed since submission
                    raise JobError(Problem("unusable_raster", exc.detail, ())) from None
                rasters.append((r["id"], path, r["path"]))
            else:
                path = Path(tmp) / f"upload-{k}.raster"
                path.write_bytes(base64.b64decode(r["upload"]))
                rasters.append((r["id"], path, f"the upload of image {r['id']}"))
        settings = MatchSettings(**(document.get("match") or {}))
        heights = tuple(document["heights_m"]) if document.get("heights_m") else None
        with confined(space):
            return run_matching(document["job"], rasters, heights, settings, progress, cancel)


def _match_inputs() -> dict[str, InputDescription]:
    from service.schemas import ExecuteInputs

    fields = ExecuteInputs.model_json_schema()
    props, defs = fields["properties"], fields.get("$defs", {})

    def described(name: str, title: str, min_occurs: int) -> InputDescription:
        schema = dict(props[name])
        schema.pop("default", None)
        if defs:
            schema["$defs"] = defs
        return InputDescription(title=title, description=props[name].get("description", ""), minOccurs=min_occurs, maxOccurs=1, schema=schema)

    return {
        "images": described("images", "Rasters", 1),
        "heights_m": described("heights_m", "Terrain height range", 0),
        "match": described("match", "Matching settings", 0),
    }


PROCESSES: dict[str, Process] = {
    p.id: p
    for p in (
        Process(
            BUNDLE_ADJUSTMENT,
            "Bundle adjustment of pushbroom images",
            "Estimates the platform-model parameters of every image (and the tie points) from "
            "image observations of control and tie points, and reports sigmas, correlations, "
            "residuals and check-point statistics.",
            "Adjustment report",
            count=_observations,
            check=_check_adjustment,
            run=_run_adjustment,
        ),
        Process(
            MODEL_COMPARISON,
            "Platform model comparison",
            "Adjusts the same observations with each of several platform models and reports one "
            "adjustment per model plus a side-by-side table of sigma0, chi-square verdicts and "
            "check-point RMSE.",
            "Comparison report",
            count=_observations,
            check=_check_comparison,
            run=_run_comparison,
            extra_inputs=_comparison_inputs,
        ),
        Process(
            PREANALYSIS,
            "Pre-analysis of a planned block",
            "Predicts the precision (sigmas and error ellipses) of the check, tie and control "
            "points of a planned block from the planned point coordinates and the images' "
            "approximate orientation, before anything is measured; image observations are not "
            "needed.",
            "Pre-analysis report",
            count=_planned_observations,
            check=_check_preanalysis,
            run=_run_preanalysis,
        ),
        Process(
            MATCH,
            "Tie points from the images",
            "Finds tie points in the rasters of the job's images, guided by the job's initial "
            "orientation (SIFT in the predicted epipolar band, ratio / mutual / RANSAC checks, "
            "correlation to sub-pixel, multi-image tracks, thinning, epipolar check; "
            "docs/matching.md). Rasters are uploads (small images) or files under the server's "
            "image root. The result's observations are the tie-point measurements (the "
            "observations table is the CSV pba job reads) and its summary the counts per pair.",
            "Tie points",
            count=_observations,
            check=_check_match,
            run=_run_match,
            cost=_match_cost,
            extra_inputs=_match_inputs,
            tables=("observations",),
        ),
    )
}

ProcessId = Literal[tuple(PROCESSES)]  # type: ignore[valid-type]
"""The offered process ids as a type (query parameters list them as an enum)."""


def process(process_id: str) -> Process:
    """The process ``process_id`` of the table; NoSuchProcess (404) when none is offered."""
    found = PROCESSES.get(process_id)
    if found is None:
        raise NoSuchProcess(process_id)
    return found


@lru_cache(maxsize=1)
def job_schema() -> dict[str, Any]:
    """JSON schema of the job document (from the one pydantic model)."""
    return Job.model_json_schema()


def model_names() -> list[str]:
    """Names of the registered platform models."""
    from solver.platforms import model_names as names

    return list(names())


def describe(process_id: str, base_url: str) -> ProcessDescription:
    """The OGC process description of ``process_id`` (NoSuchProcess when unknown)."""
    info = process(process_id)
    inputs = {
        "job": InputDescription(
            title="Job document",
            description="cameras, images with their platform models, ground points, image "
            "observations and options (schema_version 1.0); camera refs name cameras in "
            "/cameras",
            schema=job_schema(),
        ),
        **info.extra_inputs(),
    }
    outputs = {
        "report": OutputDescription(
            title=info.report_title,
            description="see docs/report-contract.md",
            schema={"type": "object", "contentMediaType": "application/json"},
        )
    }
    href = f"{base_url}processes/{process_id}"
    return ProcessDescription(
        id=info.id,
        title=info.title,
        description=info.description,
        version=VERSION,
        jobControlOptions=["sync-execute", "async-execute", "dismiss"],
        outputTransmission=["value"],
        inputs=inputs,
        outputs=outputs,
        links=[
            Link(href=href, rel="self", type="application/json", title="process description"),
            Link(
                href=f"{href}/execution",
                rel="http://www.opengis.net/def/rel/ogc/1.0/execute",
                type="application/json",
                title="execute",
            ),
        ],
    )
