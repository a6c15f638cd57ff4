"""The camera library: namespaces, resolving ``ref`` cameras of a job, and cameras from
self-calibration.

Namespaces: every camera name lives in the namespace of the user who created it, or in the
shared namespace (read-only for users; the owner of a camera or an admin publishes to it, see
:func:`check_may_publish`). A name is looked up in the user's own namespace first, then in
the shared one (own wins on a clash); ``shared/NAME`` addresses the shared namespace
explicitly. Another user's unshared camera is not found (404), so names do not leak. Without
keys (local single-user mode) the only user owns every camera, as before namespaces existed.

A job camera with ``ref: {name, version}`` takes every field from that library version;
fields the job sets itself override the library's. The resolved camera keeps ``ref`` (with
the namespace-qualified name and the version actually used) for provenance.
"""

from __future__ import annotations

import logging
from typing import Any

from pydantic import ValidationError

from service.errors import Forbidden, InvalidInput
from service.problems import json_pointer, pydantic_errors
from service.store import SHARED, CameraRecord, Store, UserRecord
from solver.importers.presets import PRESETS
from solver.schema.job import Camera, Job

log = logging.getLogger("pba.service")

JOB_CAMERA_FIELDS = frozenset(Camera.model_fields) - {"id", "ref"}
SHARED_PREFIX = SHARED + "/"
PRESETS_CREATOR = "presets"  # created_by of the sensor presets' versions


def ensure_presets(store: Store) -> list[str]:
    """Publish the sensor presets (:mod:`solver.importers.presets`) in the shared namespace:
    every preset version the store does not have yet is added, in order, so ``prism-nadir``
    version N of the library is preset version N on every server. A shared name already
    published by someone else is left alone (logged). Returns the names added to."""
    added: list[str] = []
    for name, versions in PRESETS.items():
        stored, _ = store.list_cameras(name, 1000, 0, owners=[SHARED])
        if any(r.created_by != PRESETS_CREATOR for r in stored):
            log.warning("shared camera %r was published by a user: the preset of that name is not added", name)
            continue
        for number, preset in enumerate(versions[len(stored) :], start=len(stored) + 1):
            # exactly version ``number``: servers starting at once cannot store a preset twice
            if store.add_camera_version(
                name,
                number,
                f"{preset.description}. Source: {preset.source}",
                preset.definition,
                PRESETS_CREATOR,
                owner=SHARED,
            ):
                added.append(name)
    return added


def namespace_of(store: Store, user_id: str, name: str) -> tuple[str, str]:
    """(namespace, bare name) that ``name`` means for a user: ``shared/NAME`` the shared
    namespace; otherwise the user's own when it has a camera of that name, else shared."""
    if name.startswith(SHARED_PREFIX):
        return SHARED, name[len(SHARED_PREFIX) :]
    if store.get_camera(name, owner=user_id) is not None:
        return user_id, name
    return SHARED, name


def find_camera(
    store: Store, user_id: str, name: str, version: int | None = None
) -> CameraRecord | None:
    """The camera version ``name`` means for a user (latest when ``version`` is None)."""
    owner, bare = namespace_of(store, user_id, name)
    return store.get_camera(bare, version, owner=owner)


def qualified_name(rec: CameraRecord) -> str:
    """The name that addresses ``rec`` from any user's view (``shared/NAME`` when shared)."""
    return SHARED_PREFIX + rec.name if rec.shared else rec.name


def check_may_publish(store: Store, user: UserRecord, name: str) -> None:
    """Forbidden unless ``user`` may add a version of ``name`` to the shared namespace: an
    admin always; another user when the shared name is new or was first published by them."""
    if user.is_admin:
        return
    first = store.get_camera(name, 0, owner=SHARED)
    if first is not None and first.created_by != user.id:
        raise Forbidden(
            f"the shared camera {name!r} was published by another user; only they or an admin "
            "add versions to it (publish under another name)"
        )


def resolve_camera_refs(
    job: Job, store: Store, user_id: str, prefix: tuple[str, ...] = ("inputs", "job")
) -> Job:
    """A copy of ``job`` whose ref cameras are complete, each ref resolved in the namespaces
    of user ``user_id`` (:func:`find_camera`); InvalidInput on unknown refs."""
    if not any(c.ref is not None for c in job.cameras):
        return job
    errors: list[dict[str, Any]] = []
    cameras: list[dict[str, Any]] = []
    for i, cam in enumerate(job.cameras):
        if cam.ref is None:
            cameras.append(cam.model_dump(mode="json"))
            continue
        rec = find_camera(store, user_id, cam.ref.name, cam.ref.version)
        if rec is None:
            which = f"version {cam.ref.version}" if cam.ref.version else "any version"
            errors.append(
                {
                    "pointer": json_pointer([*prefix, "cameras", i, "ref"]),
                    "code": "unknown_camera",
                    "message": f"the camera library has no {cam.ref.name!r} ({which})",
                }
            )
            continue
        base = {k: v for k, v in rec.definition.items() if k in JOB_CAMERA_FIELDS}
        own = cam.model_dump(mode="json", exclude_unset=True, exclude={"id", "ref"})
        cameras.append(
            {
                **base,
                **own,
                "id": cam.id,
                "ref": {"name": qualified_name(rec), "version": rec.version},
            }
        )
    if errors:
        raise InvalidInput("camera references could not be resolved", errors)
    data = job.model_dump(mode="json")
    data["cameras"] = cameras
    try:
        return Job.model_validate(data)
    except ValidationError as exc:
        raise InvalidInput(
            "a camera completed from the library is invalid", pydantic_errors(exc.errors(), prefix)
        ) from None


def camera_links(rec: CameraRecord, base_url: str) -> list[dict[str, str]]:
    """Links of a camera version (``cameras/shared/NAME/...`` for shared ones)."""
    path = f"{base_url}cameras/{qualified_name(rec)}"
    return [
        {
            "href": f"{path}/versions/{rec.version}",
            "rel": "self",
            "type": "application/json",
        },
        {
            "href": path,
            "rel": "latest-version",
            "type": "application/json",
        },
    ]
