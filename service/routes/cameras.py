"""The camera library: named, versioned camera definitions (focal plane, chips, IOP with
covariance) that jobs reference with ``cameras[].ref = {name, version}``.

Each camera belongs to the user who created it; other users see it only once it is
published to the shared namespace (``POST /cameras/{name}/share``, or ``shared: true`` on
``POST /cameras``). Names resolve in the caller's own namespace, then the shared one;
``/cameras/shared/{name}`` addresses the shared one explicitly (service.cameras).
"""

from __future__ import annotations

import json
from typing import Annotated

from fastapi import APIRouter, Path, Query
from fastapi.responses import JSONResponse

from service.cameras import (
    SHARED_PREFIX,
    camera_links,
    check_may_publish,
    find_camera,
    namespace_of,
)
from service.deps import JSON_BODY, BaseUrl, CurrentUser, Services, ServicesDep
from service.errors import CameraTooLarge, Conflict, NotFound, problem_responses
from service.jobs import results_text
from service.retention import quota_bytes, quota_error
from service.routes import StrictJSONRoute
from service.schemas import (
    CameraCreate,
    CameraDefinition,
    CameraFromJob,
    CameraList,
    CameraPublic,
    CameraShare,
    Link,
)
from service.states import JobStatus
from service.store import SHARED, CameraRecord, QuotaExceeded, Store, UserRecord
from solver.observations.interior import NoEstimatedCamera, camera_from_report

router = APIRouter(prefix="/cameras", tags=["cameras"], route_class=StrictJSONRoute)

Name = Annotated[str, Path(min_length=1, max_length=128, description="camera name")]
Version = Annotated[int, Path(ge=1, le=2_000_000_000, description="version number")]
Limit = Annotated[int, Query(ge=1, le=1000)]
VersionLimit = Annotated[int, Query(ge=1, le=100, description="versions per page (each holds a whole definition)")]
Offset = Annotated[int, Query(ge=0, le=10_000_000)]


def _public(rec: CameraRecord, base: str, viewer: UserRecord) -> CameraPublic:
    """The public view; the job a shared version came from only for its publisher or an admin."""
    return CameraPublic(
        name=rec.name,
        version=rec.version,
        shared=rec.shared,
        description=rec.description,
        definition=rec.definition,
        created=rec.created,
        source_job=rec.source_job if not rec.shared or rec.created_by == viewer.id or viewer.is_admin else None,
        links=[Link(**link) for link in camera_links(rec, base)],
    )


def _created(rec: CameraRecord, base: str, viewer: UserRecord) -> JSONResponse:
    body = _public(rec, base, viewer).model_dump(mode="json", exclude_none=True)
    return JSONResponse(body, 201, headers={"Location": camera_links(rec, base)[0]["href"]})


def _definition(defn: CameraDefinition) -> dict:
    return defn.model_dump(mode="json", exclude={"id", "ref"}, exclude_none=True)


def _store_camera(services: Services, user: UserRecord, name: str, description: str, definition: dict, **where: str | None) -> CameraRecord:
    """A new camera version, its size bounded (``PBA_CAMERA_MAX_BYTES``) and counted in the
    creator's storage quota (413 either way)."""
    size = len(json.dumps(definition))
    limit = services.settings.camera_max_bytes
    if size > limit:
        raise CameraTooLarge(f"the camera definition has {size} bytes of JSON; at most {limit}")
    quota_mb = services.settings.user_storage_quota_mb
    try:
        return services.store.add_camera(name, description, definition, user.id, quota_bytes=quota_bytes(quota_mb), **where)
    except QuotaExceeded as exc:
        raise quota_error(exc, quota_mb) from None


def _owner_for_write(user: UserRecord, shared: bool, name: str, store: Store) -> str:
    """The namespace a new version of ``name`` goes to (Forbidden for a shared name the
    user may not publish to)."""
    if not shared:
        return user.id
    check_may_publish(store, user, name)
    return SHARED


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
    limit: Limit = 100,
    offset: Offset = 0,
) -> CameraList:
    """The latest version of every camera you own and of every shared camera."""
    records, total = services.store.list_cameras(None, limit, offset, owners=[user.id, SHARED])
    return CameraList(
        cameras=[_public(r, base, user) for r in records],
        numberMatched=total,
        links=[Link(href=f"{base}cameras", rel="self", type="application/json")],
    )


@router.post(
    "",
    status_code=201,
    response_model=CameraPublic,
    dependencies=JSON_BODY,
    responses={**problem_responses(401, 403, 413, 415, 422)},
)
def create_camera(
    body: CameraCreate, user: CurrentUser, services: ServicesDep, base: BaseUrl
) -> JSONResponse:
    """Store a camera definition as the next version of its name in your namespace (or, with
    ``shared``, in the shared namespace)."""
    owner = _owner_for_write(user, body.shared, body.name, services.store)
    rec = _store_camera(services, user, body.name, body.description, _definition(body.definition), owner=owner)
    return _created(rec, base, user)


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
    """Save the camera a self-calibration job of yours estimated (IOP values and covariance)
    as the next version of ``name`` in your namespace."""
    job = services.jobs.get_visible(body.job_id, user)
    if job.status != JobStatus.successful:
        # the job's own failure (a worker crash is a 500) is not this request's error
        raise Conflict(f"job {job.id} is {job.status.value}: it has no report to take a camera from")
    report = json.loads(results_text(job))
    if report.get("kind") == "comparison":
        raise Conflict("a model comparison does not yield one camera; use an adjustment job")
    try:
        estimated = camera_from_report((job.document or {}).get("job", {}), report, body.camera)
    except NoEstimatedCamera as exc:
        raise NotFound(str(exc)) from None
    # a library definition has no id and no ref (the job's camera may have come from the library)
    definition = _definition(CameraDefinition.model_validate({k: v for k, v in estimated.items() if k != "ref"}))
    rec = _store_camera(services, user, body.name, body.description, definition, source_job=job.id)
    return _created(rec, base, user)


@router.post(
    "/{name}/share",
    status_code=201,
    response_model=CameraPublic,
    dependencies=JSON_BODY,
    responses={**problem_responses(401, 403, 404, 415, 422)},
)
def share_camera(
    name: Name,
    user: CurrentUser,
    services: ServicesDep,
    base: BaseUrl,
    body: CameraShare | None = None,
) -> JSONResponse:
    """Publish a version of your camera ``name`` (the latest unless ``version`` is given) as
    the next version of ``shared/name``, which every user can read and reference."""
    version = body.version if body else None
    rec = services.store.get_camera(name, version, owner=user.id)
    if rec is None:
        which = f" version {version}" if version else ""
        raise NotFound(f"you have no camera {name!r}{which}")
    check_may_publish(services.store, user, name)
    shared = _store_camera(services, user, name, rec.description, rec.definition, source_job=rec.source_job, owner=SHARED)
    return _created(shared, base, user)


def _get(services: Services, user: UserRecord, name: str, base: str) -> CameraPublic:
    rec = find_camera(services.store, user.id, name)
    if rec is None:
        raise NotFound(f"the camera library has no {name!r}")
    return _public(rec, base, user)


def _versions(
    services: Services, user: UserRecord, name: str, base: str, limit: int, offset: int
) -> CameraList:
    owner, bare = namespace_of(services.store, user.id, name)
    records, total = services.store.list_cameras(bare, limit, offset, owners=[owner])
    if total == 0:
        raise NotFound(f"the camera library has no {name!r}")
    return CameraList(
        cameras=[_public(r, base, user) for r in records],
        numberMatched=total,
        links=[Link(href=f"{base}cameras/{name}/versions", rel="self", type="application/json")],
    )


def _version(
    services: Services, user: UserRecord, name: str, version: int, base: str
) -> CameraPublic:
    rec = find_camera(services.store, user.id, name, version)
    if rec is None:
        raise NotFound(f"the camera library has no {name!r} version {version}")
    return _public(rec, base, user)


# the shared namespace's paths come first: "shared" is not a valid camera name
@router.get(
    "/shared/{name}",
    response_model=CameraPublic,
    response_model_exclude_none=True,
    responses={**problem_responses(401, 404)},
)
def get_shared_camera(
    name: Name, user: CurrentUser, services: ServicesDep, base: BaseUrl
) -> CameraPublic:
    """The latest version of a shared camera."""
    return _get(services, user, SHARED_PREFIX + name, base)


@router.get(
    "/shared/{name}/versions",
    response_model=CameraList,
    response_model_exclude_none=True,
    responses={**problem_responses(401, 404)},
)
def list_shared_versions(
    name: Name,
    user: CurrentUser,
    services: ServicesDep,
    base: BaseUrl,
    limit: VersionLimit = 10,
    offset: Offset = 0,
) -> CameraList:
    """Every version of a shared camera, newest first (paginated)."""
    return _versions(services, user, SHARED_PREFIX + name, base, limit, offset)


@router.get(
    "/shared/{name}/versions/{version}",
    response_model=CameraPublic,
    response_model_exclude_none=True,
    responses={**problem_responses(401, 404)},
)
def get_shared_camera_version(
    name: Name, version: Version, user: CurrentUser, services: ServicesDep, base: BaseUrl
) -> CameraPublic:
    """One version of a shared camera."""
    return _version(services, user, SHARED_PREFIX + name, version, base)


@router.get(
    "/{name}",
    response_model=CameraPublic,
    response_model_exclude_none=True,
    responses={**problem_responses(401, 404)},
)
def get_camera(name: Name, user: CurrentUser, services: ServicesDep, base: BaseUrl) -> CameraPublic:
    """The latest version of your camera ``name``, else of the shared one."""
    return _get(services, user, name, base)


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
    limit: VersionLimit = 10,
    offset: Offset = 0,
) -> CameraList:
    """Every version of your camera ``name`` (else of the shared one), newest first (paginated)."""
    return _versions(services, user, name, base, limit, offset)


@router.get(
    "/{name}/versions/{version}",
    response_model=CameraPublic,
    response_model_exclude_none=True,
    responses={**problem_responses(401, 404)},
)
def get_camera_version(
    name: Name, version: Version, user: CurrentUser, services: ServicesDep, base: BaseUrl
) -> CameraPublic:
    """One version of your camera ``name`` (else of the shared one)."""
    return _version(services, user, name, version, base)
