"""The distributed queue against real servers: Celery workers (``pba worker`` subprocesses,
prefork pools) on the Redis at 127.0.0.1, the job store in a fresh PostgreSQL database, the
real solver. Jobs run and give the solver's numbers; a cancelled job stops within an
iteration; a pool process or a whole worker killed with SIGKILL mid-job gets its job
redelivered and completed exactly once; two workers share a burst; a warm shutdown hands a
running job to another worker; the HTTP API works unchanged with ``PBA_QUEUE=celery``.

Exactly once is checked twice: in the store (one successful run, the run count) and in the
workers' logs (exactly one run of each job ended with a report; the killed run never did).
"""

from __future__ import annotations

import copy
import json
import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Any, Iterator

import httpx
import pytest
from pba_celery_harness import (
    KEY_PREFIX,
    celery_env,
    delete_redis_keys,
    ended_runs,
    holder_pid,
    pg_database,
    run_outcomes,
    same_numbers,
    settings_for,
    wait_job,
    workers,
)
from pba_service_harness import PBA, Server, execute_body, load_example, submit_async, wait_status

from service.errors import failed_job_status
from service.queue.celery_backend import CeleryBackend
from service.store import Store, open_store

pytestmark = [pytest.mark.services, pytest.mark.slow]


@pytest.fixture(scope="module", autouse=True)
def _clean_redis() -> Iterator[None]:
    yield
    delete_redis_keys(KEY_PREFIX)


@pytest.fixture(scope="module")
def nadir_doc() -> dict[str, Any]:
    """examples/prism-nadir.json: one image, 23 observations (a fraction of a second)."""
    return load_example("prism-nadir.json")


@pytest.fixture(scope="module")
def strip_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A job that solves for a few seconds: 4 PRISM triplets, 6000 tie points, ~18k image
    observations, no covariance (pba simulate)."""
    out = tmp_path_factory.mktemp("strip") / "strip.json"
    subprocess.run(
        [str(PBA), "simulate", "strip", "--triplets", "4", "--tie-points", "6000", "-o", str(out)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    doc = json.loads(out.read_text())
    doc.setdefault("options", {})["covariance"] = False
    doc["name"] = "strip"
    return doc


class Deployment:
    """A store on a fresh PostgreSQL database and the API side of the Celery queue."""

    def __init__(self, env: dict[str, str]) -> None:
        self.env = env
        self.settings = settings_for(env)
        self.store: Store = open_store(self.settings.resolved_database_url)
        self.backend = CeleryBackend(self.settings, self.store)

    def submit(self, doc: dict[str, Any], process: str = "bundle-adjustment") -> str:
        """Store an accepted job and send its message (what the API's submit does)."""
        rec = self.store.create_job(
            "tester", process, {"job": doc}, len(doc["observations"]), doc.get("name", "")
        )
        self.backend.submit(rec.id)
        return rec.id

    def close(self) -> None:
        self.backend.stop()
        self.store.close()


@pytest.fixture
def deployment(request: pytest.FixtureRequest) -> Iterator[Deployment]:
    with pg_database("celery") as url:
        d = Deployment(celery_env(url, request.node.name[:40]))
        try:
            yield d
        finally:
            d.close()


def test_jobs_run_on_celery_workers(
    deployment: Deployment, tmp_path: Path, nadir_doc: dict[str, Any], strip_doc: dict[str, Any]
) -> None:
    import solver.api
    from solver.report.json_text import report_json

    direct = json.loads(report_json(solver.api.run(copy.deepcopy(nadir_doc))))
    bad = copy.deepcopy(nadir_doc)
    bad["observations"][0]["image"] = "no-such-image"
    with workers(deployment.env, tmp_path, n=1, concurrency=2) as ws:
        store = deployment.store
        good, wrong = deployment.submit(nadir_doc), deployment.submit(bad)
        rec = wait_job(store, good, {"successful"})
        assert rec.progress == 100 and rec.attempts == 1
        same_numbers(direct, rec.results)
        rec = wait_job(store, wrong, {"failed"})
        assert rec.error is not None and failed_job_status(rec.error) == 422, rec.error
        assert "no-such-image" in json.dumps(rec.error)

        # progress while solving, then a cancel stops the solve within an iteration
        long = deployment.submit(strip_doc)
        rec = wait_job(store, long, {"running"}, min_progress=10)  # iterating
        assert rec.worker and holder_pid(rec) != ws[0].pid  # solved in a pool process
        store.request_cancel(long)
        rec = wait_job(store, long, {"dismissed"}, timeout=30)  # a liveness limit, not a speed claim
        assert rec.message == "cancelled by the user"
        assert ended_runs(ws, long) == [(rec.worker, "dismissed")]


def test_killed_pool_process_job_is_redelivered_and_finished_once(
    deployment: Deployment, tmp_path: Path, strip_doc: dict[str, Any]
) -> None:
    """kill -9 of the pool process solving a job (as a native crash would): Celery requeues
    the message at once (reject_on_worker_lost) and a pool process takes the job over."""
    with workers(deployment.env, tmp_path, n=2) as ws:
        store = deployment.store
        job_id = deployment.submit(strip_doc)
        first = wait_job(store, job_id, {"running"}, min_progress=1)
        os.kill(holder_pid(first), signal.SIGKILL)
        rec = wait_job(store, job_id, {"successful"}, timeout=120)
        assert rec.attempts == 2 and rec.worker != first.worker, rec
        assert rec.results is not None and rec.results["kind"] != "comparison"
        outcomes = ended_runs(ws, job_id)
        assert outcomes == [(rec.worker, "successful")], outcomes  # the killed run never ended
        assert all(w.alive() for w in ws)  # a pool process died, not the workers


def test_killed_worker_job_is_requeued_and_finished_once(
    deployment: Deployment, tmp_path: Path, strip_doc: dict[str, Any]
) -> None:
    """kill -9 of a whole worker (main and pool processes: its machine vanishes): the job's
    lease expires, a sweeper re-queues it, the other worker finishes it once."""
    with workers(deployment.env, tmp_path, n=2) as ws:
        store = deployment.store
        job_id = deployment.submit(strip_doc)
        first = wait_job(store, job_id, {"running"}, min_progress=1)
        pid = holder_pid(first)
        victim = next(w for w in ws if os.getpgid(pid) == w.pid)
        survivor = next(w for w in ws if w is not victim)
        t0 = time.monotonic()
        victim.kill_group()
        rec = wait_job(store, job_id, {"successful"}, timeout=120)
        assert rec.attempts == 2 and rec.worker != first.worker
        assert ended_runs([survivor], job_id) == [(rec.worker, "successful")]
        assert run_outcomes([victim], job_id) == []
        lease_s = deployment.settings.lease_s
        assert time.monotonic() - t0 >= lease_s * 0.9  # waited for the lease, not less
        swept = [
            r
            for r in survivor.records()
            if r.get("job_id") == job_id and "lease of" in str(r.get("message"))
        ]
        assert swept, "the surviving worker's sweeper re-queued the job"


def test_two_workers_share_a_burst(
    deployment: Deployment, tmp_path: Path, nadir_doc: dict[str, Any]
) -> None:
    with workers(deployment.env, tmp_path, n=2) as ws:
        store = deployment.store
        ids = [deployment.submit(nadir_doc) for _ in range(40)]
        recs = [wait_job(store, job_id, {"successful"}, timeout=120) for job_id in ids]
        assert all(r.attempts == 1 for r in recs)
        holders = {r.worker.split(":")[1] for r in recs if r.worker}  # pool process pids
        pgids = {os.getpgid(int(pid)) for pid in holders}
        assert pgids == {w.pid for w in ws}, "both workers took jobs"
        ended_runs(ws, ids[-1])
        for job_id in ids:
            assert [o for _, o in run_outcomes(ws, job_id)] == ["successful"], job_id
        first = recs[0].results
        for r in recs[1:]:
            same_numbers(first, r.results)


def test_warm_shutdown_hands_the_job_to_another_worker(
    deployment: Deployment, tmp_path: Path, strip_doc: dict[str, Any]
) -> None:
    with workers(deployment.env, tmp_path, n=2) as ws:
        store = deployment.store
        job_id = deployment.submit(strip_doc)
        first = wait_job(store, job_id, {"running"}, min_progress=10)  # iterating
        victim = next(w for w in ws if os.getpgid(holder_pid(first)) == w.pid)
        victim.stop(timeout=30)  # SIGTERM: the solve stops, the job goes back to the queue
        assert victim.proc is not None and victim.proc.returncode is not None
        rec = wait_job(store, job_id, {"successful"}, timeout=120)
        assert rec.worker != first.worker and rec.attempts == 1  # a handed-back run is free
        assert [o for _, o in ended_runs(ws, job_id)] == ["successful"]


def test_time_limit_stops_a_solve(
    tmp_path: Path, strip_doc: dict[str, Any], request: pytest.FixtureRequest
) -> None:
    """PBA_JOB_TIME_LIMIT_S on a Celery worker: the solve stops at an iteration, job failed."""
    with pg_database("celery") as url:
        # the strip job now solves in ~2 s (faster solver kernels), so the limit must be well below
        env = celery_env(url, "time-limit", job_time_limit_s=0.5, kill_grace_s=30)
        d = Deployment(env)
        try:
            with workers(env, tmp_path, n=1) as ws:
                job_id = d.submit(strip_doc)
                rec = wait_job(d.store, job_id, {"failed"}, timeout=120)
                assert rec.error == {"code": "time_limit"}, rec.error
                assert "time limit of 0.5 s exceeded" in rec.message
                assert [o for _, o in ended_runs(ws, job_id)] == ["failed"]
        finally:
            d.close()


def test_sweeper_keeps_jobs_it_could_not_send(
    deployment: Deployment, tmp_path: Path, nadir_doc: dict[str, Any]
) -> None:
    """A job whose lease expired is re-queued; if the broker cannot take its message then,
    the sweeper keeps it and sends it on a later pass, and a worker runs it."""
    from datetime import timedelta

    from sqlalchemy import update

    from service.queue.celery_app import create_celery, sweep
    from service.store.leases import claim_run
    from service.store.sql import JobRow, utcnow

    store = deployment.store
    rec = store.create_job("tester", "bundle-adjustment", {"job": nadir_doc}, 23, "orphan")
    assert claim_run(store, rec.id, "gone-host:1:dead", 3.0, 2).runnable  # type: ignore[arg-type]
    past = utcnow() - timedelta(seconds=60)
    with store.engine.begin() as conn:  # type: ignore[attr-defined]
        conn.execute(update(JobRow).where(JobRow.id == rec.id).values(heartbeat=past))
    down = settings_for({**deployment.env, "PBA_BROKER_URL": "redis://127.0.0.1:1/0"})
    unsent: set[str] = set()
    expired = sweep(create_celery(down), down, store, unsent)
    assert [(e.job_id, e.action) for e in expired] == [(rec.id, "requeued")]
    assert unsent == {rec.id}  # not lost: kept for the next pass
    sweep(deployment.backend.app, deployment.settings, store, unsent)
    assert unsent == set()
    with workers(deployment.env, tmp_path, n=1):
        done = wait_job(store, rec.id, {"successful"}, timeout=120)
    assert done.attempts == 2


class CeleryServer(Server):
    """``pba serve`` with PBA_QUEUE=celery and the store in PostgreSQL."""

    def __init__(self, data_dir: Path, env: dict[str, str]) -> None:
        super().__init__(data_dir, workers=0)
        self.env.update(env)

    @property
    def database_url(self) -> str:
        return self.env["PBA_DATABASE_URL"]


def test_http_api_with_celery_queue(
    deployment: Deployment,
    tmp_path: Path,
    triplet_doc: dict[str, Any],
    strip_doc: dict[str, Any],
) -> None:
    """The OGC API unchanged over Celery: synchronous and asynchronous execution with the
    solver's numbers, status, CSV, cancel, readiness and metrics."""
    import solver.api
    from solver.report.json_text import report_json

    direct = json.loads(report_json(solver.api.run(copy.deepcopy(triplet_doc))))
    server = CeleryServer(tmp_path / "api", deployment.env)
    with workers(deployment.env, tmp_path, n=2):
        server.start()
        try:
            with server.client() as c:
                deadline = time.monotonic() + 30
                while True:  # the API counts the workers' pool processes
                    ready = c.get("/readyz").json()
                    if "2 worker processes" in ready["checks"]["queue"]:
                        break
                    assert time.monotonic() < deadline, ready
                    time.sleep(0.3)
                assert "pba_workers 2.0" in c.get("/metrics").text
                r = c.post("/processes/bundle-adjustment/execution", json=execute_body(triplet_doc))
                assert r.status_code == 200, r.text[:500]
                same_numbers(direct, r.json())
                job_id = submit_async(c, triplet_doc)
                st = wait_status(c, job_id)
                assert st["status"] == "successful" and st["progress"] == 100, st
                same_numbers(direct, c.get(f"/jobs/{job_id}/results").json()["report"])
                csv = c.get(f"/jobs/{job_id}/results/parameters.csv")
                assert csv.status_code == 200 and csv.text.count("\n") > 3

                long = submit_async(c, strip_doc)
                wait_status(c, long, {"running"}, min_progress=10)
                assert c.delete(f"/jobs/{long}").status_code == 200
                st = wait_status(c, long, {"dismissed"}, timeout=30)
                assert st["message"] == "cancelled by the user"
                listed = c.get("/jobs", params={"limit": 10}).json()
                assert {j["jobID"] for j in listed["jobs"]} >= {job_id, long}
        finally:
            server.stop()
    with pytest.raises(httpx.HTTPError):
        httpx.get(f"{server.url}/healthz", timeout=1)
