"""Retention (issue 13): the server deletes finished jobs past PBA_JOB_RETENTION_DAYS, the
per-user storage quota refuses submissions with a 413 problem, ``pba db prune`` prunes by
hand. In-process servers without workers; jobs are finished and aged through the store."""

from __future__ import annotations

import os
import subprocess
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from pba_service_harness import PBA
from sqlalchemy import update
from test_service_api import assert_problem, body, make_client

from service.retention import RetentionLoop, prune
from service.settings import Settings
from service.store import Store, open_store
from service.store.sql import JobRow

EXECUTE = "/processes/bundle-adjustment/execution"
DOC = {"job": {"name": "x"}}


def finished_job(store: Store, days_ago: float, owner: str = "u") -> str:
    """A successful job that finished ``days_ago`` days ago."""
    rec = store.create_job(owner, "bundle-adjustment", DOC, 1, "x")
    assert store.claim(rec.id, "w") is not None
    assert store.complete(rec.id, "w", '{"report": 1}', "done")
    age(store, rec.id, days_ago)
    return rec.id


def age(store: Store, job_id: str, days_ago: float) -> None:
    when = datetime.now(timezone.utc) - timedelta(days=days_ago)
    with store.engine.begin() as conn:  # type: ignore[attr-defined]
        conn.execute(update(JobRow).where(JobRow.id == job_id).values(finished=when, created=when))


def test_prune_by_age(tmp_path: Path) -> None:
    store = open_store(f"sqlite:///{tmp_path / 's.sqlite3'}")
    try:
        old, recent = finished_job(store, 10), finished_job(store, 1)
        running = store.create_job("u", "bundle-adjustment", DOC, 1, "r")
        store.claim(running.id, "w")
        age(store, running.id, 10)
        assert [p.id for p in prune(store, 5, dry_run=True)] == [old]
        assert store.get_job(old) is not None
        assert [p.id for p in prune(store, 5)] == [old]
        assert store.get_job(old) is None
        assert store.get_job(recent) is not None and store.get_job(running.id) is not None
    finally:
        store.close()


def test_retention_loop_runs_in_the_server(tmp_path: Path) -> None:
    """With PBA_JOB_RETENTION_DAYS the server prunes on its own (first pass at start-up)."""
    store = open_store(Settings(data_dir=tmp_path).resolved_database_url)
    old, recent = finished_job(store, 40), finished_job(store, 2)
    with make_client(tmp_path, job_retention_days=30, retention_interval_s=0.05):
        deadline = time.monotonic() + 30  # a bound on the wait, not a timing assertion
        while store.get_job(old) is not None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert store.get_job(old) is None
        assert store.get_job(recent) is not None
    store.close()


def test_retention_loop_survives_a_failing_pass(tmp_path: Path) -> None:
    class Broken:
        calls = 0

        def prune_jobs(self, *a: Any, **k: Any) -> list[Any]:
            Broken.calls += 1
            raise RuntimeError("database away")

    loop = RetentionLoop(Broken(), 1, 0.01)  # type: ignore[arg-type]
    loop.start()
    deadline = time.monotonic() + 30
    while Broken.calls < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    loop.stop()
    assert Broken.calls >= 3  # it kept running after the first failure


def test_storage_quota(tmp_path: Path, triplet_doc: dict[str, Any]) -> None:
    """A submission that would take the user over the quota is a 413 problem; deleting a
    job frees its space."""
    with make_client(tmp_path) as c:  # no quota: measure what one job stores
        job_id = c.post(EXECUTE, json=body(triplet_doc)).json()["jobID"]
        store = c.app.state.services.store  # type: ignore[attr-defined]
        one_job = store.storage_used(store.get_job(job_id).owner)
    assert one_job > 0
    quota_mb = 1.5 * one_job / 1e6  # room for one job, not two
    with make_client(tmp_path, user_storage_quota_mb=quota_mb) as c:
        doc = assert_problem(c.post(EXECUTE, json=body(triplet_doc)), 413)
        assert doc["type"] == "urn:pba:problem:storage-quota-exceeded"
        assert "quota" in doc["detail"]
        assert c.delete(f"/jobs/{job_id}").status_code == 200
        assert c.post(EXECUTE, json=body(triplet_doc)).status_code == 201


def run_pba(args: list[str], data_dir: Path, **env: str) -> subprocess.CompletedProcess[str]:
    environ = {k: v for k, v in os.environ.items() if not k.startswith("PBA_")}
    environ.update(PBA_DATA_DIR=str(data_dir), **env)
    return subprocess.run(
        [str(PBA), *args], env=environ, capture_output=True, text=True, timeout=120
    )


def test_pba_db_prune(tmp_path: Path) -> None:
    store = open_store(Settings(data_dir=tmp_path).resolved_database_url)
    old, recent = finished_job(store, 40), finished_job(store, 2)
    store.close()
    r = run_pba(["db", "prune"], tmp_path)
    assert r.returncode == 2 and "--older-than-days" in r.stderr  # no age given: nothing done
    r = run_pba(["db", "prune", "--older-than-days", "30", "--dry-run"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[0] == old and "would delete 1 " in r.stderr
    r = run_pba(["db", "prune", "--vacuum"], tmp_path, PBA_JOB_RETENTION_DAYS="30")
    assert r.returncode == 0 and "deleted 1 " in r.stderr, r.stderr
    store = open_store(Settings(data_dir=tmp_path).resolved_database_url)
    try:
        assert store.get_job(old) is None and store.get_job(recent) is not None
    finally:
        store.close()
