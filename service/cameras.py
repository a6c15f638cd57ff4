"""The camera library: resolving ``ref`` cameras of a job, and cameras from self-calibration.

A job camera with ``ref: {name, version}`` takes every field from that library version;
fields the job sets itself override the library's. The resolved camera keeps ``ref`` (with
the version actually used) for provenance.
"""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from service.errors import InvalidInput, NotFound
from service.problems import json_pointer, pydantic_errors
from service.store import CameraRecord, Store
from solver.job import Camera, Job

JOB_CAMERA_FIELDS = frozenset(Camera.model_fields) - {"id", "ref"}


def resolve_camera_refs(job: Job, store: Store, prefix: tuple[str, ...] = ("inputs", "job")) -> Job:
    """A copy of ``job`` whose ref cameras are complete; InvalidInput on unknown refs."""
    if not any(c.ref is not None for c in job.cameras):
        return job
    errors: list[dict[str, Any]] = []
    cameras: list[dict[str, Any]] = []
    for i, cam in enumerate(job.cameras):
        if cam.ref is None:
            cameras.append(cam.model_dump(mode="json"))
            continue
        rec = store.get_camera(cam.ref.name, cam.ref.version)
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
            {**base, **own, "id": cam.id, "ref": {"name": rec.name, "version": rec.version}}
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


def camera_from_report(
    document: dict[str, Any], report: dict[str, Any], camera_id: str
) -> dict[str, Any]:
    """A library definition from a finished job: the job's camera with the estimated
    interior orientation (values and covariance) the report gives for it.

    Reads ``report["cameras"]``: ``[{"id", "iop": {name: value}, "iop_covariance": {"names",
    "matrix"}}]``; a report without an entry for the camera did not estimate its interior
    orientation (NotFound).
    """
    job = document.get("job", {})
    cams = {c.get("id"): c for c in job.get("cameras", [])}
    if camera_id not in cams:
        raise NotFound(f"the job has no camera {camera_id!r}")
    definition = {k: v for k, v in cams[camera_id].items() if k in JOB_CAMERA_FIELDS}
    estimated = {c.get("id"): c for c in (report.get("cameras") or []) if isinstance(c, dict)}
    entry = estimated.get(camera_id)
    if not entry or not entry.get("iop"):
        raise NotFound(
            f"the job's report has no estimated interior orientation for camera {camera_id!r} "
            "(was it a self-calibration job?)"
        )
    definition["iop"] = {**definition.get("iop", {}), **entry["iop"]}
    if entry.get("iop_covariance"):
        definition["iop_covariance"] = entry["iop_covariance"]
    return definition


def camera_links(rec: CameraRecord, base_url: str) -> list[dict[str, str]]:
    """Links of a camera version."""
    return [
        {
            "href": f"{base_url}cameras/{rec.name}/versions/{rec.version}",
            "rel": "self",
            "type": "application/json",
        },
        {
            "href": f"{base_url}cameras/{rec.name}",
            "rel": "latest-version",
            "type": "application/json",
        },
    ]
