"""Plots of a job's report as images: ``/jobs/{jobId}/plots`` lists the kinds that apply,
``/jobs/{jobId}/plots/{kind}.{png|svg}`` draws one (service/plots.py; everything drawn comes
from the stored report).

A plot that does not apply to the job (height discrepancies of mono check points, per-model
RMSE of a single adjustment, correlations without covariance) answers 409; an unknown image or
model, or a job without results, 404; a failed job 409. Never a 500 for any of these.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Annotated, Literal
from urllib.parse import quote

from fastapi import APIRouter, Query
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response
from pydantic import BaseModel

from service.deps import BaseUrl, VisibleJob
from service.errors import Conflict, NotFound, ResultNotReady, problem_responses
from service.plots import (
    FORMATS,
    PLOT_KINDS,
    NoSuchSelection,
    PlotNotApplicable,
    adjustment_report,
    applicable,
    plot_bytes,
)
from service.schemas import Link
from service.states import JobStatus
from service.store import JobRecord

router = APIRouter(prefix="/jobs", tags=["plots"])

# the kinds of service.plots.PLOT_KINDS, spelled out for the OpenAPI document (a test compares)
PlotKindName = Literal[
    "planimetric-discrepancies",
    "height-discrepancies",
    "image-residuals",
    "residual-histograms",
    "correlations",
    "cost",
    "error-ellipses",
    "model-rmse",
]

CACHE_BYTES = 64 * 2**20  # rendered images kept per server process (a report never changes)
CACHE_CONTROL = "private, max-age=300"


class PlotNotApplicableProblem(Conflict):
    code, title = "plot-not-applicable", "Plot does not apply to this job"


class NoSuchSelectionProblem(NotFound):
    code, title = "no-such-selection", "No such image or model in the report"


class JobHasNoReport(Conflict):
    code, title = "job-failed", "The job failed; it has no report to plot"


class PlotInfo(BaseModel):
    """One plot kind that applies to the job, with its image links."""

    kind: str
    title: str
    description: str
    per_image: bool
    links: list[Link]


class PlotIndex(BaseModel):
    """``GET /jobs/{jobId}/plots``: what can be drawn for this job."""

    jobID: str
    kind: str
    images: list[str]
    models: list[str] | None = None
    model: str | None = None
    plots: list[PlotInfo]


class _Cache:
    """A small LRU of rendered images (at most ``max_bytes``), keyed by job, kind, format,
    image and model."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self.size = 0
        self.items: OrderedDict[tuple[str, ...], bytes] = OrderedDict()
        self.lock = threading.Lock()

    def get(self, key: tuple[str, ...]) -> bytes | None:
        with self.lock:
            data = self.items.get(key)
            if data is not None:
                self.items.move_to_end(key)
            return data

    def put(self, key: tuple[str, ...], data: bytes) -> None:
        if len(data) > self.max_bytes // 4:
            return
        with self.lock:
            old = self.items.pop(key, None)
            self.size += len(data) - (len(old) if old is not None else 0)
            self.items[key] = data
            while self.size > self.max_bytes:
                _, dropped = self.items.popitem(last=False)
                self.size -= len(dropped)


_cache = _Cache(CACHE_BYTES)


def _report(job: JobRecord) -> dict:
    """The job's report, or the problem that says why there is none."""
    if job.status == JobStatus.failed:
        raise JobHasNoReport(f"the job failed: {job.message}")
    if job.status != JobStatus.successful:
        state = "was dismissed" if job.status == JobStatus.dismissed else f"is {job.status.value}"
        raise ResultNotReady(f"the job {state}; it has no report to plot yet")
    report = job.results
    if not isinstance(report, dict):
        raise ResultNotReady("the job's results are missing")
    return report


ImageQuery = Annotated[
    str | None,
    Query(max_length=200, description="image id (per-image kinds; default: every image)"),
]
ModelQuery = Annotated[
    str | None,
    Query(
        max_length=64,
        description="model comparison: the model whose report to draw (default: the first "
        "that succeeded); ignored for a single adjustment",
    ),
]


@router.get(
    "/{jobId}/plots",
    response_model=PlotIndex,
    response_model_exclude_none=True,
    responses=problem_responses(401, 404, 409),
)
def list_plots(job: VisibleJob, base: BaseUrl, model: ModelQuery = None) -> PlotIndex:
    """The plot kinds that apply to a successful job's report, with PNG and SVG links."""
    model = model or None
    report = _report(job)
    try:
        sub = adjustment_report(report, model)
    except NoSuchSelection as exc:
        raise NoSuchSelectionProblem(str(exc)) from exc
    except PlotNotApplicable:
        sub = {}
    kinds = applicable(report, model)
    suffix = f"?model={quote(model)}" if model and report.get("kind") == "comparison" else ""
    href = f"{base}jobs/{job.id}/plots"
    plots = [
        PlotInfo(
            kind=k,
            title=PLOT_KINDS[k].title,
            description=PLOT_KINDS[k].description,
            per_image=PLOT_KINDS[k].per_image,
            links=[
                Link(href=f"{href}/{k}.{fmt}{suffix}", rel="alternate", type=media, title=fmt)
                for fmt, media in FORMATS.items()
            ],
        )
        for k in kinds
    ]
    models = None
    chosen = None
    if report.get("kind") == "comparison":
        models = [str(m) for m in report.get("models") or []]
        chosen = next((m for m in models if (report.get("reports") or {}).get(m) is sub), None)
    return PlotIndex(
        jobID=job.id,
        kind=str(report.get("kind", "adjustment")),
        images=[str(im.get("id")) for im in sub.get("images") or []],
        models=models,
        model=chosen,
        plots=plots,
    )


@router.get(
    "/{jobId}/plots/{kind}.{format}",
    response_class=Response,
    responses={
        200: {
            "description": "the plot as PNG or SVG",
            "content": {media: {"schema": {"type": "string"}} for media in FORMATS.values()},
        },
        **problem_responses(401, 404, 409),
    },
)
async def get_plot(
    job: VisibleJob,
    kind: PlotKindName,
    format: Literal["png", "svg"],
    image: ImageQuery = None,
    model: ModelQuery = None,
) -> Response:
    """One plot of a successful job's report as PNG or SVG (see ``GET /jobs/{jobId}/plots``
    for the kinds that apply). ``image`` selects one image for the per-image kinds."""
    image, model = image or None, model or None
    spec = PLOT_KINDS[kind]
    key = (job.id, kind, format, image if spec.per_image else "", model or "")
    data = _cache.get(key) if job.status == JobStatus.successful else None
    if data is None:
        data = await run_in_threadpool(_draw, job, kind, format, image, model)
        _cache.put(key, data)
    return Response(data, media_type=FORMATS[format], headers={"Cache-Control": CACHE_CONTROL})


def _draw(job: JobRecord, kind: str, fmt: str, image: str | None, model: str | None) -> bytes:
    report = _report(job)
    try:
        return plot_bytes(report, kind, fmt, image, model)
    except PlotNotApplicable as exc:
        raise PlotNotApplicableProblem(str(exc)) from exc
    except NoSuchSelection as exc:
        raise NoSuchSelectionProblem(str(exc)) from exc
