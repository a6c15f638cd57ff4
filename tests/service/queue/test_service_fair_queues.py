"""Fair sharing end to end on both queue backends: with one worker busy on one user's batch,
another user's jobs are not run after the whole batch.

Orders are read from the store's ``started`` timestamps (no wall-clock assertions). One
worker (one solve at a time) makes the order the policy's alone: strictly oldest first
would run all of user a's batch before anything of user b.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import pytest
from pba_celery_harness import (
    KEY_PREFIX,
    celery_env,
    delete_redis_keys,
    pg_database,
    settings_for,
    wait_job,
    workers,
)
from pba_service_harness import PBA, Server, execute_body, submit_async, wait_status

from service.store import JobRecord, Store, open_store

pytestmark = [pytest.mark.slow]


@pytest.fixture(scope="module")
def batch_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A job of a batch: 2 PRISM triplets, 3000 tie points, ~9000 observations (above the
    small-job threshold of 5000), a few seconds of solving."""
    out = tmp_path_factory.mktemp("batch") / "strip.json"
    subprocess.run(
        [str(PBA), "simulate", "strip", "--triplets", "2", "--tie-points", "3000", "-o", str(out)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    doc = json.loads(out.read_text())
    doc.setdefault("options", {})["covariance"] = False
    doc["name"] = "batch"
    return doc


def started(store: Store, job_id: str) -> Any:
    rec = store.get_job(job_id)
    assert rec is not None and rec.started is not None, rec
    return rec.started


def assert_fair_order(store: Store, batch: list[str], b_big: str, b_small: str) -> None:
    """b's small job starts before a's second batch job (it waits for one running job at
    most); b's big job starts before a's last one (users take turns)."""
    recs: list[JobRecord | None] = [store.get_job(i) for i in [*batch, b_big, b_small]]
    assert all(r is not None and r.status.value == "successful" for r in recs), recs
    assert started(store, b_small) < started(store, batch[1])
    assert started(store, b_big) < started(store, batch[-1])


def test_local_pool_shares_between_users(
    tmp_path: Path, batch_doc: dict[str, Any], small_doc: dict[str, Any]
) -> None:
    srv = Server(tmp_path / "srv", workers=1, require_api_keys="true").start()
    try:
        key_a, key_b = srv.create_key("a"), srv.create_key("b")
        with srv.client(key_a) as ca, srv.client(key_b) as cb:
            batch = [submit_async(ca, batch_doc) for _ in range(3)]
            wait_status(ca, batch[0], {"running"})
            b_big = submit_async(cb, batch_doc)
            # a synchronous small request: answered with the report, not handed back as 201
            r = cb.post("/processes/bundle-adjustment/execution", json=execute_body(small_doc))
            assert r.status_code == 200, r.text
            b_small = r.headers["Location"].rsplit("/", 1)[-1]
            for job_id in [*batch, b_big]:
                wait_status(ca if job_id in batch else cb, job_id, timeout=300)
        store = srv.store()
        try:
            small = store.get_job(b_small)
            assert small is not None and small.small  # below the threshold: the small lane (not because it is synchronous)
            assert_fair_order(store, batch, b_big, b_small)
        finally:
            store.close()
    finally:
        srv.stop()


@pytest.mark.services
def test_celery_shares_between_users(
    tmp_path: Path, batch_doc: dict[str, Any], small_doc: dict[str, Any]
) -> None:
    from service.queue.celery_backend import CeleryBackend

    with pg_database("fair") as url:
        env = celery_env(url, "fair-queues")
        settings = settings_for(env)
        store = open_store(settings.resolved_database_url)
        backend = CeleryBackend(settings, store)

        def submit(owner: str, doc: dict[str, Any], small: bool) -> str:
            rec = store.create_job(
                owner, "bundle-adjustment", {"job": doc}, len(doc["observations"]), "", small
            )
            backend.submit(rec.id)
            return rec.id

        try:
            with workers(env, tmp_path, n=1, concurrency=1):
                batch = [submit("a", batch_doc, False) for _ in range(3)]
                wait_job(store, batch[0], {"running"})
                b_big = submit("b", batch_doc, False)
                b_small = submit("b", small_doc, True)
                for job_id in [*batch, b_big, b_small]:
                    wait_job(store, job_id, {"successful"}, timeout=300)
            assert_fair_order(store, batch, b_big, b_small)
            # every job ran once: messages used for other jobs lost or doubled none
            runs = [getattr(store.get_job(i), "attempts", None) for i in [*batch, b_big, b_small]]
            assert runs == [1] * 5
        finally:
            backend.stop()
            store.close()
            delete_redis_keys(KEY_PREFIX)
