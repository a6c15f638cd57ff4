"""The HTTP API in-process (no worker processes, PBA_WORKERS=0): capabilities, local mode and
keys, problem documents for bad input, limits, camera library, CORS.

Jobs that pass validation are stored and stay accepted here; solving is tested end to end
against a real server in test_service_e2e.py.
"""

from __future__ import annotations

import copy
import json
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Iterator

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.auth import create_key
from service.settings import Settings
from service.store import open_store
from solver.importers.presets import PRESETS

PROBLEM = "application/problem+json"


def make_client(tmp_path: Path, **overrides: Any) -> TestClient:
    settings = Settings(data_dir=tmp_path, workers=0, log_format="text", **overrides)
    return TestClient(create_app(settings), raise_server_exceptions=False)


@pytest.fixture
def local(tmp_path: Path) -> Iterator[TestClient]:
    """Local single-user mode (bound to 127.0.0.1, no keys)."""
    with make_client(tmp_path, max_body_bytes=200_000) as c:
        yield c


@pytest.fixture
def keyed(tmp_path: Path) -> Iterator[tuple[TestClient, dict[str, str]]]:
    """Keys required; alice (queued limit 1, 200 observations max) and an admin."""
    with make_client(tmp_path, require_api_keys=True) as c:
        store = open_store(Settings(data_dir=tmp_path).resolved_database_url)
        keys = {
            "alice": create_key(store, "alice", max_queued_jobs=1, max_job_observations=200)[0],
            "bob": create_key(store, "bob")[0],
        }
        store.close()
        yield c, keys


def body(job: dict[str, Any], **inputs: Any) -> dict[str, Any]:
    """An execute request with a copy of ``job`` (session fixtures stay untouched)."""
    return {"inputs": {"job": copy.deepcopy(job), **inputs}}


def assert_problem(r: Any, status: int, pointer: str | None = None) -> dict[str, Any]:
    assert r.status_code == status, r.text[:1000]
    assert r.headers["content-type"].startswith(PROBLEM)
    doc = r.json()
    assert doc["status"] == status and doc["title"] and doc["type"]
    if pointer is not None:
        assert pointer in [e["pointer"] for e in doc.get("errors", [])], doc
    return doc


# -- settings and keys ---------------------------------------------------------------------
def test_keys_required_unless_bound_to_loopback() -> None:
    assert not Settings(host="127.0.0.1").auth_required
    assert not Settings(host="::1").auth_required
    assert Settings(host="0.0.0.0").auth_required
    assert Settings(host="192.168.1.10").auth_required
    assert Settings(host="127.0.0.1", require_api_keys=True).auth_required


def test_settings_from_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("PBA_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("PBA_WORKERS", "3")
    monkeypatch.setenv("PBA_CORS_ORIGINS", "http://a.example, http://b.example")
    monkeypatch.setenv("PBA_JOB_TIME_LIMIT_S", "12.5")
    s = Settings()
    assert (s.workers, s.job_time_limit_s) == (3, 12.5)
    assert s.cors_origins == ["http://a.example", "http://b.example"]
    assert s.resolved_database_url == f"sqlite:///{(tmp_path / 'pba.sqlite3').resolve()}"


def test_local_mode_needs_no_key(local: TestClient) -> None:
    assert local.get("/jobs").status_code == 200
    assert_problem(local.get("/jobs", headers={"X-API-Key": "pba_bad_key"}), 401)


def test_keys_required_mode(keyed: tuple[TestClient, dict[str, str]]) -> None:
    c, keys = keyed
    assert_problem(c.get("/jobs"), 401)
    assert_problem(c.get("/jobs", headers={"X-API-Key": "wrong"}), 401)
    assert c.get("/jobs", headers={"X-API-Key": keys["bob"]}).status_code == 200
    assert c.get("/jobs", headers={"Authorization": f"Bearer {keys['bob']}"}).status_code == 200
    assert c.get(f"/jobs?api_key={keys['bob']}").status_code == 200
    # public capabilities need no key
    assert c.get("/").status_code == 200 and c.get("/conformance").status_code == 200


# -- capabilities ------------------------------------------------------------------------
def test_landing_conformance_processes(local: TestClient) -> None:
    links = {link["rel"]: link["href"] for link in local.get("/").json()["links"]}
    assert {"self", "service-desc", "http://www.opengis.net/def/rel/ogc/1.0/processes"} <= set(
        links
    )
    conf = local.get("/conformance").json()["conformsTo"]
    assert "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/core" in conf
    ids = [p["id"] for p in local.get("/processes").json()["processes"]]
    assert ids == ["bundle-adjustment", "model-comparison", "preanalysis", "match"]
    desc = local.get("/processes/bundle-adjustment").json()
    assert desc["inputs"]["job"]["schema"]["title"] == "Job"
    assert "report" in desc["outputs"]
    comparison = local.get("/processes/model-comparison").json()
    assert "K2" in comparison["inputs"]["models"]["schema"]["items"]["enum"]
    assert_problem(local.get("/processes/nope"), 404)
    assert_problem(local.post("/processes/nope/execution", json={"inputs": {}}), 422)
    assert_problem(local.get("/jobs/no-such-job"), 404)
    assert_problem(local.get("/no/such/path"), 404)
    assert_problem(local.put("/jobs"), 405)
    health = local.get("/healthz").json()
    assert health["status"] == "ok" and set(health["checks"]) == {"evaluation"}
    # make test builds the compiled cost functions: the health endpoint must say so
    assert health["checks"]["evaluation"] == "compiled" or os.environ.get("PBA_REQUIRE_NATIVE") != "1", health
    assert local.get("/readyz").status_code == 200


# -- bad input -------------------------------------------------------------------------
def test_malformed_json_and_nan_are_400(local: TestClient) -> None:
    headers = {"content-type": "application/json"}
    for raw in (
        b'{"inputs": {"job": ',
        b"not json",
        b'{"inputs": {"job": NaN}}',
        b'{"a": Infinity}',
    ):
        assert_problem(
            local.post("/processes/bundle-adjustment/execution", content=raw, headers=headers), 400
        )
        assert_problem(local.post("/jobs/validate", content=raw, headers=headers), 400)


def test_nan_inside_the_job_is_refused(local: TestClient, triplet_doc: dict[str, Any]) -> None:
    job = copy.deepcopy(triplet_doc)
    job["observations"][0]["line"] = 481.25  # a value to find in the text
    text = json.dumps(body(job)).replace('"line": 481.25', '"line": NaN', 1)
    assert "NaN" in text
    r = local.post("/jobs/validate", content=text, headers={"content-type": "application/json"})
    assert_problem(r, 400)


def test_schema_errors_point_at_the_field(local: TestClient, triplet_doc: dict[str, Any]) -> None:
    job = copy.deepcopy(triplet_doc)
    job["observations"][3]["line"] = "abc"
    job["cameras"][0]["focal_mm"] = -1
    doc = assert_problem(
        local.post("/jobs/validate", json=body(job)), 422, "/inputs/job/observations/3/line"
    )
    assert "/inputs/job/cameras/0/focal_mm" in [e["pointer"] for e in doc["errors"]]
    assert_problem(local.post("/jobs/validate", json={"inputs": {}}), 422, "/inputs/job")
    assert_problem(local.post("/jobs/validate", json=[1, 2]), 422)
    assert_problem(local.post("/jobs/validate", json=body(job, extra=1)), 422, "/inputs/extra")


def test_unknown_model_and_missing_references(
    local: TestClient, triplet_doc: dict[str, Any]
) -> None:
    job = copy.deepcopy(triplet_doc)
    job["images"][1]["model"]["name"] = "NO-SUCH-MODEL"
    job["observations"][5]["point"] = "ghost"
    job["images"][2]["camera"] = "missing-camera"
    for url in ("/jobs/validate", "/processes/bundle-adjustment/execution"):
        doc = assert_problem(
            local.post(url, json=body(job)), 422, "/inputs/job/images/1/model/name"
        )
        pointers = [e["pointer"] for e in doc["errors"]]
        assert "/inputs/job/observations/5/point" in pointers
        assert any(p.startswith("/inputs/job/images/2") for p in pointers)
    assert local.get("/jobs").json()["numberMatched"] == 0  # nothing was queued


def test_comparison_models_are_checked(local: TestClient, triplet_doc: dict[str, Any]) -> None:
    url = "/processes/model-comparison/execution"
    assert_problem(local.post(url, json=body(triplet_doc)), 422, "/inputs/models")
    assert_problem(
        local.post(url, json=body(triplet_doc, models=["K2", "XX"])), 422, "/inputs/models/1"
    )
    assert_problem(
        local.post("/processes/bundle-adjustment/execution", json=body(triplet_doc, models=["K2"])),
        422,
        "/inputs/models",
    )
    r = local.post(
        "/jobs/validate?process=model-comparison", json=body(triplet_doc, models=["K2", "P2"])
    )
    assert r.status_code == 200, r.text


def test_body_over_the_limit_is_413(local: TestClient, triplet_doc: dict[str, Any]) -> None:
    big = body(triplet_doc)
    big["inputs"]["job"]["name"] = "x" * 150
    big["inputs"]["job"]["observations"] = triplet_doc["observations"] * 20
    r = local.post("/jobs/validate", json=big)
    assert_problem(r, 413)

    def chunks() -> Iterator[bytes]:  # no Content-Length: counted while reading
        for _ in range(30):
            yield b" " * 10_000

    assert_problem(
        local.post(
            "/jobs/validate", content=chunks(), headers={"content-type": "application/json"}
        ),
        413,
    )


def test_a_body_with_its_length_streams_through_the_limit() -> None:
    """A body within its declared Content-Length reaches the app chunk by chunk (before, the
    limit held the whole body and replayed it: a 41 MB upload cost 80 MB more of the API
    process's memory); past the limit the app sees a disconnect, never more bytes."""
    import asyncio

    from service.middleware import BodyLimitMiddleware

    def run(length: int, parts: list[bytes]) -> list[dict[str, Any]]:
        seen: list[dict[str, Any]] = []

        async def app(scope: Any, receive: Any, send: Any) -> None:
            while True:
                message = await receive()
                seen.append(message)
                if message["type"] != "http.request" or not message.get("more_body"):
                    return

        incoming = [{"type": "http.request", "body": p, "more_body": k < len(parts) - 1} for k, p in enumerate(parts)]

        async def receive() -> dict[str, Any]:
            return incoming.pop(0)

        async def send(message: Any) -> None:
            raise AssertionError(f"the middleware answered itself: {message}")

        scope = {"type": "http", "method": "POST", "path": "/", "headers": [(b"content-length", str(length).encode())]}
        # a loop of its own in a thread: the suite may already run one in this thread
        with ThreadPoolExecutor(1) as pool:
            pool.submit(asyncio.run, BodyLimitMiddleware(app, max_bytes=100)(scope, receive, send)).result()
        return seen

    assert [m["body"] for m in run(90, [b"a" * 30] * 3)] == [b"a" * 30] * 3  # as they came
    past = run(90, [b"a" * 60] * 2)  # more than the length declared (a server would not deliver it)
    assert past[0]["body"] == b"a" * 60 and past[1] == {"type": "http.disconnect"}


def test_valid_job_validates_and_is_queued(local: TestClient, triplet_doc: dict[str, Any]) -> None:
    r = local.post("/jobs/validate", json=body(triplet_doc))
    assert r.status_code == 200, r.text
    summary = r.json()
    assert summary["valid"] and summary["n_observations"] == 438 and summary["dof"] > 0
    r = local.post("/processes/bundle-adjustment/execution", json=body(triplet_doc))
    assert r.status_code == 201  # no workers: answered asynchronously
    assert r.headers["location"].endswith(f"/jobs/{r.json()['jobID']}")
    st = local.get(f"/jobs/{r.json()['jobID']}").json()
    assert st["status"] == "accepted" and st["progress"] == 0
    assert_problem(local.get(f"/jobs/{st['jobID']}/results"), 404)
    r = local.delete(f"/jobs/{st['jobID']}")
    assert r.status_code == 200 and r.json()["status"] == "dismissed"


# -- limits and ownership ---------------------------------------------------------------
def test_per_user_limits(
    keyed: tuple[TestClient, dict[str, str]], triplet_doc: dict[str, Any]
) -> None:
    c, keys = keyed
    alice = {"X-API-Key": keys["alice"]}
    assert_problem(
        c.post("/processes/bundle-adjustment/execution", json=body(triplet_doc), headers=alice), 413
    )
    small = copy.deepcopy(triplet_doc)
    small["observations"] = small["observations"][:180]
    used = {o["point"] for o in small["observations"]}
    small["points"] = [p for p in small["points"] if p["id"] in used]
    r = c.post("/processes/bundle-adjustment/execution", json=body(small), headers=alice)
    assert r.status_code == 201, r.text
    r = c.post("/processes/bundle-adjustment/execution", json=body(small), headers=alice)
    assert_problem(r, 429)
    # bob neither sees nor cancels alice's job
    bob = {"X-API-Key": keys["bob"]}
    job_id = c.get("/jobs", headers=alice).json()["jobs"][0]["jobID"]
    assert_problem(c.get(f"/jobs/{job_id}", headers=bob), 404)
    assert_problem(c.delete(f"/jobs/{job_id}", headers=bob), 404)
    assert c.get("/jobs", headers=bob).json()["numberMatched"] == 0


# -- cameras ---------------------------------------------------------------------------
def test_camera_library_and_refs(local: TestClient, triplet_doc: dict[str, Any]) -> None:
    definition = {k: v for k, v in triplet_doc["cameras"][0].items() if k != "id"}
    definition["iop"] = {}
    definition["iop_covariance"] = {"names": ["df"], "matrix": [[1e-6]]}
    r = local.post(
        "/cameras", json={"name": "prism-backward", "description": "v1", "definition": definition}
    )
    assert r.status_code == 201, r.text
    assert r.json()["version"] == 1 and r.headers["location"].endswith(
        "/cameras/prism-backward/versions/1"
    )
    definition["focal_mm"] += 0.001
    r = local.post("/cameras", json={"name": "prism-backward", "definition": definition})
    assert r.json()["version"] == 2
    assert local.get("/cameras/prism-backward").json()["version"] == 2
    assert local.get("/cameras/prism-backward/versions/1").json()["description"] == "v1"
    assert local.get("/cameras/prism-backward/versions").json()["numberMatched"] == 2
    # one own camera and the sensor presets of the shared namespace
    assert local.get("/cameras").json()["numberMatched"] == 1 + len(PRESETS)
    assert_problem(local.get("/cameras/none"), 404)
    assert_problem(local.get("/cameras/prism-backward/versions/9"), 404)
    bad = dict(definition, focal_mm="long")
    assert_problem(
        local.post("/cameras", json={"name": "x", "definition": bad}), 422, "/definition/focal_mm"
    )
    bad = dict(definition, iop_covariance={"names": ["a", "b"], "matrix": [[1.0]]})
    assert_problem(local.post("/cameras", json={"name": "x", "definition": bad}), 422)

    job = copy.deepcopy(triplet_doc)
    job["cameras"][0] = {"id": "prism-backward", "ref": {"name": "prism-backward", "version": 1}}
    r = local.post("/jobs/validate", json=body(job))
    assert r.status_code == 200, r.text
    r = local.post("/processes/bundle-adjustment/execution", json=body(job))
    assert r.status_code == 201, r.text
    # the stored document has the resolved camera, with the version used
    store = local.app.state.services.store  # type: ignore[attr-defined]
    stored = store.get_document(r.json()["jobID"])["job"]["cameras"][0]
    assert stored["focal_mm"] == triplet_doc["cameras"][0]["focal_mm"]
    assert stored["ref"] == {"name": "prism-backward", "version": 1}
    job["cameras"][0] = {"id": "prism-backward", "ref": {"name": "unknown-cam"}}
    assert_problem(local.post("/jobs/validate", json=body(job)), 422, "/inputs/job/cameras/0/ref")


def test_cors_origins(tmp_path: Path) -> None:
    with make_client(tmp_path, cors_origins=["http://front.example"]) as c:
        r = c.options(
            "/jobs",
            headers={
                "Origin": "http://front.example",
                "Access-Control-Request-Method": "POST",
                "Access-Control-Request-Headers": "X-API-Key",
            },
        )
        assert r.headers.get("access-control-allow-origin") == "http://front.example"
        r = c.get("/jobs", headers={"Origin": "http://evil.example"})
        assert "access-control-allow-origin" not in r.headers


def test_problem_details_are_strict_json() -> None:
    """Non-finite numbers in a problem's details become null (a 4xx never turns into a 500)."""
    import service.errors
    from solver.report.json_text import json_ready

    assert service.errors.json_ready is json_ready  # the conversion problem documents are written with

    safe = json_ready([{"condition": float("inf"), "nested": {"x": float("nan"), "ok": [1.5, -float("inf")]}}])
    assert json.loads(json.dumps(safe, allow_nan=False)) == [{"condition": None, "nested": {"x": None, "ok": [1.5, None]}}]
