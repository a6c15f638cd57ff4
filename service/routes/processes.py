"""Processes: list, describe, execute (synchronously for small jobs, else asynchronously)."""

from __future__ import annotations

import asyncio
import time
from typing import Annotated

from fastapi import APIRouter, Header, Path
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response

from service.deps import JSON_BODY, BaseUrl, CurrentUser, Services, ServicesDep
from service.errors import ServiceError, problem_responses
from service.jobs import results_text, status_info
from service.processes import PROCESSES, describe, process
from service.routes import StrictJSONRoute
from service.schemas import (
    Execute,
    Link,
    ProcessDescription,
    ProcessList,
    ProcessSummary,
    StatusInfo,
)
from service.states import FINISHED
from service.store import JobRecord

router = APIRouter(prefix="/processes", tags=["processes"], route_class=StrictJSONRoute)

ProcessId = Annotated[str, Path(max_length=64, description="process id")]


@router.get("", response_model=ProcessList, response_model_exclude_none=True)
def list_processes(base: BaseUrl) -> ProcessList:
    """The processes this server offers."""
    summaries = [
        ProcessSummary(**describe(pid, base).model_dump(include=set(ProcessSummary.model_fields)))
        for pid in PROCESSES
    ]
    return ProcessList(
        processes=summaries,
        links=[Link(href=f"{base}processes", rel="self", type="application/json")],
    )


@router.get(
    "/{processId}",
    response_model=ProcessDescription,
    response_model_by_alias=True,
    response_model_exclude_none=True,
    responses={**problem_responses(404)},
)
def get_process(processId: ProcessId, base: BaseUrl) -> ProcessDescription:
    """Description of one process, with its inputs and outputs."""
    return describe(processId, base)


async def _accepted(
    rec: JobRecord, base: str, preference: bool, services: Services
) -> JSONResponse:
    headers = {"Location": f"{base}jobs/{rec.id}"}
    if preference:
        headers["Preference-Applied"] = "respond-async"
    info = status_info(rec, base, await run_in_threadpool(services.jobs.placement_of, rec))
    return JSONResponse(info.model_dump(mode="json", exclude_none=True), 201, headers=headers)


@router.post(
    "/{processId}/execution",
    dependencies=JSON_BODY,
    responses={
        200: {
            "description": "synchronous execution: the report (raw) or {report} (document)",
            "content": {"application/json": {}},
        },
        201: {"description": "job accepted (asynchronous execution)", "model": StatusInfo},
        **problem_responses(401, 404, 413, 415, 422, 429, 500, 503),
    },
)
async def execute(
    processId: ProcessId,
    body: Execute,
    user: CurrentUser,
    services: ServicesDep,
    base: BaseUrl,
    prefer: Annotated[
        str | None, Header(description="respond-async for an asynchronous job")
    ] = None,
) -> Response:
    """Execute a process: ``Prefer: respond-async`` answers 201 with the job's Location; otherwise
    a small job is solved before answering (200 with the report), a large one answers 201."""
    wants_async = "respond-async" in (prefer or "").lower() or body.mode == "async"
    settings = services.settings
    sync = not (
        wants_async
        or process(processId).count(body.inputs.job) > settings.sync_max_observations
        or settings.sync_timeout_s <= 0
        or services.backend.worker_count() == 0
    )
    rec = await run_in_threadpool(services.jobs.submit, user, processId, body.inputs)
    if not sync:
        return await _accepted(rec, base, wants_async, services)
    deadline = time.monotonic() + settings.sync_timeout_s
    started = time.monotonic()
    delay = 0.01  # poll the store every 10 ms for the first second (small jobs), then back off
    while rec.status not in FINISHED:
        if time.monotonic() > deadline:
            return await _accepted(rec, base, False, services)
        await asyncio.sleep(delay)
        if time.monotonic() - started > 1.0:
            delay = min(delay * 1.5, 0.25)
        found = await run_in_threadpool(services.store.get_job, rec.id)
        if found is None:
            break
        rec = found
    try:
        text = await run_in_threadpool(results_text, rec)
    except ServiceError as exc:  # the job failed: its problem document, and where the job is
        exc.headers = {**exc.headers, "Location": f"{base}jobs/{rec.id}"}
        raise
    if body.response == "document":
        text = '{"report":' + text + "}"
    return Response(
        text, 200, media_type="application/json", headers={"Location": f"{base}jobs/{rec.id}"}
    )
