"""Ownership pinned route by route (real server): every route of the OpenAPI document that
takes a job id, a camera name or a user, asked with another user's key, answers 404 or 403,
while the owner gets an answer on the same job routes (so the walk is not vacuous: removing
the owner check of any one route, e.g. the GeoJSON one, fails this test). A route added later
is walked without editing the test; only its path parameters must be known below."""

from __future__ import annotations

import re
from typing import Any

import pytest
from pba_service_harness import Server, execute_body, load_example, wait_status

IMAGE = "prism-nadir"
CAMERA = {"focal_mm": 1939.0, "pixel_mm": 0.0071, "line_time_s": 0.00037, "lines": 1000, "columns": 1000}
BODIES: dict[str, dict[str, Any]] = {
    "/jobs/{jobId}/results/ground-to-image": {"image": IMAGE, "points": [{"lon": -51.4, "lat": -22.1, "height": 400.0}]},
    "/jobs/{jobId}/results/image-to-ground": {"image": IMAGE, "pixels": [{"line": 100.0, "column": 100.0, "height": 400.0}]},
    "/cameras/{name}/share": {},
    "/admin/users/{name}": {"weight": 2},
}
OWNED = ("{jobId}", "{name}")


def _value(path: str, param: dict[str, Any], job: str) -> str:
    name = param["name"]
    enum = param.get("schema", {}).get("enum")
    if name == "jobId":
        return job
    if name == "name":
        return "alice" if path.startswith("/admin/") else "alicecam"
    if name == "image":
        return IMAGE
    if name == "version":
        return "1"
    if enum:
        return str(enum[0])
    raise AssertionError(f"the walk does not know path parameter {name!r} of {path}: add it here")


def routes(doc: dict[str, Any], job: str) -> list[tuple[str, str, str, dict[str, Any] | None]]:
    """(method, template, concrete path, body) of every owned route, DELETE last."""
    out = []
    for template, ops in doc["paths"].items():
        if not any(p in template for p in OWNED):
            continue
        for method, op in ops.items():
            params = {p["name"]: p for p in op.get("parameters", []) if p["in"] == "path"}
            path = re.sub(r"\{(\w+)\}", lambda m: _value(template, params[m.group(1)], job), template)
            out.append((method.upper(), template, path, BODIES.get(template)))
    out.append(("POST", "/cameras/from-job", "/cameras/from-job", {"job_id": job, "camera": IMAGE, "name": "stolen"}))
    return sorted(out, key=lambda r: r[0] == "DELETE")


@pytest.fixture(scope="module")
def alice_job(server: Server, keys: dict[str, str]) -> str:
    with server.client(keys["alice"]) as c:
        # asynchronous: a loaded machine may take longer than the synchronous wait
        r = c.post(
            "/processes/bundle-adjustment/execution",
            json=execute_body(load_example("prism-nadir.json")),
            headers={"Prefer": "respond-async"},
        )
        assert r.status_code == 201, r.text[:500]
        job = r.json()["jobID"]
        assert wait_status(c, job, timeout=600)["status"] == "successful"
        assert c.post("/cameras", json={"name": "alicecam", "definition": CAMERA}).status_code == 201
        return job


def test_another_users_key_reaches_nothing_owned(server: Server, keys: dict[str, str], alice_job: str) -> None:
    with server.client(keys["alice"]) as alice, server.client(keys["bob"]) as bob:
        doc = alice.get("/openapi.json").json()
        walked = routes(doc, alice_job)
        templates = {t for _, t, _, _ in walked}
        assert {"/jobs/{jobId}/results/geojson", "/jobs/{jobId}/events", "/jobs/{jobId}/results/rpc/{image}", "/cameras/{name}", "/admin/users/{name}"} <= templates
        for method, template, path, body in walked:
            if "{jobId}" in template and method != "DELETE":
                own = alice.request(method, path, json=body, timeout=300)
                assert own.status_code < 400, (method, path, own.status_code, own.text[:300])
            r = bob.request(method, path, json=body, timeout=300)
            assert r.status_code in (403, 404), (method, path, r.status_code, r.text[:300])
        assert alice.get(f"/jobs/{alice_job}").json()["status"] == "successful"
