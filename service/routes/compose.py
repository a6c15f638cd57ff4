"""``POST /jobs/compose``: a job document from the files a photogrammetrist has (multipart:
the files, and a ``spec`` naming what each is). The use case is service/compose.py; the
formats are solver/importers."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Form, UploadFile
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from service.compose import (
    MAX_FILES,
    ComposeResult,
    check_file_name,
    check_sizes,
    compose_uploads,
    parse_spec,
    references,
)
from service.deps import CurrentUser, ServicesDep
from service.errors import InvalidInput, problem_responses

router = APIRouter(prefix="/jobs", tags=["jobs"])
CHUNK_BYTES = 1 << 20


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
    named: dict[str, UploadFile] = {}
    lines: dict[str, int] = {}
    sizes: dict[str, int] = {}
    for i, f in enumerate(files):
        name = check_file_name(f.filename, i)
        if name in named:
            raise InvalidInput(
                f"two files named {name!r}",
                [{"pointer": f"/files/{name}", "code": "duplicate_file", "message": "file names must be distinct"}],
            )
        named[name] = f
        lines[name], sizes[name] = await _count(f)
    _, max_observations = services.jobs.limits_of(user)
    check_sizes(parsed, lines, sizes, services.settings.compose_max_rows, max_observations)
    referenced = {name for _, name in references(parsed)}
    uploads = {name: await f.read() for name, f in named.items() if name in referenced}
    return await run_in_threadpool(compose_uploads, parsed, uploads, services.store, user)


class SensorFormat(BaseModel):
    """A vendor metadata format the composition reads (solver.sensors.readers)."""

    name: str
    description: str
    roots: list[str] = Field(description="XML root elements that name the format")
    file_names: list[str] = Field(description="file names (glob, any case) that name the format alone")


class ComposeFormats(BaseModel):
    """What the composition recognises without being told (the web page's job builder asks)."""

    sensor: list[SensorFormat]


@router.get("/compose/formats", response_model=ComposeFormats)
async def compose_formats() -> ComposeFormats:
    """The vendor sensor-metadata formats the composition reads: their XML roots and the file
    names that name them (the job builder recognises dropped files by them)."""
    from solver.sensors.readers import describe

    return ComposeFormats(sensor=[SensorFormat(**f) for f in describe()])


async def _count(f: UploadFile) -> tuple[int, int]:
    """(lines: line ends + 1, bytes) of an upload, read in chunks of :data:`CHUNK_BYTES` (the
    multipart parser keeps big uploads on disk), then rewound: counted before it is held."""
    lines, size = 1, 0
    while chunk := await f.read(CHUNK_BYTES):
        lines += chunk.count(b"\n")
        size += len(chunk)
    await f.seek(0)
    return lines, size
