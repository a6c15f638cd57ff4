"""``POST /jobs/compose``: a job document from the files a photogrammetrist has (multipart:
the files, and a ``spec`` naming what each is). The use case is service/compose.py; the
formats are solver/importers."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Form, UploadFile
from fastapi.concurrency import run_in_threadpool

from service.compose import MAX_FILES, ComposeResult, check_file_name, compose_uploads, parse_spec
from service.deps import CurrentUser, ServicesDep
from service.errors import InvalidInput, problem_responses

router = APIRouter(prefix="/jobs", tags=["jobs"])


@router.post(
    "/compose",
    response_model=ComposeResult,
    responses={**problem_responses(401, 413, 422)},
)
async def compose_job(
    user: CurrentUser,
    services: ServicesDep,
    spec: Annotated[str, Form(description="JSON: what each uploaded file is (ComposeSpec)")],
    files: Annotated[list[UploadFile], File(description="the source files, named as in spec")],
) -> ComposeResult:
    """Compose a job document from uploaded survey, measurement (CSV, QGIS .points, ASP
    .gcp), ephemeris, attitude and camera files; 422 with file, line and column of every
    problem of a file, else the document, its summary and the solver's checks."""
    parsed = parse_spec(spec)
    if len(files) > MAX_FILES:
        raise InvalidInput(f"at most {MAX_FILES} files", [{"pointer": "/files", "code": "too_many", "message": "too many files"}])
    uploads: dict[str, bytes] = {}
    for i, f in enumerate(files):
        name = check_file_name(f.filename, i)
        if name in uploads:
            raise InvalidInput(
                f"two files named {name!r}",
                [{"pointer": f"/files/{name}", "code": "duplicate_file", "message": "file names must be distinct"}],
            )
        uploads[name] = await f.read()
    _, max_observations = services.jobs.limits_of(user)
    return await run_in_threadpool(
        compose_uploads, parsed, uploads, services.store, user, services.settings.compose_max_rows, max_observations
    )
