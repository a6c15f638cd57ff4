"""The camera library: named, versioned camera definitions (focal plane, chips, IOP with
covariance) that jobs reference with ``cameras[].ref = {name, version}``. The library is
shared by all users of the server; every new definition of a name is a new version."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query
from fastapi.responses import JSONResponse

from service.cameras import camera_from_report, camera_links
from service.deps import JSON_BODY, BaseUrl, CurrentUser, ServicesDep
from service.errors import Conflict, NotFound, problem_responses
from service.jobs import results_text
from service.routes import StrictJSONRoute
from service.schemas import (
    CameraCreate,
    CameraDefinition,
    CameraFromJob,
    CameraList,
    CameraPublic,
    Link,
)
from service.store import CameraRecord

router = APIRouter(prefix="/cameras", tags=["cameras"], route_class=StrictJSONRoute)

Name = Annotated[str, Path(min_length=1, max_length=128, description="camera name")]


def _public(rec: CameraRecord, base: str) -> CameraPublic:
    return CameraPublic(
        name=rec.name,
        version=rec.version,
        description=rec.description,
        definition=rec.definition,
        created=rec.created,
        source_job=rec.source_job,
        links=[Link(**link) for link in camera_links(rec, base)],
    )


def _created(rec: CameraRecord, base: str) -> JSONResponse:
    body = _public(rec, base).model_dump(mode="json", exclude_none=True)
    return JSONResponse(
        body, 201, headers={"Location": f"{base}cameras/{rec.name}/versions/{rec.version}"}
    )


def _definition(defn: CameraDefinition) -> dict:
    return defn.model_dump(mode="json", exclude={"id", "ref"}, exclude_none=True)


@router.get(
    "",
    response_model=CameraList,
    response_model_exclude_none=True,
    responses={**problem_responses(401)},
)
def list_cameras(
    user: CurrentUser,
    services: ServicesDep,
    base: BaseUrl,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
) -> CameraList:
    """The latest version of every camera in the library."""
    records, total = services.store.list_cameras(None, limit, offset)
    return CameraList(
        cameras=[_public(r, base) for r in records],
        numberMatched=total,
        links=[Link(href=f"{base}cameras", rel="self", type="application/json")],
    )


@router.post(
    "",
    status_code=201,
    response_model=CameraPublic,
    dependencies=JSON_BODY,
    responses={**problem_responses(401, 413, 415, 422)},
)
def create_camera(
    body: CameraCreate, user: CurrentUser, services: ServicesDep, base: BaseUrl
) -> JSONResponse:
    """Store a camera definition as the next version of its name."""
    rec = services.store.add_camera(
        body.name, body.description, _definition(body.definition), user.id
    )
    return _created(rec, base)


@router.post(
    "/from-job",
    status_code=201,
    response_model=CameraPublic,
    dependencies=JSON_BODY,
    responses={**problem_responses(401, 404, 409, 415, 422)},
)
def camera_from_job(
    body: CameraFromJob, user: CurrentUser, services: ServicesDep, base: BaseUrl
) -> JSONResponse:
    """Save the camera a self-calibration job estimated (IOP values and covariance) as the next
    version of ``name``."""
    import json

    job = services.jobs.get_visible(body.job_id, user)
    report = json.loads(results_text(job))
    if report.get("kind") == "comparison":
        raise Conflict("a model comparison does not yield one camera; use an adjustment job")
    document = job.document or {}
    definition = camera_from_report(document, report, body.camera)
    CameraDefinition.model_validate(definition)
    rec = services.store.add_camera(
        body.name, body.description, definition, user.id, source_job=job.id
    )
    return _created(rec, base)


@router.get(
    "/{name}",
    response_model=CameraPublic,
    response_model_exclude_none=True,
    responses={**problem_responses(401, 404)},
)
def get_camera(name: Name, user: CurrentUser, services: ServicesDep, base: BaseUrl) -> CameraPublic:
    """The latest version of a camera."""
    rec = services.store.get_camera(name)
    if rec is None:
        raise NotFound(f"the camera library has no {name!r}")
    return _public(rec, base)


@router.get(
    "/{name}/versions",
    response_model=CameraList,
    response_model_exclude_none=True,
    responses={**problem_responses(401, 404)},
)
def list_versions(
    name: Name,
    user: CurrentUser,
    services: ServicesDep,
    base: BaseUrl,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
) -> CameraList:
    """Every version of a camera, newest first."""
    records, total = services.store.list_cameras(name, limit, offset)
    if total == 0:
        raise NotFound(f"the camera library has no {name!r}")
    return CameraList(
        cameras=[_public(r, base) for r in records],
        numberMatched=total,
        links=[Link(href=f"{base}cameras/{name}/versions", rel="self", type="application/json")],
    )


@router.get(
    "/{name}/versions/{version}",
    response_model=CameraPublic,
    response_model_exclude_none=True,
    responses={**problem_responses(401, 404)},
)
def get_camera_version(
    name: Name,
    version: Annotated[int, Path(ge=1, le=2_000_000_000)],
    user: CurrentUser,
    services: ServicesDep,
    base: BaseUrl,
) -> CameraPublic:
    """One version of a camera."""
    rec = services.store.get_camera(name, version)
    if rec is None:
        raise NotFound(f"the camera library has no {name!r} version {version}")
    return _public(rec, base)
