"""Camera namespaces with keys required (issue 13): each camera belongs to its user; other
users see it only once it is shared; refs resolve in the own namespace, then the shared one.
In-process server without workers (jobs stay accepted; their stored documents show which
camera a ref resolved to)."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any, Iterator

import pytest
from fastapi.testclient import TestClient
from test_service_api import assert_problem, body, make_client

from service.auth import create_key
from service.settings import Settings
from service.store import open_store
from solver.importers.presets import PRESETS

N_PRESETS = len(PRESETS)  # the sensor presets every server publishes in the shared namespace

EXECUTE = "/processes/bundle-adjustment/execution"


@pytest.fixture
def lab(tmp_path: Path) -> Iterator[tuple[TestClient, dict[str, dict[str, str]]]]:
    """Keys required; alice and bob (users) and root (admin); their request headers."""
    with make_client(tmp_path, require_api_keys=True) as c:
        store = open_store(Settings(data_dir=tmp_path).resolved_database_url)
        keys = {
            "alice": create_key(store, "alice")[0],
            "bob": create_key(store, "bob")[0],
            "root": create_key(store, "root", is_admin=True)[0],
        }
        store.close()
        yield c, {user: {"X-API-Key": key} for user, key in keys.items()}


def definition(triplet_doc: dict[str, Any], focal_mm: float) -> dict[str, Any]:
    """The triplet's first camera as a library definition with a recognisable focal length."""
    d = {k: v for k, v in triplet_doc["cameras"][0].items() if k != "id"}
    d["focal_mm"] = focal_mm
    return d


def post_camera(
    c: TestClient,
    headers: dict[str, str],
    triplet_doc: dict[str, Any],
    name: str,
    focal_mm: float,
    **fields: Any,
) -> Any:
    """``POST /cameras`` of the triplet's first camera with ``focal_mm`` as ``name``."""
    request = {"name": name, "definition": definition(triplet_doc, focal_mm), **fields}
    return c.post("/cameras", json=request, headers=headers)


def resolved_camera(
    c: TestClient, headers: dict[str, str], triplet_doc: dict[str, Any], ref: dict[str, Any]
) -> dict[str, Any]:
    """Submit the triplet with its first camera replaced by ``ref``; the stored camera."""
    job = copy.deepcopy(triplet_doc)
    job["cameras"][0] = {"id": job["cameras"][0]["id"], "ref": ref}
    r = c.post(EXECUTE, json=body(job), headers=headers)
    assert r.status_code == 201, r.text
    store = c.app.state.services.store  # type: ignore[attr-defined]
    return store.get_document(r.json()["jobID"])["job"]["cameras"][0]


def ref_problem(
    c: TestClient, headers: dict[str, str], triplet_doc: dict[str, Any], ref: dict[str, Any]
) -> None:
    job = copy.deepcopy(triplet_doc)
    job["cameras"][0] = {"id": job["cameras"][0]["id"], "ref": ref}
    for path in (EXECUTE, "/jobs/validate"):
        r = c.post(path, json=body(job), headers=headers)
        assert_problem(r, 422, "/inputs/job/cameras/0/ref")


def test_another_users_camera_is_invisible(
    lab: tuple[TestClient, dict[str, dict[str, str]]], triplet_doc: dict[str, Any]
) -> None:
    c, h = lab
    r = post_camera(c, h["bob"], triplet_doc, "bcam", 1.0)
    assert r.status_code == 201 and r.json()["shared"] is False
    # read, versions, one version, list, shared path: 404 / nothing, as if it did not exist
    for path in (
        "/cameras/bcam",
        "/cameras/bcam/versions",
        "/cameras/bcam/versions/1",
        "/cameras/shared/bcam",
        "/cameras/shared/bcam/versions",
        "/cameras/shared/bcam/versions/1",
    ):
        assert_problem(c.get(path, headers=h["alice"]), 404)
    assert c.get("/cameras", headers=h["alice"]).json()["numberMatched"] == N_PRESETS
    assert c.get("/cameras", headers=h["bob"]).json()["numberMatched"] == 1 + N_PRESETS
    # a job of alice cannot reference it, by either name
    ref_problem(c, h["alice"], triplet_doc, {"name": "bcam"})
    ref_problem(c, h["alice"], triplet_doc, {"name": "bcam", "version": 1})
    ref_problem(c, h["alice"], triplet_doc, {"name": "shared/bcam"})
    # alice cannot share it (it is not hers) and an admin does not see it either
    assert_problem(c.post("/cameras/bcam/share", headers=h["alice"]), 404)
    assert_problem(c.get("/cameras/bcam", headers=h["root"]), 404)


def test_posting_the_same_name_does_not_touch_the_owners_camera(
    lab: tuple[TestClient, dict[str, dict[str, str]]], triplet_doc: dict[str, Any]
) -> None:
    """The reported attack: alice posts bob's name; bob's jobs keep running bob's camera."""
    c, h = lab
    post_camera(c, h["bob"], triplet_doc, "bcam", 1.0)
    r = post_camera(c, h["alice"], triplet_doc, "bcam", 2.0)
    assert r.status_code == 201 and r.json()["version"] == 1  # alice's own bcam, version 1
    got = c.get("/cameras/bcam", headers=h["bob"]).json()
    assert (got["version"], got["definition"]["focal_mm"]) == (1, 1.0)
    assert c.get("/cameras/bcam/versions", headers=h["bob"]).json()["numberMatched"] == 1
    cam = resolved_camera(c, h["bob"], triplet_doc, {"name": "bcam"})
    assert cam["focal_mm"] == 1.0 and cam["ref"] == {"name": "bcam", "version": 1}
    cam = resolved_camera(c, h["alice"], triplet_doc, {"name": "bcam"})
    assert cam["focal_mm"] == 2.0


def test_shared_namespace(
    lab: tuple[TestClient, dict[str, dict[str, str]]], triplet_doc: dict[str, Any]
) -> None:
    c, h = lab
    post_camera(c, h["bob"], triplet_doc, "prism", 1.0, description="bob's")
    r = c.post("/cameras/prism/share", headers=h["bob"])
    assert r.status_code == 201, r.text
    assert r.json()["shared"] is True and r.json()["version"] == 1
    assert r.headers["location"].endswith("/cameras/shared/prism/versions/1")
    # alice reads and references it (own namespace first: she has no prism)
    got = c.get("/cameras/prism", headers=h["alice"]).json()
    assert got["shared"] is True and got["description"] == "bob's"
    assert c.get("/cameras/shared/prism/versions/1", headers=h["alice"]).status_code == 200
    assert c.get("/cameras/prism/versions", headers=h["alice"]).json()["numberMatched"] == 1
    listed = c.get("/cameras", headers=h["alice"]).json()["cameras"]
    assert [(x["name"], x["shared"]) for x in listed if x["name"] not in PRESETS] == [("prism", True)]
    cam = resolved_camera(c, h["alice"], triplet_doc, {"name": "prism"})
    assert cam["focal_mm"] == 1.0 and cam["ref"] == {"name": "shared/prism", "version": 1}
    # the shared namespace is read-only for alice: no new version under bob's shared name
    assert_problem(
        post_camera(c, h["alice"], triplet_doc, "prism", 9.0, shared=True),
        403,
    )
    post_camera(c, h["alice"], triplet_doc, "prism", 2.0)
    assert_problem(c.post("/cameras/prism/share", headers=h["alice"]), 403)
    assert c.get("/cameras/shared/prism", headers=h["bob"]).json()["version"] == 1
    # name clash: alice's own prism wins; shared/prism still reaches the shared one
    got = c.get("/cameras/prism", headers=h["alice"]).json()
    assert got["shared"] is False and got["definition"]["focal_mm"] == 2.0
    assert resolved_camera(c, h["alice"], triplet_doc, {"name": "prism"})["focal_mm"] == 2.0
    cam = resolved_camera(c, h["alice"], triplet_doc, {"name": "shared/prism", "version": 1})
    assert cam["focal_mm"] == 1.0
    assert c.get("/cameras", headers=h["alice"]).json()["numberMatched"] == 2 + N_PRESETS
    # the publisher and an admin add versions to the shared name
    post_camera(c, h["bob"], triplet_doc, "prism", 3.0)
    assert c.post("/cameras/prism/share", headers=h["bob"]).json()["version"] == 2
    r = post_camera(c, h["root"], triplet_doc, "prism", 4.0, shared=True)
    assert r.status_code == 201 and r.json()["version"] == 3 and r.json()["shared"] is True
    r = c.post("/cameras/prism/share", json={"version": 1}, headers=h["bob"])
    assert r.json()["version"] == 4 and r.json()["definition"]["focal_mm"] == 1.0
    assert_problem(c.post("/cameras/prism/share", json={"version": 7}, headers=h["bob"]), 404)
    # bob's own versions were untouched by all this
    assert c.get("/cameras/prism/versions", headers=h["bob"]).json()["numberMatched"] == 2
    # "shared" is not a camera name
    assert_problem(
        post_camera(c, h["bob"], triplet_doc, "shared", 1.0),
        422,
        "/name",
    )


def test_camera_from_another_users_job(
    lab: tuple[TestClient, dict[str, dict[str, str]]], triplet_doc: dict[str, Any]
) -> None:
    """from-job reads only the caller's jobs and writes only the caller's namespace. The job
    is finished through the store with a report naming an estimated IOP (what a
    self-calibration writes; the real solve of from-job is covered in test_service_e2e)."""
    c, h = lab
    r = c.post(EXECUTE, json=body(triplet_doc), headers=h["bob"])
    job_id, cam_id = r.json()["jobID"], triplet_doc["cameras"][0]["id"]
    store = c.app.state.services.store  # type: ignore[attr-defined]
    assert store.claim(job_id, "w") is not None
    report = {"cameras": [{"id": cam_id, "iop": {"df": 0.001}}]}
    assert store.complete(job_id, "w", json.dumps(report), "done")
    request = {"job_id": job_id, "camera": cam_id, "name": "calib"}
    assert_problem(c.post("/cameras/from-job", json=request, headers=h["alice"]), 404)
    r = c.post("/cameras/from-job", json=request, headers=h["bob"])
    assert r.status_code == 201 and r.json()["shared"] is False, r.text
    stored = c.get("/cameras/calib", headers=h["bob"]).json()
    assert stored["source_job"] == job_id
    # the job's camera with the estimate, as a library definition: no id, no ref
    assert stored["definition"]["iop"]["df"] == 0.001 and not {"id", "ref"} & set(stored["definition"])
    assert stored["definition"]["focal_mm"] == triplet_doc["cameras"][0]["focal_mm"]
    assert_problem(c.get("/cameras/calib", headers=h["alice"]), 404)
    missing = assert_problem(c.post("/cameras/from-job", json={**request, "camera": "nope"}, headers=h["bob"]), 404)
    assert "no camera 'nope'" in missing["detail"]


def test_single_user_mode_owns_and_shares(tmp_path: Path, triplet_doc: dict[str, Any]) -> None:
    """Without keys the local user owns every camera; refs resolve as before."""
    with make_client(tmp_path) as c:
        r = post_camera(c, {}, triplet_doc, "cam", 5.0)
        assert r.status_code == 201 and r.json()["shared"] is False
        assert c.get("/cameras/cam").json()["version"] == 1
        cam = resolved_camera(c, {}, triplet_doc, {"name": "cam"})
        assert cam["ref"] == {"name": "cam", "version": 1}
        assert c.post("/cameras/cam/share").json()["shared"] is True


def test_camera_from_a_failed_job_is_a_conflict_not_the_jobs_error(
    lab: tuple[TestClient, dict[str, dict[str, str]]], triplet_doc: dict[str, Any]
) -> None:
    """A job failed by a worker crash carries a 500 problem; from-job on it is the caller's
    conflict (409), not a server error (schemathesis found the 500 relayed)."""
    c, h = lab
    r = c.post(EXECUTE, json=body(triplet_doc), headers=h["bob"])
    job_id, cam_id = r.json()["jobID"], triplet_doc["cameras"][0]["id"]
    store = c.app.state.services.store  # type: ignore[attr-defined]
    assert store.claim(job_id, "w") is not None
    assert store.fail(job_id, "the worker process running this job was killed by SIGKILL", {"code": "worker_died"})
    request = {"job_id": job_id, "camera": cam_id, "name": "calib"}
    assert_problem(c.post("/cameras/from-job", json=request, headers=h["bob"]), 409)
