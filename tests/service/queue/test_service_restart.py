"""Restarts: jobs queued across a graceful stop complete; a job left running by a crash of
the whole server (server and workers SIGKILLed together) is re-queued once, then failed."""

from __future__ import annotations

import copy
import os
import time
from pathlib import Path
from typing import Any

import pytest
from pba_service_harness import Server, execute_body, gis_processes, submit_async, wait_status

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


def test_graceful_restart_with_queued_jobs(
    tmp_path: Path, medium_doc: dict[str, Any], small_doc: dict[str, Any]
) -> None:
    # no small-job lane: the queued jobs are small, and a reserved worker would run them at once
    first = Server(tmp_path, workers=1, small_job_workers=0).start()
    try:
        with first.client() as c:  # local single-user mode: no key
            running = submit_async(c, medium_doc)
            wait_status(c, running, {"running"}, min_progress=5)
            # queued behind the running job once it holds the only worker: submitted together,
            # the small-job lane would run them first
            queued = [submit_async(c, small_doc) for _ in range(3)]
    finally:
        # uvicorn re-raises SIGTERM after its graceful shutdown, hence -15
        assert first.stop() in (0, -15)
    assert "server stopped" in [r["message"] for r in first.log_records()]  # graceful, not killed
    store = first.store()
    try:
        rec = store.get_job(running)
        assert rec is not None and rec.status == JobStatus.accepted, rec
        assert (
            "server stopped" in rec.message and rec.attempts == 0
        )  # a clean stop costs no attempt
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


def test_crash_requeues_a_running_job_once_then_fails_it(
    tmp_path: Path, medium_doc: dict[str, Any], small_doc: dict[str, Any]
) -> None:
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
            r = c.post("/processes/bundle-adjustment/execution", json=execute_body(small_doc))
            assert r.status_code == 200, r.text[:300]
    finally:
        server.stop()


def test_server_killed_alone_its_orphaned_worker_hands_the_job_back(
    tmp_path: Path, medium_doc: dict[str, Any]
) -> None:
    server = Server(tmp_path, workers=1).start()
    with server.client() as c:
        job_id = submit_async(c, medium_doc)
        wait_status(c, job_id, {"running"}, min_progress=5)
    pid = worker_pid_of(server, job_id)
    assert server.proc is not None
    gis = gis_pids_of(server.proc.pid)  # started early by pba serve
    server.proc.kill()  # only the server process; its worker notices and gives the job back
    server.proc.wait(10)
    deadline = time.monotonic() + 20
    while pid_alive(pid) or any(pid_alive(g) for g in gis):
        assert time.monotonic() < deadline, f"the orphaned worker ({pid_alive(pid)}) or a GIS process ({[pid_alive(g) for g in gis]}) did not exit"
        time.sleep(0.2)
    store = server.store()
    try:
        rec = store.get_job(job_id)
        assert rec is not None and rec.status == JobStatus.accepted and rec.attempts == 0, rec
    finally:
        store.close()
    server = Server(tmp_path, workers=1).start()
    try:
        with server.client() as c:
            assert wait_status(c, job_id, timeout=120)["status"] == "successful"
    finally:
        server.stop()


def test_time_limit_fails_a_long_job(
    tmp_path: Path, big_doc: dict[str, Any], small_doc: dict[str, Any]
) -> None:
    # 2 s: the soft limit (checked between solver iterations) or, if the solver is still setting
    # up after the 1 s grace, the supervisor's kill; both fail the job with the same reason
    server = Server(tmp_path, workers=1, job_time_limit_s=2, kill_grace_s=1).start()
    try:
        with server.client() as c:
            job_id = submit_async(c, big_doc)
            st = wait_status(c, job_id, {"failed"}, timeout=30)
            assert "time limit of 2 s exceeded" in st["message"], st
            assert (
                c.post(
                    "/processes/bundle-adjustment/execution", json=execute_body(small_doc)
                ).status_code
                == 200
            )
    finally:
        server.stop()


def worker_pid_of(server: Server, job_id: str) -> int:
    store = server.store()
    try:
        rec = store.get_job(job_id)
    finally:
        store.close()
    assert rec is not None and rec.worker
    return int(rec.worker.rsplit(":", 1)[1])


def gis_pids_of(parent: int, timeout_s: float = 30.0) -> list[int]:
    """The ``pba-gis`` processes the server process ``parent`` started (the small-transform
    lane's and a general one), once both are up."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        named = gis_processes(parent)
        if len(named) >= 2:
            return named
        time.sleep(0.2)
    raise AssertionError(f"no pba-gis process started by {parent}")


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True
