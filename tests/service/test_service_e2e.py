"""End to end through HTTP against a real ``pba serve`` (uvicorn + 2 worker processes) and the
real solver: same numbers as the solver run directly, SSE progress, cancellation of a long
job, a worker killed with SIGKILL mid-job, 200 concurrent jobs, per-user isolation, CSV,
model comparison, metrics and structured logs."""

from __future__ import annotations

import copy
import csv
import io
import json
import math
import os
import signal
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import httpx
import pytest
from pba_service_harness import FINISHED, Server, execute_body, submit_async, wait_status
from tolerances import RECOMPUTED_REL, SAME_NUMBER_REL

from service.states import JobStatus

# report numbers that may be ~0 (means, offsets): the relative bound alone would demand equality there
NEAR_ZERO_ABS = 1e-12

pytestmark = pytest.mark.slow


def ignored(key: str) -> bool:
    """Wall-clock timings (``solve_time_s``, ``total_time_s``, ``timings``) differ between runs."""
    return key.endswith("time_s") or key == "timings"


def assert_same_numbers(a: Any, b: Any, path: str = "") -> None:
    """Reports equal up to 1e-9 relative (floats), exactly otherwise; timings ignored."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), f"{path}: keys {set(a) ^ set(b)}"
        for k in a:
            if not ignored(k):
                assert_same_numbers(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), f"{path}: lengths"
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            assert_same_numbers(x, y, f"{path}/{i}")
    elif isinstance(a, float) and isinstance(b, (int, float)):
        assert math.isclose(a, b, rel_tol=RECOMPUTED_REL, abs_tol=NEAR_ZERO_ABS), f"{path}: {a} != {b}"
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


def json_roundtrip(report: dict[str, Any]) -> dict[str, Any]:
    from solver.report.json_text import report_json

    return json.loads(report_json(report))


def read_events(
    client: httpx.Client, job_id: str, key: str, until: Any = None, timeout: float = 120
) -> list[dict[str, Any]]:
    """Status events of a job's SSE stream (EventSource-style ``?api_key=``), until the
    stream ends or ``until(event)`` is true."""
    events: list[dict[str, Any]] = []
    with client.stream(
        "GET",
        f"/jobs/{job_id}/events",
        params={"api_key": key},
        headers={"X-API-Key": ""},
        timeout=timeout,
    ) as r:
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("text/event-stream")
        kind = None
        for line in r.iter_lines():
            if line.startswith("event:"):
                kind = line.split(":", 1)[1].strip()
            elif line.startswith("data:") and kind == "status":
                events.append(json.loads(line.split(":", 1)[1]))
                if until is not None and until(events[-1]):
                    break
    return events


def worker_pid(server: Server, job_id: str) -> int:
    store = server.store()
    try:
        rec = store.get_job(job_id)
    finally:
        store.close()
    assert rec is not None and rec.worker, rec
    return int(rec.worker.rsplit(":", 1)[1])


def test_triplet_same_numbers_as_the_solver(
    server: Server, keys: dict[str, str], triplet_doc: dict[str, Any]
) -> None:
    import solver.api

    direct = json_roundtrip(solver.api.run(copy.deepcopy(triplet_doc)))
    with server.client(keys["alice"]) as c:
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(triplet_doc))
        assert r.status_code == 200, r.text[:500]
        assert r.headers["location"].startswith(f"{server.url}/jobs/")
        assert_same_numbers(direct, r.json())
        job_id = submit_async(c, triplet_doc)
        st = wait_status(c, job_id)
        assert st["status"] == "successful" and st["progress"] == 100, st
        assert {"created", "started", "finished", "updated"} <= set(st)
        res = c.get(f"/jobs/{job_id}/results")
        assert res.status_code == 200
        assert_same_numbers(direct, res.json()["report"])
        rows = list(
            csv.DictReader(io.StringIO(c.get(f"/jobs/{job_id}/results/parameters.csv").text))
        )
        by_name = {(row["image"], row["name"]): row for row in rows}
        for image in direct["images"]:
            for p in image["parameters"]:
                assert float(by_name[(image["id"], p["name"])]["value"]) == pytest.approx(
                    p["value"], rel=SAME_NUMBER_REL
                )
        obs = c.get(f"/jobs/{job_id}/results/observations.csv")
        assert obs.headers["content-type"].startswith("text/csv")
        assert len(list(csv.DictReader(io.StringIO(obs.text)))) == len(direct["observations"])
        cps = list(
            csv.DictReader(io.StringIO(c.get(f"/jobs/{job_id}/results/checkpoints.csv").text))
        )
        assert len(cps) == direct["checkpoints"]["n"]


def test_sse_progress_and_cancel_a_running_large_job(
    server: Server, keys: dict[str, str], big_doc: dict[str, Any], small_doc: dict[str, Any]
) -> None:
    with server.client(keys["alice"]) as c:
        job_id = submit_async(c, big_doc)
        events = read_events(
            c,
            job_id,
            keys["alice"],
            until=lambda e: e["status"] == "running" and "iteration" in e["message"],
        )
        assert events[0]["status"] in ("accepted", "running")
        r = c.delete(f"/jobs/{job_id}")
        assert r.status_code == 200 and r.json()["status"] in ("running", "dismissed")
        rest = read_events(c, job_id, keys["alice"])
        # stopped, not finished: the solve would take many more iterations (how fast a cancel
        # takes effect is measured in bench/, not asserted here)
        assert rest[-1]["status"] == "dismissed", rest[-1]
        assert "cancel" in rest[-1]["message"]
        progress = [e["progress"] for e in events + rest]
        assert progress == sorted(progress), progress  # never decreases
        assert c.get(f"/jobs/{job_id}/results").status_code == 404
        # the worker that held it goes on serving
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(small_doc))
        assert r.status_code == 200, r.text[:300]


def test_worker_killed_mid_job_fails_the_job_and_server_goes_on(
    server: Server, keys: dict[str, str], big_doc: dict[str, Any], small_doc: dict[str, Any]
) -> None:
    with server.client(keys["alice"]) as c:
        job_id = submit_async(c, big_doc)
        wait_status(c, job_id, {"running"}, min_progress=10)
        pid = worker_pid(server, job_id)
        os.kill(pid, signal.SIGKILL)
        st = wait_status(c, job_id, {"failed"}, timeout=30)
        assert "killed by SIGKILL" in st["message"], st["message"]
        r = c.get(f"/jobs/{job_id}/results")
        assert r.status_code == 500 and r.json()["title"] == "The job failed"
        assert c.get("/healthz").status_code == 200
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(small_doc))
        assert r.status_code == 200, r.text[:300]
        deadline = time.monotonic() + 30
        while not c.get("/readyz").json()["checks"]["queue"].startswith("2 of 2 workers alive"):
            assert time.monotonic() < deadline, "the killed worker was not replaced"
            time.sleep(0.2)


def test_users_see_only_their_own_jobs(
    server: Server, keys: dict[str, str], small_doc: dict[str, Any]
) -> None:
    alice, bob, root = (server.client(keys[k]) for k in ("alice", "bob", "root"))
    with alice, bob, root:
        job_id = submit_async(alice, small_doc)
        for path in (
            f"/jobs/{job_id}",
            f"/jobs/{job_id}/results",
            f"/jobs/{job_id}/events",
            f"/jobs/{job_id}/results/observations.csv",
        ):
            r = bob.get(path)
            assert r.status_code == 404 and r.json()["type"].endswith("no-such-job"), (path, r.text)
        assert bob.delete(f"/jobs/{job_id}").status_code == 404
        assert job_id not in [
            j["jobID"] for j in bob.get("/jobs", params={"limit": 1000}).json()["jobs"]
        ]
        assert job_id in [
            j["jobID"] for j in alice.get("/jobs", params={"limit": 1000}).json()["jobs"]
        ]
        assert job_id in [
            j["jobID"] for j in root.get("/jobs", params={"limit": 1000}).json()["jobs"]
        ]
        assert wait_status(root, job_id)["status"] == "successful"  # the admin sees it
        with server.client() as anonymous:
            assert anonymous.get(f"/jobs/{job_id}").status_code == 401
        assert wait_status(alice, job_id)["status"] == "successful"  # bob's DELETE changed nothing


def test_200_concurrent_small_jobs(server: Server, small_doc: dict[str, Any]) -> None:
    key = server.create_key("carol")
    body = execute_body(small_doc)
    with server.client(key) as c:

        def submit(_: int) -> str:
            r = c.post(
                "/processes/bundle-adjustment/execution",
                json=body,
                headers={"Prefer": "respond-async"},
            )
            assert r.status_code == 201, r.text[:300]
            return r.json()["jobID"]

        with ThreadPoolExecutor(16) as pool:
            ids = list(pool.map(submit, range(200)))
        assert len(set(ids)) == 200
        deadline = time.monotonic() + 240
        while True:
            listed = c.get("/jobs", params={"limit": 1000}).json()
            done = [j for j in listed["jobs"] if j["status"] in FINISHED]
            if len(done) == 200:
                break
            assert time.monotonic() < deadline, f"{len(done)} of 200 finished"
            time.sleep(1.0)
        assert listed["numberMatched"] == 200
        assert sorted(j["jobID"] for j in listed["jobs"]) == sorted(ids)
        assert {j["status"] for j in listed["jobs"]} == {"successful"}
        sigma0 = {
            c.get(f"/jobs/{i}/results").json()["report"]["adjustment"]["sigma0_aposteriori"]
            for i in ids[::20]
        }
        assert len(sigma0) == 1
    store = server.store()
    try:
        for job_id in ids:
            rec = store.get_job(job_id)
            assert rec is not None and rec.status == JobStatus.successful and rec.attempts == 1, rec
            assert rec.results_text
    finally:
        store.close()


def test_model_comparison_process(
    server: Server, keys: dict[str, str], triplet_doc: dict[str, Any]
) -> None:
    with server.client(keys["bob"]) as c:
        r = c.post(
            "/processes/model-comparison/execution",
            json={"inputs": {"job": triplet_doc, "models": ["K2", "P2"]}, "response": "document"},
        )
        assert r.status_code == 200, r.text[:500]
        report = r.json()["report"]
        assert report["kind"] == "comparison" and [t["model"] for t in report["table"]] == [
            "K2",
            "P2",
        ]
        job_id = r.headers["location"].rsplit("/", 1)[1]
        rows = list(
            csv.DictReader(io.StringIO(c.get(f"/jobs/{job_id}/results/parameters.csv").text))
        )
        assert {row["model"] for row in rows} == {"K2", "P2"}


def test_camera_from_a_job_without_self_calibration_is_404(
    server: Server, keys: dict[str, str], small_doc: dict[str, Any]
) -> None:
    with server.client(keys["bob"]) as c:
        job_id = submit_async(c, small_doc)
        wait_status(c, job_id)
        r = c.post(
            "/cameras/from-job", json={"job_id": job_id, "camera": "prism-nadir", "name": "prism-n"}
        )
        assert r.status_code == 404 and "interior orientation" in r.json()["detail"]
        r = c.post("/cameras/from-job", json={"job_id": job_id, "camera": "nope", "name": "x"})
        assert r.status_code == 404


def test_metrics_health_and_structured_logs(
    server: Server, keys: dict[str, str], small_doc: dict[str, Any]
) -> None:
    with server.client(keys["bob"]) as c:
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(small_doc))
        job_id = r.headers["location"].rsplit("/", 1)[1]
        assert c.get("/healthz").json()["status"] == "ok"
        ready = c.get("/readyz").json()
        assert ready["status"] == "ok" and ready["checks"]["store"] == "ok"
        assert c.get("/metrics").status_code == 403  # keys required: an admin's or the token
    with server.client(keys["root"]) as c:
        text = c.get("/metrics").text
    assert 'pba_jobs{status="successful"}' in text
    assert "pba_queue_depth" in text and "pba_workers 2.0" in text
    assert 'pba_solve_duration_seconds_count{status="successful"}' in text
    records = [r for r in server.log_records() if r.get("job_id") == job_id]
    messages = [r["message"] for r in records]
    assert any(m.startswith("solve finished") for m in messages), messages
    assert all(r["level"] and r["time"] for r in records)


def test_a_job_the_solver_rejects_fails_with_its_problems(
    server: Server, keys: dict[str, str], triplet_doc: dict[str, Any]
) -> None:
    job = copy.deepcopy(triplet_doc)
    gcps = [p for p in job["points"] if p["role"] == "gcp"]
    for p in gcps[1:]:  # one control point: valid counts, singular normal matrix
        p["role"] = "tie"
    with server.client(keys["bob"]) as c:
        assert c.post("/jobs/validate", json=execute_body(job)).status_code == 200
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(job))
        assert r.status_code == 422, r.text[:300]
        assert r.headers["content-type"].startswith("application/problem+json")
        problem = r.json()
        assert problem["errors"][0]["code"] == "rank_deficient"
        assert problem["errors"][0]["pointer"].startswith("/inputs/job")
        job_id = r.headers["location"].rsplit("/", 1)[1]
        st = c.get(f"/jobs/{job_id}").json()
        assert st["status"] == "failed" and "invalid job" in st["message"]
        assert st["problems"][0]["code"] == "rank_deficient"
        assert c.get(f"/jobs/{job_id}/results").status_code == 422


def test_control_of_another_image_is_a_422_naming_it(server: Server, keys: dict[str, str], tmp_path_factory) -> None:
    """A SPOT 1-4 job composed from its metadata whose control was measured in a neighbouring
    image (tests/solver/quality/test_control_fit.py): refused before solving, by name, as the
    solver's other problems are."""
    from spot14_jobs import foreign, product, truth_job

    scene, _, p = product(tmp_path_factory.mktemp("spot14"))
    job = foreign(scene, truth_job(scene, p, 6, 2, 4, perturb=False))
    with server.client(keys["bob"]) as c:
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(job))
        assert r.status_code == 422, r.text[:300]
        err = r.json()["errors"][0]
        assert err["code"] == "control_does_not_belong" and err["pointer"] == "/inputs/job/images/0", err
        assert "these 6 control points" in err["message"] and "another image's points?" in err["message"], err
