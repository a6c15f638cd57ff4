"""Jobs: list, status, results (JSON and CSV), dismiss/cancel, dry-run validation, SSE events."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterable
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response
from fastapi.sse import EventSourceResponse, ServerSentEvent

from service.deps import JSON_BODY, BaseUrl, CurrentUser, ServicesDep, VisibleJob
from service.errors import JobDismissed, problem_responses
from service.jobs import results_text, status_info, validate_inputs
from service.processes import BUNDLE_ADJUSTMENT, ProcessId
from service.report_csv import table_rows, to_csv
from service.routes import StrictJSONRoute
from service.schemas import Execute, JobList, Link, StatusInfo, ValidationReport
from service.states import FINISHED, JobStatus
from service.store import JobRecord

router = APIRouter(prefix="/jobs", tags=["jobs"], route_class=StrictJSONRoute)

NOT_FOUND = problem_responses(401, 404)


@router.get(
    "",
    response_model=JobList,
    response_model_exclude_none=True,
    responses={**problem_responses(401)},
)
def list_jobs(
    user: CurrentUser,
    services: ServicesDep,
    base: BaseUrl,
    status: Annotated[
        list[JobStatus] | None, Query(description="only jobs in these states")
    ] = None,
    processID: Annotated[
        ProcessId | None,
        Query(description="only this process"),
    ] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 10,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
) -> JobList:
    """The current user's jobs (an admin's: everyone's), newest first, with paging links."""
    owner = None if user.is_admin else user.id
    records, total = services.store.list_jobs(owner, status, processID, limit, offset)
    query = "".join(f"&status={s.value}" for s in status or []) + (
        f"&processID={processID}" if processID else ""
    )
    links = [
        Link(
            href=f"{base}jobs?limit={limit}&offset={offset}{query}",
            rel="self",
            type="application/json",
        )
    ]
    if offset + limit < total:
        links.append(
            Link(
                href=f"{base}jobs?limit={limit}&offset={offset + limit}{query}",
                rel="next",
                type="application/json",
            )
        )
    if offset > 0:
        links.append(
            Link(
                href=f"{base}jobs?limit={limit}&offset={max(0, offset - limit)}{query}",
                rel="prev",
                type="application/json",
            )
        )
    return JobList(jobs=[status_info(r, base) for r in records], numberMatched=total, links=links)


@router.post(
    "/validate",
    response_model=ValidationReport,
    dependencies=JSON_BODY,
    responses={**problem_responses(400, 401, 413, 415, 422)},
)
def validate_job(
    body: Execute,
    user: CurrentUser,
    services: ServicesDep,
    process: Annotated[
        ProcessId,
        Query(description="process to validate for"),
    ] = BUNDLE_ADJUSTMENT,
) -> ValidationReport:
    """Dry run: schema, camera references, model names, degrees of freedom; nothing is queued.
    Answers 200 with the counts, or 422 with every problem pointing at its field."""
    _, summary = validate_inputs(process, body.inputs, services.store, user, services.settings)
    return ValidationReport.model_validate(summary)


@router.get(
    "/{jobId}", response_model=StatusInfo, response_model_exclude_none=True, responses=NOT_FOUND
)
def get_status(job: VisibleJob, services: ServicesDep, base: BaseUrl) -> StatusInfo:
    """Status of a job: state, progress 0-100 (never decreasing), message, times, links; an
    accepted job's position among the waiting jobs and estimated start."""
    return status_info(job, base, services.jobs.placement_of(job))


@router.delete(
    "/{jobId}", response_model=StatusInfo, response_model_exclude_none=True, responses=NOT_FOUND
)
def dismiss_job(
    job: VisibleJob, user: CurrentUser, services: ServicesDep, base: BaseUrl
) -> StatusInfo:
    """Cancel a queued or running job (a running solve stops within one iteration), or dismiss
    a finished one (its results are deleted)."""
    return status_info(services.jobs.cancel(job.id, user), base)


@router.get(
    "/{jobId}/results",
    responses={
        200: {"description": "results document {report: ...}", "content": {"application/json": {}}},
        **problem_responses(401, 404, 422, 500),
    },
)
def get_results(job: VisibleJob) -> Response:
    """Results document ``{"report": <report>}`` of a successful job (docs/report-contract.md);
    a failed job answers with its error as a problem document."""
    return Response('{"report":' + results_text(job) + "}", media_type="application/json")


@router.get(
    "/{jobId}/results/{table}.csv",
    response_class=Response,
    responses={200: {"content": {"text/csv": {}}}, **problem_responses(401, 404, 422, 500)},
)
def get_results_table(
    job: VisibleJob, table: Literal["observations", "checkpoints", "parameters", "rejected"]
) -> Response:
    """One table of the report as CSV: observations (residuals), checkpoints, parameters,
    rejected (data snooping: failed tests and non-identifiable groups with their status, removed,
    kept or reinstated, and the control points the removals took away; docs/quality.md)."""
    import json

    report = json.loads(results_text(job))
    return Response(to_csv(table_rows(report, table)), media_type="text/csv; charset=utf-8")


def _job_with_events(job: VisibleJob) -> JobRecord:
    """The path's job unless dismissed (before the stream starts: a 404, not a broken stream)."""
    if job.status == JobStatus.dismissed:
        raise JobDismissed(f"job {job.id} was dismissed: it has no events")
    return job


@router.get("/{jobId}/events", response_class=EventSourceResponse, responses=NOT_FOUND)
async def job_events(
    job: Annotated[JobRecord, Depends(_job_with_events)], request: Request, services: ServicesDep, base: BaseUrl
) -> AsyncIterable[ServerSentEvent]:
    """Server-Sent Events: a ``status`` event (the status document) whenever the status,
    progress or message changes; the stream ends after the job finishes. A dismissed job has
    no events (404)."""
    last: tuple[str, int, str] | None = None
    n = 0
    rec = job
    while True:
        key = (rec.status.value, rec.progress, rec.message)
        if key != last:
            last = key
            n += 1
            info = status_info(rec, base).model_dump(mode="json", exclude_none=True)
            yield ServerSentEvent(data=info, event="status", id=str(n))
        if rec.status in FINISHED or await request.is_disconnected():
            return
        await asyncio.sleep(services.settings.sse_interval_s)
        found = await run_in_threadpool(services.store.get_job, job.id)
        if found is None:
            return
        rec = found
