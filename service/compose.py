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

import ctypes
import json
from collections import Counter
from dataclasses import MISSING
from dataclasses import fields as dataclass_fields
from types import UnionType
from typing import Annotated, Any, Union, get_args, get_origin, get_type_hints

from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model

from service.cameras import find_camera, qualified_name, resolve_camera_refs
from service.errors import InvalidInput, JobTooLarge, ServiceError
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
MAX_REFERENCES = 256  # file names in one spec (a file shared by several images counts once per image)
MAX_SENSOR_BYTES = 16 * 2**20  # one vendor metadata file (a full SPOT 5 scene's DIMAP is 2.5 MB, a WorldView XML 2 MB)
MAX_NAME_BYTES = 255  # a file name, UTF-8 (NAME_MAX of the usual file systems)
MAX_JSON_DEPTH = 32  # nesting of the spec (the job document is far flatter)
FileName = Annotated[str, Field(min_length=1, max_length=MAX_NAME_BYTES)]


# The wire form of a composition is derived from the solver's one specification,
# :class:`solver.importers.compose.ComposeRequest` and :class:`ImageSources`: every field
# carries over under its own name and type, a source file becomes the name of an uploaded file,
# and the server adds only the bounds below (and ``columns``, the uploads' column maps).
NOT_UPLOADED: frozenset[str] = frozenset()  # fields of the solver's request not taken from uploads
BOUNDS: dict[str, dict[str, Any]] = {
    "id": {"min_length": 1, "max_length": 64},
    "camera": {"min_length": 1, "max_length": 128},
    "rpc_model": {"max_length": 32},
    "crs": {"max_length": 4096},
    "map_crs": {"max_length": 4096},
    "time_scale": {"max_length": 32},
    "name": {"max_length": 200},
    "images": {"min_length": 1, "max_length": 64},
    "models": {"min_length": 1, "max_length": 16},
    "sigma_px": {"gt": 0, "le": 1e6},
    "match_tolerance_m": {"gt": 0, "le": 1e6},
    "bias_prior_px": {"gt": 0, "le": 1e6},
    "dem_sigma_m": {"gt": 0, "le": 1e4},
    "dem_vertical": {"max_length": 64},
    "first_line_time_s": {"allow_inf_nan": False},
}
DESCRIPTIONS = {
    "rpc": "an RPC image: its NAME_RPC.TXT, NAME.RPB, ALOS RPC-*.txt or DIMAP RPC_*.XML (no raster)",
    "sensor": "vendor sensor metadata (Maxar XML, DIMAP of SPOT 1-7 and Pleiades): the image's camera, ephemeris, "
    "attitude, line times and model",
    "rpc_model": "bias model of the RPC images without their own",
    "bias_prior_px": "a 0 +- this prior (px) on every RPC image's bias terms (drift terms: this over the image's extent)",
    "points": "point tables with a role column",
    "asp_gcp": "ASP GCP files naming their images",
    "camera": "camera by name (a camera file's, a preset, the camera library's)",
    "crs": "CRS of the point tables",
    "dem": "a DEM raster (GeoTIFF, JPEG 2000): its heights of the tie points become observations (job.dem)",
    "dem_sigma_m": "the DEM's vertical accuracy, one sigma (m)",
    "dem_vertical": "the DEM's vertical datum where its file does not state it: ellipsoid, egm96, egm2008 or EPSG:code",
}


def _is_file(hint: Any) -> bool:
    return hint is SourceFile or (get_origin(hint) in (Union, UnionType) and SourceFile in get_args(hint))


def _is_file_list(hint: Any) -> bool:
    return get_origin(hint) is list and get_args(hint) == (SourceFile,)


def _wire_fields(cls: type, nested: dict[type, type]) -> dict[str, Any]:
    """The pydantic fields of ``cls``'s wire form (a source file -> its file name)."""
    hints = get_type_hints(cls)
    out: dict[str, Any] = {}
    for f in dataclass_fields(cls):
        if f.name in NOT_UPLOADED:
            continue
        hint = hints[f.name]
        if _is_file(hint):
            hint = FileName | None
        elif _is_file_list(hint):
            hint = Annotated[list[FileName], Field(max_length=MAX_FILES)]
        elif get_origin(hint) is list and get_args(hint)[0] in nested:
            hint = list[nested[get_args(hint)[0]]]  # type: ignore[index]
        if f.default_factory is not MISSING:
            default: dict[str, Any] = {"default_factory": f.default_factory}
        else:
            default = {} if f.default is MISSING else {"default": f.default}
        info = Field(**default, description=DESCRIPTIONS.get(f.name), **BOUNDS.get(f.name, {}))
        out[f.name] = (hint, info)
    return out


_CONFIG = ConfigDict(extra="forbid")
ImageSpec = create_model(  # type: ignore[call-overload]
    "ImageSpec",
    __config__=_CONFIG,
    __doc__="One image of a composition: the fields of ImageSources, files by their upload names.",
    **_wire_fields(ImageSources, {}),
)
ComposeSpec = create_model(  # type: ignore[call-overload]
    "ComposeSpec",
    __config__=_CONFIG,
    __doc__="What the uploaded files are (by their file names) and the job's choices: the fields "
    "of ComposeRequest (see ``pba job --help``), files by their upload names.",
    columns=(
        dict[str, dict[str, str]],
        Field(default_factory=dict, description="file name -> {its column name: the format's name}"),
    ),
    **_wire_fields(ComposeRequest, {ImageSources: ImageSpec}),
)


class ComposeResult(BaseModel):
    """The composed job document, what it holds, the import's notes and the solver's checks."""

    job: dict[str, Any]
    summary: dict[str, Any]
    notes: list[str]
    validation: dict[str, Any]


def parse_spec(text: str) -> Any:
    """The form's ``spec`` field (JSON) or InvalidInput pointing into ``/spec``."""
    def no_constant(name: str) -> Any:
        raise ValueError(f"{name} is not a JSON number")

    try:
        obj = json.loads(text, parse_constant=no_constant)
    except ValueError as exc:
        raise InvalidInput(
            "the spec is not JSON", [{"pointer": "/spec", "code": "invalid_json", "message": str(exc)}]
        ) from None
    except RecursionError:
        obj = None
    if obj is None or json_depth(obj) > MAX_JSON_DEPTH:
        raise InvalidInput(
            "the spec is nested too deeply",
            [{"pointer": "/spec", "code": "nesting_too_deep", "message": f"at most {MAX_JSON_DEPTH} levels of nesting"}],
        )
    try:
        return ComposeSpec.model_validate(obj)
    except ValidationError as exc:
        raise InvalidInput("the spec does not match the schema", pydantic_errors(exc.errors(), ("spec",))) from None


def json_depth(obj: Any) -> int:
    """Nesting depth of a parsed JSON value (a scalar: 0, ``{}``: 1), without recursion."""
    depth, level = 0, [obj]
    while True:
        containers = [n for n in level if isinstance(n, (dict, list))]
        if not containers:
            return depth
        depth += 1
        level = [v for n in containers for v in (n.values() if isinstance(n, dict) else n)]


def check_file_name(name: str | None, index: int) -> str:
    """The name of the ``index``-th uploaded file, or InvalidInput (empty, control characters,
    more than :data:`MAX_NAME_BYTES` bytes of UTF-8, not encodable): the spec names files by
    these names, and an RPC file is written to disk under its kind (solver.importers.rpc)."""
    message = None
    if not name:
        message, code = "an uploaded file has no name (the spec names the files by their names)", "empty_file_name"
    elif any(ord(c) < 32 or ord(c) == 127 for c in name):
        message, code = "the file name holds a control character", "invalid_file_name"
    else:
        try:
            size = len(name.encode("utf-8"))
        except UnicodeEncodeError:
            message, code = "the file name is not valid Unicode", "invalid_file_name"
        else:
            if size > MAX_NAME_BYTES:
                message, code = f"the file name has {size} bytes; at most {MAX_NAME_BYTES}", "file_name_too_long"
    if message is not None:
        raise InvalidInput(message, [{"pointer": f"/files/{index}", "code": code, "message": message}])
    assert name is not None
    return name


def references(spec: Any) -> list[tuple[tuple[str | int, ...], str]]:
    """(where in the spec, file name) of every file the spec names."""
    def of(cls: type, wire: Any, where: tuple[str | int, ...]) -> list[tuple[tuple[str | int, ...], str]]:
        hints = get_type_hints(cls)
        refs: list[tuple[tuple[str | int, ...], str]] = []
        for f in dataclass_fields(cls):
            if f.name in NOT_UPLOADED:
                continue
            value, hint = getattr(wire, f.name), hints[f.name]
            if _is_file(hint) and value is not None:
                refs.append(((*where, f.name), value))
            elif _is_file_list(hint):
                refs += [((*where, f.name, j), n) for j, n in enumerate(value)]
        return refs

    refs = [r for k, im in enumerate(spec.images) for r in of(ImageSources, im, ("images", k))]
    return refs + of(ComposeRequest, spec, ())


def check_sizes(spec: Any, lines: dict[str, int], sizes: dict[str, int], max_rows: int, max_observations: int) -> None:
    """Refuse, before any file is read into memory or parsed, a spec naming more than
    :data:`MAX_REFERENCES` files or one file twice in one image (422), or uploads whose
    ``lines`` (per file name: line ends + 1), counted once per reference, exceed
    ``max_rows`` (``PBA_COMPOSE_MAX_ROWS``), whose measurement lines exceed the user's
    ``max_observations``, or a sensor metadata file over :data:`MAX_SENSOR_BYTES` (``sizes``:
    bytes per file name) (413): the work of a composition is bounded by these counts."""
    refs = references(spec)
    if len(refs) > MAX_REFERENCES:
        raise InvalidInput(
            f"the spec names {len(refs)} files; at most {MAX_REFERENCES}",
            [{"pointer": "/spec", "code": "too_many_references", "message": f"at most {MAX_REFERENCES} file names"}],
        )
    for k, im in enumerate(spec.images):
        twice = [n for n, c in Counter(im.measurements).items() if c > 1]
        if twice:
            raise InvalidInput(
                f"image {im.id!r} names {twice[0]!r} twice",
                [{"pointer": json_pointer(("spec", "images", k, "measurements")), "code": "duplicate_reference", "message": f"{twice[0]!r} is named twice"}],
            )
    for where, name in refs:  # metadata XML is bounded by its bytes, not by lines of rows
        if where[-1] == "sensor" and sizes.get(name, 0) > MAX_SENSOR_BYTES:
            raise JobTooLarge(f"the sensor metadata {name!r} has {sizes[name]} bytes; at most {MAX_SENSOR_BYTES}")
    rows = sum(lines.get(name, 0) for where, name in refs if where[-1] != "sensor")
    measured = sum(lines.get(name, 0) for where, name in refs if where[0] == "asp_gcp" or where[-2:-1] == ("measurements",))
    if rows > max_rows:
        raise JobTooLarge(
            f"the uploads hold {rows} lines (counted once per file name in the spec); a composition on the server "
            f"takes at most {max_rows}: compose bigger jobs with pba job on your machine"
        )
    if measured > max_observations:
        raise JobTooLarge(f"the measurement files hold {measured} lines; your limit is {max_observations} observations per job")


def release_memory() -> None:
    """Give freed heap pages back to the system (glibc ``malloc_trim``; nothing elsewhere):
    a composition's transient objects would otherwise keep the API process's RSS high."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _request(spec: Any, uploads: dict[str, bytes]) -> ComposeRequest:
    """The solver's request of a checked spec: every field carried over, each file name
    replaced by its upload (InvalidInput listing the names that were not uploaded)."""
    missing: list[dict[str, Any]] = []

    def file(name: str, where: tuple[str | int, ...]) -> SourceFile:
        if name not in uploads:
            missing.append(
                {"pointer": json_pointer(("spec", *where)), "code": "missing_file", "message": f"no uploaded file named {name!r}"}
            )
            return SourceFile(name, b"")
        return SourceFile(name, uploads[name], spec.columns.get(name, {}))

    def build(cls: type, wire: Any, where: tuple[str | int, ...]) -> Any:
        hints = get_type_hints(cls)
        values: dict[str, Any] = {}
        for f in dataclass_fields(cls):
            if f.name in NOT_UPLOADED:
                continue
            value, hint = getattr(wire, f.name), hints[f.name]
            if _is_file(hint):
                values[f.name] = file(value, (*where, f.name)) if value is not None else None
            elif _is_file_list(hint):
                values[f.name] = [file(n, (*where, f.name, j)) for j, n in enumerate(value)]
            elif f.name == "images":
                values[f.name] = [build(ImageSources, im, (*where, f.name, k)) for k, im in enumerate(value)]
            else:
                values[f.name] = value
        return cls(**values)

    req = build(ComposeRequest, spec, ())
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


def compose_uploads(
    spec: Any, uploads: dict[str, bytes], store: Store, user: UserRecord
) -> ComposeResult:
    """Compose (the caller checked the sizes first: :func:`check_sizes`), resolve library
    cameras for the checks, summarize and validate; the heap is trimmed afterwards
    (:func:`release_memory`)."""
    try:
        return _compose(spec, uploads, store, user)
    finally:
        release_memory()


def _compose(spec: Any, uploads: dict[str, bytes], store: Store, user: UserRecord) -> ComposeResult:
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
