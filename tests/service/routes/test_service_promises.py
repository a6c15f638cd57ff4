"""Small promises of the HTTP API (in process, no workers): links never built from a client's
Host header, no string coercion in admin and share bodies, 405 answers listing every method of
the path, no events of a dismissed job, a shared camera not showing its publisher's job."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator

import pytest
from fastapi.testclient import TestClient
from test_service_api import assert_problem, body, make_client

from service.auth import create_key
from service.settings import Settings
from service.store import SHARED, open_store

CAMERA = {"focal_mm": 1939.0, "pixel_mm": 0.0071, "line_time_s": 0.00037, "lines": 1000, "columns": 1000}


@pytest.fixture
def keyed(tmp_path: Path) -> Iterator[tuple[TestClient, dict[str, dict[str, str]]]]:
    with make_client(tmp_path, require_api_keys=True) as c:
        store = open_store(Settings(data_dir=tmp_path).resolved_database_url)
        keys = {u: create_key(store, u, is_admin=(u == "root"))[0] for u in ("alice", "bob", "root")}
        alice = store.create_user("alice")
        store.add_camera("pub", "", CAMERA, alice.id, source_job="job-of-alice", owner=SHARED)
        store.close()
        yield c, {u: {"X-API-Key": k} for u, k in keys.items()}


def test_links_ignore_an_untrusted_host_header(tmp_path: Path) -> None:
    with make_client(tmp_path) as c:
        r = c.get("/jobs", headers={"Host": "evil.example"})
        assert r.status_code == 200
        assert all("evil.example" not in link["href"] for link in r.json()["links"]), r.json()["links"]
    with make_client(tmp_path, trusted_hosts="pba.example") as c:
        links = c.get("/jobs", headers={"Host": "pba.example"}).json()["links"]
        assert links[0]["href"].startswith("http://pba.example/")
    with make_client(tmp_path, public_url="https://pba.example.org/base") as c:
        links = c.get("/jobs", headers={"Host": "evil.example"}).json()["links"]
        assert links[0]["href"].startswith("https://pba.example.org/base/jobs")


@pytest.mark.parametrize("field, value", [("weight", "2"), ("max_queued_jobs", "5"), ("max_running_jobs", True), ("max_queued_jobs", 5.0)])
def test_admin_patch_refuses_coerced_values(keyed: Any, field: str, value: Any) -> None:
    c, h = keyed
    assert_problem(c.patch("/admin/users/alice", json={field: value}, headers=h["root"]), 422)
    assert c.patch("/admin/users/alice", json={"weight": 2}, headers=h["root"]).status_code == 200


@pytest.mark.parametrize("version", ["1", True, 1.0])
def test_share_body_refuses_coerced_versions(keyed: Any, version: Any) -> None:
    c, h = keyed
    assert c.post("/cameras", json={"name": "mine", "definition": CAMERA}, headers=h["alice"]).status_code == 201
    assert_problem(c.post("/cameras/mine/share", json={"version": version}, headers=h["alice"]), 422)


def test_method_not_allowed_lists_every_method_of_the_path(keyed: Any, small_doc: dict[str, Any]) -> None:
    c, h = keyed
    r = c.post("/processes/bundle-adjustment/execution", json=body(small_doc), headers={**h["alice"], "Prefer": "respond-async"})
    job = r.json()["jobID"]
    r = c.options(f"/jobs/{job}", headers=h["alice"])
    assert r.status_code == 405
    assert {"GET", "DELETE"} <= {m.strip() for m in r.headers["allow"].split(",")}


def test_a_dismissed_job_has_no_events(keyed: Any, small_doc: dict[str, Any]) -> None:
    c, h = keyed
    r = c.post("/processes/bundle-adjustment/execution", json=body(small_doc), headers={**h["alice"], "Prefer": "respond-async"})
    job = r.json()["jobID"]
    assert c.delete(f"/jobs/{job}", headers=h["alice"]).json()["status"] == "dismissed"
    assert_problem(c.get(f"/jobs/{job}/events", headers=h["alice"]), 404)


def test_a_shared_camera_hides_the_publishers_job(keyed: Any) -> None:
    c, h = keyed
    assert "source_job" not in c.get("/cameras/shared/pub", headers=h["bob"]).json()
    assert all("source_job" not in v for v in c.get("/cameras/shared/pub/versions", headers=h["bob"]).json()["cameras"])
    assert c.get("/cameras/shared/pub", headers=h["alice"]).json()["source_job"] == "job-of-alice"
