"""Restarts: jobs queued across a graceful stop complete; a job left running by a crash of
the whole server (server and workers SIGKILLed together) is re-queued once, then failed."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
from pba_service_harness import Server, execute_body, submit_async, wait_status

from service.states import JobStatus

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def medium_doc(big_doc: dict[str, Any]) -> dict[str, Any]:
    """The large job capped at 6 iterations: several seconds of solving."""
    doc = copy.deepcopy(big_doc)
    doc.setdefault("options", {})["max_iterations"] = 6
    doc["options"]["covariance"] = False
    doc["name"] = "medium"
    return doc


def test_graceful_restart_with_queued_jobs(tmp_path: Path, medium_doc: dict[str, Any], small_doc: dict[str, Any]) -> None:
    first = Server(tmp_path, workers=1).start()
    try:
        with first.client() as c:  # local single-user mode: no key
            running = submit_async(c, medium_doc)
            queued = [submit_async(c, small_doc) for _ in range(3)]
            wait_status(c, running, {"running"}, min_progress=5)
    finally:
        # uvicorn re-raises SIGTERM after its graceful shutdown, hence -15
        assert first.stop() in (0, -15)
    assert "server stopped" in [r["message"] for r in first.log_records()]  # graceful, not killed
    store = first.store()
    try:
        rec = store.get_job(running)
        assert rec is not None and rec.status == JobStatus.accepted, rec
        assert "server stopped" in rec.message and rec.attempts == 0  # a clean stop costs no attempt
        assert all(store.get_job(j).status == JobStatus.accepted for j in queued)  # type: ignore[union-attr]
    finally:
        store.close()
    second = Server(tmp_path, workers=2).start()
    try:
        with second.client() as c:
            for job_id in [running, *queued]:
                assert wait_status(c, job_id, timeout=120)["status"] == "successful"
    finally:
        second.stop()


def test_crash_requeues_a_running_job_once_then_fails_it(tmp_path: Path, medium_doc: dict[str, Any]) -> None:
    server = Server(tmp_path, workers=1).start()
    with server.client() as c:
        job_id = submit_async(c, medium_doc)
        wait_status(c, job_id, {"running"}, min_progress=5)
    server.kill_group()  # the machine went down: server and worker die together

    server = Server(tmp_path, workers=1).start()
    with server.client() as c:
        st = c.get(f"/jobs/{job_id}").json()
        assert st["status"] in ("accepted", "running"), st
        assert any(
            r.get("job_id") == job_id and "re-queued" in r["message"] for r in server.log_records()
        )
        wait_status(c, job_id, {"running"}, min_progress=5)
    server.kill_group()  # and once more, during the second run

    server = Server(tmp_path, workers=1).start()
    try:
        with server.client() as c:
            st = c.get(f"/jobs/{job_id}").json()
            assert st["status"] == "failed", st
            assert "interrupted by a server restart 2 times" in st["message"]
            # the server is healthy and serves new work
            r = c.post("/processes/bundle-adjustment/execution", json=execute_body(medium_doc | {"options": {"max_iterations": 1, "covariance": False}}))
            assert r.status_code == 200, r.text[:300]
    finally:
        server.stop()
