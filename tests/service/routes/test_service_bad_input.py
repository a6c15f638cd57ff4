"""Issue 13 through HTTP: every malformed job is a 4xx problem document pointing at the field,
for execution and for /jobs/validate (in-process app, no workers: refused before queuing)."""

from __future__ import annotations

from typing import Any, Iterator

import pytest
from bad_job_cases import CASES, bad_job
from fastapi.testclient import TestClient

from service.app import create_app
from service.problems import json_pointer
from service.settings import Settings

PROBLEM = "application/problem+json"
URLS = ("/jobs/validate", "/processes/bundle-adjustment/execution")


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(data_dir=tmp_path_factory.mktemp("bad"), workers=0, log_format="text")
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


@pytest.mark.parametrize("url", URLS)
@pytest.mark.parametrize("case", sorted(CASES))
def test_malformed_job_is_a_4xx_with_a_pointer(client: TestClient, case: str, url: str) -> None:
    r = client.post(url, json={"inputs": {"job": bad_job(case)}})
    assert r.status_code == 422, r.text[:2000]
    assert r.headers["content-type"].startswith(PROBLEM)
    pointers = [e["pointer"] for e in r.json()["errors"]]
    assert json_pointer(("inputs", "job", *CASES[case][1])) in pointers, pointers
    assert client.get("/jobs").json()["numberMatched"] == 0  # nothing was queued


@pytest.mark.parametrize(
    ("models", "pointer"),
    [(["K2"] * 500, "/inputs/models"), (["K2", "K2"], "/inputs/models/1"), (["ON2", "MT12"], "/inputs/models/1")],
)
def test_comparison_models_bounded_and_distinct(
    client: TestClient, models: list[str], pointer: str
) -> None:
    doc: dict[str, Any] = {"inputs": {"job": bad_job("lines_as_float"), "models": models}}
    doc["inputs"]["job"]["cameras"][0]["lines"] = 16000
    for url in ("/jobs/validate?process=model-comparison", "/processes/model-comparison/execution"):
        r = client.post(url, json=doc)
        assert r.status_code == 422, r.text[:2000]
        assert pointer in [e["pointer"] for e in r.json()["errors"]]


def test_library_camera_with_impossible_values_is_refused(client: TestClient) -> None:
    cam = bad_job("lines_as_float")["cameras"][0]
    cam["lines"] = 16000
    for field, value, pointer in [
        ("focal_mm", 5e-324, "/definition/focal_mm"),
        ("focal_mm", "481.8", "/definition/focal_mm"),
        ("iop", {"a0@7": 0.01}, "/definition/iop"),
    ]:
        definition = {**cam, field: value}
        r = client.post("/cameras", json={"name": "bad-cam", "definition": definition})
        assert r.status_code == 422, r.text[:2000]
        assert pointer in [e["pointer"] for e in r.json()["errors"]]
