"""Compose a job document from uploaded files (``POST /jobs/compose``): the use case behind
service/routes/compose.py.

No format is parsed here: the uploads and the form's ``spec`` become a
:class:`solver.importers.compose.ComposeRequest`, the solver composes the document, and this
module only adds what the server knows: the caller's camera library (own namespace, then
shared, where the sensor presets are, :func:`service.cameras.ensure_presets`) and the answer's
shape. A file problem (:class:`solver.importers.errors.SourceError`) is a 422 problem
document whose entries name ``file``, ``line`` and ``column`` (pointer ``/files/<name>``);
a spec problem points into ``/spec``. A composed job the solver's checks refuse is still
returned (200), with ``validation.valid`` false and its problems pointing into ``/job``: the
page shows them beside the inputs.
"""

from __future__ import annotations

import json
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from service.cameras import find_camera, qualified_name, resolve_camera_refs
from service.errors import InvalidInput, ServiceError
from service.problems import job_error_entries, json_pointer, problem_entries, pydantic_errors
from service.store import Store, UserRecord
from solver.errors import JobError
from solver.importers.compose import (
    ComposeRequest,
    ImageSources,
    SourceFile,
    compose_job,
    summarize,
)
from solver.importers.errors import SourceError
from solver.schema.job import load_job

MAX_FILES = 200
Name = Field(min_length=1, max_length=255)


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ImageSpec(_Spec):
    """One image: its id, the uploaded files of its measurements and times, its camera; or, for
    an RPC image, the uploaded file of its RPC (instead of camera and times) and its bias model."""

    id: str = Field(min_length=1, max_length=64)
    camera: str | None = Field(default=None, min_length=1, max_length=128)
    measurements: list[str] = Field(default_factory=list, max_length=MAX_FILES)
    ephemeris: str | None = None
    attitude: str | None = None
    state: str | None = None
    rpc: str | None = Field(default=None, description="an RPC image: its NAME_RPC.TXT, NAME.RPB or DIMAP RPC_*.XML (no raster)")
    rpc_model: str | None = Field(default=None, max_length=32, description="its bias model (default: the spec's rpc_model)")


class ComposeSpec(_Spec):
    """What the uploaded files are (by their file names) and the job's choices; the form
    of :class:`solver.importers.compose.ComposeRequest` (see ``pba job --help``)."""

    images: list[ImageSpec] = Field(min_length=1, max_length=64)
    gcps: list[str] = Field(default_factory=list)
    checks: list[str] = Field(default_factory=list)
    points: list[str] = Field(default_factory=list, description="point tables with a role column")
    asp_gcp: list[str] = Field(default_factory=list, description="ASP GCP files naming their images")
    camera_files: list[str] = Field(default_factory=list)
    camera: str | None = Field(default=None, description="camera of images without their own")
    crs: str | None = Field(default=None, max_length=4096, description="CRS of the point tables")
    models: list[str] = Field(default_factory=lambda: ["K2"], min_length=1, max_length=16)
    rpc_model: str = Field(default="RPC-DRIFT", max_length=32, description="bias model of the RPC images without their own")
    options: dict[str, Any] = Field(default_factory=dict)
    name: str = Field(default="job", max_length=200)
    time_scale: str | None = Field(default=None, max_length=32)
    sigma_px: float = Field(default=0.5, gt=0, le=1e6)
    match_tolerance_m: float = Field(default=1.0, gt=0, le=1e6)
    map_crs: str | None = Field(default=None, max_length=4096)
    columns: dict[str, dict[str, str]] = Field(
        default_factory=dict, description="file name -> {its column name: the format's name}"
    )


class ComposeResult(BaseModel):
    """The composed job document, what it holds, the import's notes and the solver's checks."""

    job: dict[str, Any]
    summary: dict[str, Any]
    notes: list[str]
    validation: dict[str, Any]


def parse_spec(text: str) -> ComposeSpec:
    """The form's ``spec`` field (JSON) or InvalidInput pointing into ``/spec``."""
    def no_constant(name: str) -> Any:
        raise ValueError(f"{name} is not a JSON number")

    try:
        obj = json.loads(text, parse_constant=no_constant)
    except ValueError as exc:
        raise InvalidInput(
            "the spec is not JSON", [{"pointer": "/spec", "code": "invalid_json", "message": str(exc)}]
        ) from None
    try:
        return ComposeSpec.model_validate(obj)
    except ValidationError as exc:
        raise InvalidInput("the spec does not match the schema", pydantic_errors(exc.errors(), ("spec",))) from None


def _request(spec: ComposeSpec, uploads: dict[str, bytes]) -> ComposeRequest:
    missing: list[dict[str, Any]] = []

    def file(name: str, where: tuple[str | int, ...]) -> SourceFile:
        if name not in uploads:
            missing.append(
                {"pointer": json_pointer(("spec", *where)), "code": "missing_file", "message": f"no uploaded file named {name!r}"}
            )
            return SourceFile(name, b"")
        return SourceFile(name, uploads[name], spec.columns.get(name, {}))

    images = []
    for k, im in enumerate(spec.images):
        images.append(
            ImageSources(
                im.id,
                [file(n, ("images", k, "measurements", j)) for j, n in enumerate(im.measurements)],
                im.camera,
                *(
                    file(n, ("images", k, attr)) if n else None
                    for attr, n in (("ephemeris", im.ephemeris), ("attitude", im.attitude), ("state", im.state))
                ),
                rpc=file(im.rpc, ("images", k, "rpc")) if im.rpc else None,
                rpc_model=im.rpc_model,
            )
        )
    req = ComposeRequest(
        images=images,
        **{
            attr: [file(n, (attr, j)) for j, n in enumerate(getattr(spec, attr))]
            for attr in ("gcps", "checks", "points", "asp_gcp", "camera_files")
        },
        camera=spec.camera,
        crs=spec.crs,
        models=spec.models,
        rpc_model=spec.rpc_model,
        options=spec.options,
        name=spec.name,
        time_scale=spec.time_scale,
        sigma_px=spec.sigma_px,
        match_tolerance_m=spec.match_tolerance_m,
        map_crs=spec.map_crs,
    )
    if missing:
        raise InvalidInput("the spec names files that were not uploaded", missing)
    return req


def source_error_entries(exc: SourceError, uploads: dict[str, bytes]) -> list[dict[str, Any]]:
    """A SourceError's problems as problem-document entries naming file, line and column
    (pointer ``/files/<name>``; a problem of the spec's choices, e.g. an unknown camera or
    CRS, points into ``/spec``)."""
    return [
        {
            "pointer": json_pointer(("files", p.file) if p.file in uploads else ("spec", p.file)),
            "code": p.code,
            "message": str(p),
            "file": p.file,
            "line": p.line,
            "column": p.column,
        }
        for p in exc.source_problems
    ]


def compose_uploads(spec: ComposeSpec, uploads: dict[str, bytes], store: Store, user: UserRecord) -> ComposeResult:
    """Compose, resolve library cameras for the checks, summarize and validate."""
    import solver.api

    def lookup(name: str) -> dict[str, Any] | None:
        rec = find_camera(store, user.id, name)
        return None if rec is None else {"ref": {"name": qualified_name(rec), "version": rec.version}}

    try:
        composed = compose_job(_request(spec, uploads), lookup)
    except SourceError as exc:
        raise InvalidInput(str(exc), source_error_entries(exc, uploads)) from None
    try:
        job = load_job(composed.job)
    except ValidationError as exc:
        return ComposeResult(
            job=composed.job,
            summary=summarize(composed.job),
            notes=composed.notes,
            validation={"valid": False, "problems": pydantic_errors(exc.errors(), ("job",))},
        )
    try:
        resolved = resolve_camera_refs(job, store, user.id, ("job",))
        validation = solver.api.validate(resolved)
    except ServiceError as exc:
        validation = {"valid": False, "problems": exc.errors}
        resolved = job
    except JobError as exc:
        validation = {"valid": False, "problems": job_error_entries(exc, ("job",))}
        resolved = job
    else:
        validation = {**validation, "problems": problem_entries(validation.get("problems", []), ("job",))}
    return ComposeResult(
        job=composed.job,
        summary=summarize(resolved.model_dump(mode="json")),
        notes=composed.notes,
        validation=validation,
    )
