"""Hardening for a shared server (issue 13): /metrics behind a key and computed from the store,
a private SQLite file, ``nosniff`` on every response, 415 for a body that is not JSON, CSV
cells escaped against formula injection. In-process (PBA_WORKERS=0); finished jobs are written
into the store directly, the way a worker records them.
"""

from __future__ import annotations

import copy
import csv
import io
import json
import sqlite3
import stat
from pathlib import Path
from typing import Any, Iterator

import pytest
from fastapi.testclient import TestClient

from service import report_csv as tables
from service.app import create_app
from service.auth import create_key, local_user
from service.settings import Settings
from service.store import Store, open_store

PROBLEM = "application/problem+json"
METRICS_TOKEN = "metrics-token-0123456789abcdef"
INJECTIONS = ("=HYPERLINK(\"http://evil\",\"x\")", "@SUM(1+1)", "+1+cmd|' /C calc'!A0", "-2+3", "\tx", "\rx")


def make_client(tmp_path: Path, **overrides: Any) -> TestClient:
    settings = Settings(data_dir=tmp_path, workers=0, log_format="text", **overrides)
    return TestClient(create_app(settings), raise_server_exceptions=False)


def store_of(tmp_path: Path) -> Store:
    return open_store(Settings(data_dir=tmp_path).resolved_database_url)


def finish_job(store: Store, owner: str, results: dict[str, Any], worker: str = "w") -> str:
    """A job run to ``successful`` the way a worker records it."""
    rec = store.create_job(owner, "bundle-adjustment", {"inputs": {}}, 1, "test")
    assert store.claim(rec.id, worker) is not None
    assert store.complete(rec.id, worker, json.dumps(results), "finished")
    return rec.id


def histogram_count(text: str, status: str) -> float | None:
    """The ``_count`` sample of the solve-duration histogram for ``status`` (None if absent)."""
    prefix = f'pba_solve_duration_seconds_count{{status="{status}"}} '
    for line in text.splitlines():
        if line.startswith(prefix):
            return float(line[len(prefix) :])
    return None


@pytest.fixture
def local(tmp_path: Path) -> Iterator[TestClient]:
    with make_client(tmp_path, max_body_bytes=200_000) as c:
        yield c


# -- /metrics --------------------------------------------------------------------------------
def test_metrics_need_an_admin_key_or_the_token_when_keys_are_required(tmp_path: Path) -> None:
    with make_client(tmp_path, require_api_keys=True, metrics_token=METRICS_TOKEN) as c:
        store = store_of(tmp_path)
        bob = create_key(store, "bob")[0]
        root = create_key(store, "root", is_admin=True)[0]
        store.close()
        r = c.get("/metrics")
        assert r.status_code == 401 and r.headers["content-type"].startswith(PROBLEM)
        assert c.get("/metrics", headers={"X-API-Key": "pba_wrong_key"}).status_code == 401
        assert c.get("/metrics", headers={"Authorization": "Bearer not-the-token"}).status_code == 401
        assert c.get("/metrics", headers={"X-API-Key": bob}).status_code == 403
        for headers in ({"X-API-Key": root}, {"Authorization": f"Bearer {METRICS_TOKEN}"}):
            r = c.get("/metrics", headers=headers)
            assert r.status_code == 200 and "pba_jobs" in r.text, r.text[:300]


def test_metrics_are_open_in_local_mode(local: TestClient) -> None:
    r = local.get("/metrics")
    assert r.status_code == 200 and "pba_queue_depth" in r.text


def test_metrics_token_shorter_than_16_characters_is_refused() -> None:
    with pytest.raises(ValueError):
        Settings(metrics_token="short")


def test_solve_durations_come_from_the_store(tmp_path: Path) -> None:
    """Jobs finished before the server started are counted, and two servers on one store
    (or one after a restart) report the same histogram."""
    store = store_of(tmp_path)
    owner = local_user(store).id
    for _ in range(3):
        finish_job(store, owner, {"kind": "adjustment"})
    with make_client(tmp_path) as first, make_client(tmp_path) as second:
        text = first.get("/metrics").text
        assert histogram_count(text, "successful") == 3.0, text
        assert 'pba_jobs{status="successful"} 3.0' in text
        finish_job(store, owner, {"kind": "adjustment"})
        for client in (first, second):
            assert histogram_count(client.get("/metrics").text, "successful") == 4.0
    store.close()
    with make_client(tmp_path) as restarted:
        assert histogram_count(restarted.get("/metrics").text, "successful") == 4.0


# -- the SQLite file -------------------------------------------------------------------------
def test_sqlite_store_and_data_dir_are_private(tmp_path: Path) -> None:
    data_dir = tmp_path / "new" / "data"
    with make_client(data_dir) as c:
        assert c.get("/jobs").status_code == 200
        db = data_dir / "pba.sqlite3"
        # the store's connections close after each use, which removes -wal and -shm: hold one
        # open (the store put the file in WAL mode) to see the modes SQLite gives them
        conn = sqlite3.connect(db)
        try:
            conn.execute("SELECT count(*) FROM sqlite_master").fetchall()
            for path in (db, data_dir / "pba.sqlite3-wal", data_dir / "pba.sqlite3-shm"):
                assert path.exists(), path
                assert stat.S_IMODE(path.stat().st_mode) == 0o600, (path, oct(path.stat().st_mode))
        finally:
            conn.close()
        assert stat.S_IMODE(data_dir.stat().st_mode) == 0o700


def test_an_existing_sqlite_file_keeps_its_mode(tmp_path: Path) -> None:
    path = tmp_path / "pba.sqlite3"
    path.touch(mode=0o640)
    path.chmod(0o640)  # the owner's choice (e.g. a group of operators) is not overridden
    open_store(f"sqlite:///{path}").close()
    assert stat.S_IMODE(path.stat().st_mode) == 0o640


# -- nosniff ---------------------------------------------------------------------------------
def test_every_response_says_nosniff(local: TestClient, tmp_path: Path) -> None:
    store = store_of(tmp_path)
    job_id = finish_job(store, local_user(store).id, {"kind": "adjustment", "observations": []})
    store.close()
    responses = {
        "landing (JSON)": local.get("/"),
        "processes (JSON)": local.get("/processes"),
        "404 problem": local.get("/jobs/no-such-job"),
        "405 problem": local.put("/jobs"),
        "422 problem": local.post("/jobs/validate", json={"inputs": {}}),
        "413 from the body limit": local.post(
            "/jobs/validate", content=b"{" + b" " * 300_000 + b"}",
            headers={"Content-Type": "application/json"},
        ),
        "415 problem": local.post("/jobs/validate", content=b"{}", headers={"Content-Type": "text/plain"}),
        "metrics": local.get("/metrics"),
        "healthz": local.get("/healthz"),
        "web page": local.get("/ui"),
        "static file": local.get("/ui/assets/app.js"),
        "CSV": local.get(f"/jobs/{job_id}/results/observations.csv"),
        "results": local.get(f"/jobs/{job_id}/results"),
    }
    for what, r in responses.items():
        assert r.status_code < 500, (what, r.status_code)
        assert r.headers.get("x-content-type-options") == "nosniff", (what, dict(r.headers))


# -- 415 -------------------------------------------------------------------------------------
JSON_BODY_ENDPOINTS = (
    "/processes/bundle-adjustment/execution",
    "/processes/model-comparison/execution",
    "/jobs/validate",
    "/cameras",
    "/cameras/from-job",
    "/cameras/somecam/share",
)


@pytest.mark.parametrize("path", JSON_BODY_ENDPOINTS)
@pytest.mark.parametrize(
    "content_type", ["text/plain", "application/x-www-form-urlencoded", "multipart/form-data; boundary=x", "application/xml"]
)
def test_a_body_that_is_not_json_is_415(local: TestClient, path: str, content_type: str) -> None:
    r = local.post(path, content=b'{"inputs": {}}', headers={"Content-Type": content_type})
    assert r.status_code == 415, r.text[:300]
    assert r.headers["content-type"].startswith(PROBLEM)
    doc = r.json()
    assert doc["status"] == 415 and doc["type"] == "urn:pba:problem:unsupported-media-type"
    assert doc["errors"][0]["pointer"] == ""


@pytest.mark.parametrize(
    "content_type", ["application/json", "application/json; charset=utf-8", "application/problem+json"]
)
def test_json_media_types_are_read(local: TestClient, content_type: str) -> None:
    # an empty job: read as JSON, then refused by the schema (422), not by its media type
    r = local.post("/jobs/validate", content=b'{"inputs": {}}', headers={"Content-Type": content_type})
    assert r.status_code == 422, r.text[:300]


# -- CSV formula injection -------------------------------------------------------------------
def test_csv_cell_escapes_formulas_and_keeps_numbers() -> None:
    for text in INJECTIONS:
        assert tables.csv_cell(text) == "'" + text
    # numbers stay numbers, whether typed or written as text (a negative residual, a list)
    for value in (-1.5, -3, 0, True, None, "-1.5", "-2.5e-06", "+4", "-1.0;2.5;-3", "P01", "", "a=b"):
        assert tables.csv_cell(value) == value


def test_csv_downloads_escape_ids_from_the_job(local: TestClient, tmp_path: Path) -> None:
    """A point or image id chosen by the user cannot become a spreadsheet formula; negative
    residuals are still written as numbers."""
    observations = [
        {
            "image": bad,
            "point": bad,
            "role": "tie",
            "line": 10.0,
            "column": 20.0,
            "sigma_px": 0.5,
            "residual_line_px": -0.25,
            "residual_column_px": 0.125,
        }
        for bad in INJECTIONS
    ]
    report = {
        "kind": "adjustment",
        "observations": observations,
        "images": [{"id": "=1+1", "camera": "@cam", "model": "K2", "parameters": [{"name": "-X", "value": -12.5}]}],
        "checkpoints": {"points": [{"id": "=cmd()", "discrepancy_m": {"e": -0.5}}]},
    }
    store = store_of(tmp_path)
    job_id = finish_job(store, local_user(store).id, report)
    store.close()
    rows = list(csv.DictReader(io.StringIO(local.get(f"/jobs/{job_id}/results/observations.csv").text)))
    assert [r["point"] for r in rows] == ["'" + t for t in INJECTIONS]
    assert [r["image"] for r in rows] == ["'" + t for t in INJECTIONS]
    assert all(r["residual_line_px"] == "-0.25" for r in rows)
    params = list(csv.DictReader(io.StringIO(local.get(f"/jobs/{job_id}/results/parameters.csv").text)))
    assert params == [{"image": "'=1+1", "camera": "'@cam", "model": "K2", "name": "'-X", "value": "-12.5"}]
    cps = list(csv.DictReader(io.StringIO(local.get(f"/jobs/{job_id}/results/checkpoints.csv").text)))
    assert cps == [{"id": "'=cmd()", "discrepancy_m_e": "-0.5"}]


def test_csv_of_a_comparison_escapes_too() -> None:
    sub = {"observations": [{"point": "=X()", "residual_line_px": -1.0}]}
    rows = tables.table_rows({"kind": "comparison", "reports": {"K2": copy.deepcopy(sub)}}, "observations")
    text = tables.to_csv(rows)
    assert text.splitlines() == ["model,point,residual_line_px", "K2,'=X(),-1.0"]


# -- an unusable solve is a failed job -------------------------------------------------------
def test_an_unusable_solve_fails_the_job_with_a_problem_document(
    local: TestClient, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The worker's run (in this process, so the residual blocks can be made to fail: Ceres
    then ends with FAILURE) records a failed job; status and results say why, as a 422."""
    import solver.engine.backend as backend
    from service.execution import RunLimits, run_claimed_job
    from service.states import JobStatus

    doc = json.loads((Path(__file__).resolve().parents[2] / "examples" / "prism-nadir.json").read_text())
    r = local.post(
        "/processes/bundle-adjustment/execution",
        json={"inputs": {"job": doc}},
        headers={"Prefer": "respond-async"},
    )
    assert r.status_code == 201, r.text[:300]
    job_id = r.headers["location"].rsplit("/", 1)[1]
    monkeypatch.setenv("PBA_EVALUATION", "python")  # the Python cost functions can be patched
    for cls in (backend.ImageBatchCost, backend.PointCost):
        monkeypatch.setattr(cls, "Evaluate", lambda self, parameters, residuals, jacobians: False)
    store = store_of(tmp_path)
    job = store.claim(job_id, "test-worker")
    assert job is not None
    assert run_claimed_job(store, job, "test-worker", RunLimits(job_time_limit_s=600)) == JobStatus.failed
    store.close()
    st = local.get(f"/jobs/{job_id}").json()
    assert st["status"] == "failed", st
    assert st["message"].startswith("the adjustment did not produce a usable solution")
    assert st["problems"][0]["code"] == "unusable_solution"
    assert st["problems"][0]["pointer"] == "/inputs/job"
    assert st["problems"][0]["detail"]["termination"] == "FAILURE"
    res = local.get(f"/jobs/{job_id}/results")
    assert res.status_code == 422 and res.headers["content-type"].startswith(PROBLEM)
    assert res.json()["errors"][0]["code"] == "unusable_solution"
