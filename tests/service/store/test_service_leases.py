"""Leases and fencing tokens of distributed runs (service.store.leases), on SQLite and on a
fresh PostgreSQL database: a job is claimed once, taken over only from a dead or silent
holder, a stale run can no longer write, and expired leases are re-queued or failed."""

from __future__ import annotations

import os
import threading
import time
from datetime import timedelta
from pathlib import Path
from typing import Iterator

import pytest
from pba_celery_harness import pg_database
from sqlalchemy import update

from service.states import JobStatus
from service.store import open_store
from service.store.leases import (
    claim_run,
    expire_leases,
    heartbeat_of,
    holder_is_dead_here,
    parse_token,
    renew,
    run_token,
)
from service.store.sql import JobRow, SqlStore, utcnow

DOC = {"job": {"name": "x"}}
LEASE_S = 30.0


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.services)])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[SqlStore]:
    if request.param == "sqlite":
        s = open_store(f"sqlite:///{tmp_path / 'store.sqlite3'}")
        try:
            yield s  # type: ignore[misc]
        finally:
            s.close()
        return
    with pg_database("lease") as url:
        s = open_store(url)
        try:
            yield s  # type: ignore[misc]
        finally:
            s.close()


def new_job(store: SqlStore) -> str:
    return store.create_job("u1", "bundle-adjustment", DOC, 10, "j").id


def age_lease(store: SqlStore, job_id: str, seconds: float) -> None:
    """Pretend the holder last renewed its lease ``seconds`` ago."""
    past = utcnow() - timedelta(seconds=seconds)
    with store.engine.begin() as conn:
        conn.execute(update(JobRow).where(JobRow.id == job_id).values(heartbeat=past, started=past))


def never_dead(_: str | None) -> bool:
    return False


def test_tokens() -> None:
    token = run_token(1234)
    host, pid = parse_token(token)  # type: ignore[misc]
    assert pid == 1234 and token.startswith(host + ":1234:")
    assert run_token(1) != run_token(1)  # a fresh token per run
    assert parse_token("host:12") is None and parse_token(None) is None
    assert not holder_is_dead_here(run_token(os.getpid()))  # this process is alive
    assert holder_is_dead_here(run_token(2**22 + 12345))  # no such pid
    assert not holder_is_dead_here("otherhost-xyz:1:abcd")  # cannot tell: lease decides


def test_claim_then_held_then_finished(store: SqlStore) -> None:
    job_id = new_job(store)
    first = claim_run(store, job_id, "h:1:a", LEASE_S, 2, never_dead)
    assert first.outcome == "claimed" and first.runnable
    assert first.job is not None and first.job.worker == "h:1:a" and first.job.attempts == 1
    assert heartbeat_of(store, job_id) is not None
    dup = claim_run(store, job_id, "h:2:b", LEASE_S, 2, never_dead)
    assert (dup.outcome, dup.holder, dup.runnable) == ("held", "h:1:a", False)
    assert store.complete(job_id, "h:1:a", '{"r": 1}', "done")
    late = claim_run(store, job_id, "h:3:c", LEASE_S, 2, never_dead)
    assert late.outcome == "finished" and not late.runnable
    assert claim_run(store, "no-such-job", "h:4:d", LEASE_S, 2).outcome == "missing"


def test_take_over_after_lease_and_fencing(store: SqlStore) -> None:
    job_id = new_job(store)
    claim_run(store, job_id, "h:1:old", LEASE_S, 3, never_dead)
    assert store.set_progress(job_id, "h:1:old", 30, "iteration 2")
    age_lease(store, job_id, LEASE_S + 1)
    new = claim_run(store, job_id, "h:2:new", LEASE_S, 3, never_dead)
    assert new.outcome == "taken_over" and new.job is not None
    assert (new.job.worker, new.job.attempts, new.job.progress) == ("h:2:new", 2, 30)
    # the old run is fenced out: nothing it writes lands
    assert not renew(store, job_id, "h:1:old")
    assert not store.set_progress(job_id, "h:1:old", 90, "stale")
    assert not store.complete(job_id, "h:1:old", '{"stale": true}', "stale")
    assert not store.fail(job_id, "stale failure", worker="h:1:old")
    assert renew(store, job_id, "h:2:new")
    assert store.complete(job_id, "h:2:new", '{"r": 2}', "done")
    rec = store.get_job(job_id)
    assert rec is not None and rec.status == JobStatus.successful and rec.results == {"r": 2}


def test_take_over_at_once_from_a_dead_holder(store: SqlStore) -> None:
    job_id = new_job(store)
    claim_run(store, job_id, "h:1:dead", LEASE_S, 2, never_dead)
    fresh = claim_run(store, job_id, "h:2:x", LEASE_S, 2, never_dead)
    assert fresh.outcome == "held"  # lease still fresh, holder not known dead
    took = claim_run(store, job_id, "h:2:x", LEASE_S, 2, lambda w: w == "h:1:dead")
    assert took.outcome == "taken_over"


def test_last_attempt_fails_and_cancelled_is_dismissed(store: SqlStore) -> None:
    job_id = new_job(store)
    claim_run(store, job_id, "h:1:a", LEASE_S, 1, never_dead)
    age_lease(store, job_id, LEASE_S + 1)
    res = claim_run(store, job_id, "h:2:b", LEASE_S, 1, never_dead)
    assert res.outcome == "failed" and res.job is not None
    assert res.job.status == JobStatus.failed and "lost 1 time" in res.job.message
    assert res.job.error == {"code": "worker_died"}

    other = new_job(store)
    claim_run(store, other, "h:1:a", LEASE_S, 2, never_dead)
    store.request_cancel(other)
    age_lease(store, other, LEASE_S + 1)
    res = claim_run(store, other, "h:2:b", LEASE_S, 2, never_dead)
    assert res.outcome == "finished" and res.job is not None
    assert res.job.status == JobStatus.dismissed


@pytest.mark.services
def test_renewing_holder_keeps_the_job() -> None:
    """A take-over is a compare-and-set on the heartbeat it read: a holder that renews its
    lease in between keeps the job (PostgreSQL; SQLite serialises the two writers anyway)."""
    with pg_database("lease") as url:
        store: SqlStore = open_store(url)  # type: ignore[assignment]
        try:
            job_id = new_job(store)
            claim_run(store, job_id, "h:1:a", LEASE_S, 3, never_dead)

            def renews_then_looks_dead(worker: str | None) -> bool:
                assert renew(store, job_id, "h:1:a")  # renewed after the claimant's read
                return True

            res = claim_run(store, job_id, "h:2:b", LEASE_S, 3, renews_then_looks_dead)
            assert res.outcome == "held", res
            assert store.get_job(job_id).worker == "h:1:a"  # type: ignore[union-attr]
        finally:
            store.close()


def test_concurrent_claims_of_one_job(store: SqlStore) -> None:
    """Eight runs receive the same message at once: exactly one claims the job."""
    job_ids = [new_job(store) for _ in range(5)]
    outcomes: list[tuple[str, str]] = []
    lock = threading.Lock()
    barrier = threading.Barrier(8)

    def run(i: int) -> None:
        barrier.wait()
        for job_id in job_ids:
            res = claim_run(store, job_id, f"h:{i}:t", LEASE_S, 2, never_dead)
            with lock:
                outcomes.append((job_id, res.outcome))

    threads = [threading.Thread(target=run, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for job_id in job_ids:
        mine = [o for j, o in outcomes if j == job_id]
        assert sorted(mine) == ["claimed"] + ["held"] * 7, mine


def test_expire_leases(store: SqlStore) -> None:
    requeue, last, late, cancelled, fresh = (new_job(store) for _ in range(5))
    for job_id in (requeue, last, late, cancelled, fresh):
        claim_run(store, job_id, f"h:1:{job_id[:4]}", LEASE_S, 5, never_dead)
    with store.engine.begin() as conn:  # the job of ``last`` has been run twice already
        conn.execute(update(JobRow).where(JobRow.id == last).values(attempts=2))
    store.request_cancel(cancelled)
    for job_id in (requeue, last, cancelled):
        age_lease(store, job_id, LEASE_S + 1)
    age_lease(store, late, 100.0)
    done = {e.job_id: e.action for e in expire_leases(store, LEASE_S, 2, job_time_limit_s=60.0)}
    assert done == {
        requeue: "requeued",
        last: "failed",
        late: "time_limit",
        cancelled: "dismissed",
    }
    rec = store.get_job(requeue)
    assert rec is not None and rec.status == JobStatus.accepted and rec.worker is None
    assert "stopped renewing its lease" in rec.message
    assert store.get_job(late).error == {"code": "time_limit"}  # type: ignore[union-attr]
    assert store.get_job(fresh).status == JobStatus.running  # type: ignore[union-attr]
    assert expire_leases(store, LEASE_S, 2, 60.0) == []  # nothing twice
    again = claim_run(store, requeue, "h:2:z", LEASE_S, 2, never_dead)
    assert again.outcome == "claimed" and again.job.attempts == 2  # type: ignore[union-attr]


def test_renew_moves_the_heartbeat(store: SqlStore) -> None:
    job_id = new_job(store)
    claim_run(store, job_id, "h:1:a", LEASE_S, 2, never_dead)
    before = heartbeat_of(store, job_id)
    time.sleep(0.01)
    assert renew(store, job_id, "h:1:a")
    after = heartbeat_of(store, job_id)
    assert before is not None and after is not None and after > before
