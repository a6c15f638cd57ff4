"""The OGC process ``preanalysis`` (issue 15): listed and described, planned jobs validated with
problem documents that point into the request, accepted jobs solved by the real solver through
the worker's entry point (the process table's ``run``, as service.execution calls it)."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any, Iterator

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.processes import PREANALYSIS, process
from service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def local(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(data_dir=tmp_path, workers=0, log_format="text")
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


@pytest.fixture(scope="module")
def planned() -> dict[str, Any]:
    """examples/prism-triplet.json as planned: no observations, tie points at their true place."""
    job = json.loads((ROOT / "examples" / "prism-triplet.json").read_text())
    truth = json.loads((ROOT / "examples" / "prism-triplet.truth.json").read_text())
    where = {p["id"]: p for p in truth["points"]}
    job["observations"] = []
    for p in job["points"]:
        if p["role"] == "tie":
            q = where[p["id"]]
            p["coordinates"] = [q["lon_deg"], q["lat_deg"], q["height_m"]]
    return job


def test_preanalysis_is_a_process(local: TestClient) -> None:
    ids = [p["id"] for p in local.get("/processes").json()["processes"]]
    assert PREANALYSIS in ids
    desc = local.get(f"/processes/{PREANALYSIS}").json()
    assert desc["outputs"]["report"]["title"] == "Pre-analysis report"


def test_planned_points_need_coordinates(local: TestClient, planned: dict[str, Any]) -> None:
    job = copy.deepcopy(planned)
    tie = next(i for i, p in enumerate(job["points"]) if p["role"] == "tie")
    del job["points"][tie]["coordinates"]
    r = local.post(f"/processes/{PREANALYSIS}/execution", json={"inputs": {"job": job}})
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json")
    assert f"/inputs/job/points/{tie}/coordinates" in [e["pointer"] for e in r.json()["errors"]]
    # the same planned job, complete, is accepted (no observations needed)
    r = local.post(f"/processes/{PREANALYSIS}/execution", json={"inputs": {"job": planned}})
    assert r.status_code == 201, r.text


def test_the_worker_runs_the_preanalysis(planned: dict[str, Any]) -> None:
    report = process(PREANALYSIS).run({"job": planned}, lambda *_: None, lambda: False)
    assert report["kind"] == "preanalysis"
    cps = report["checkpoints"]
    assert cps["n"] == sum(p["role"] == "check" for p in planned["points"])
    assert all(p["sigma_m"] and p["sigma_m"]["e"] > 0 for p in cps["points"])
    # the simulated triplet sees every point in its three images; the planned one too (the
    # nominal attitude levelled to the platform's vertical: docs/models.md section 13)
    assert all(len(p["images"]) == 3 for p in cps["points"])
    json.dumps(report, allow_nan=False)  # JSON-ready
