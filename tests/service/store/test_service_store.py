"""Store tests, parameterised by database URL: SQLite (a temp file) and PostgreSQL on
127.0.0.1 (a fresh temporary database; ``make test`` starts the server). Extra URLs can be
added with ``PBA_TEST_DATABASE_URLS`` (comma-separated)."""

from __future__ import annotations

import json
import os
import threading
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Iterator

import pytest

from service.auth import create_key, hash_key, user_for_key
from service.states import JobStatus
from service.store import SHARED, Store, open_store

PG_ADMIN_URL = os.environ.get(
    "PBA_TEST_POSTGRES_ADMIN", "postgresql://postgres@127.0.0.1:5432/postgres"
)
BACKENDS = ["sqlite", pytest.param("postgresql", marks=pytest.mark.services)] + [
    u for u in os.environ.get("PBA_TEST_DATABASE_URLS", "").split(",") if u.strip()
]


def _pg_database() -> Iterator[str]:
    import psycopg

    name = f"pba_test_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    base = PG_ADMIN_URL.rsplit("/", 1)[0].replace("postgresql://", "postgresql+psycopg://")
    try:
        yield f"{base}/{name}"
    finally:
        with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture(params=BACKENDS)
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Store]:
    if request.param == "sqlite":
        urls: Iterator[str] = iter([f"sqlite:///{tmp_path / 'store.sqlite3'}"])
    elif request.param == "postgresql":
        urls = _pg_database()
    else:
        urls = iter([request.param])
    url = next(urls)
    s = open_store(url)
    try:
        yield s
    finally:
        s.close()
        for _ in urls:  # runs the generator's clean-up
            pass


DOC = {"job": {"name": "x"}}


def new_job(store: Store, owner: str = "u1", name: str = "j") -> str:
    return store.create_job(owner, "bundle-adjustment", DOC, 10, name).id


def test_create_get_and_document(store: Store) -> None:
    rec = store.create_job("u1", "bundle-adjustment", DOC, 12, "my job")
    got = store.get_job(rec.id)
    assert got is not None
    assert (got.status, got.progress, got.owner, got.n_observations, got.name) == (
        JobStatus.accepted,
        0,
        "u1",
        12,
        "my job",
    )
    assert got.created.tzinfo is not None
    assert got.document == DOC
    assert got.results is None
    assert store.get_job("nope") is None


def test_list_filters_paging_and_counts(store: Store) -> None:
    ids = [new_job(store, "u1", f"a{i}") for i in range(5)] + [new_job(store, "u2", "b")]
    jobs, total = store.list_jobs("u1", limit=2, offset=0)
    assert total == 5 and [j.id for j in jobs] == ids[4:2:-1]  # newest first
    jobs, total = store.list_jobs("u1", limit=2, offset=4)
    assert [j.id for j in jobs] == [ids[0]]
    _, total = store.list_jobs(None)
    assert total == 6
    store.claim_next("w")
    _, total = store.list_jobs("u1", statuses=[JobStatus.running])
    assert total == 1
    assert store.count_queued("u1") == 5
    assert store.counts_by_status()[JobStatus.running] == 1


def test_claim_is_fifo_and_sets_running(store: Store) -> None:
    a, b = new_job(store), new_job(store)
    first = store.claim_next("w1")
    assert first is not None and first.id == a
    assert (first.status, first.worker, first.attempts) == (JobStatus.running, "w1", 1)
    assert first.started is not None
    second = store.claim_next("w2")
    assert second is not None and second.id == b
    assert store.claim_next("w3") is None
    assert store.claim(a, "w4") is None  # already running


def test_concurrent_claims_take_each_job_once(store: Store) -> None:
    ids = {new_job(store) for _ in range(40)}
    claimed: list[tuple[str, str]] = []
    lock = threading.Lock()

    def worker(name: str) -> None:
        while True:
            rec = store.claim_next(name)
            if rec is None:
                return
            with lock:
                claimed.append((rec.id, name))

    threads = [threading.Thread(target=worker, args=(f"w{i}",)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(c[0] for c in claimed) == sorted(ids)  # every job once, none twice


def test_progress_only_increases_and_only_for_the_holder(store: Store) -> None:
    job_id = new_job(store)
    store.claim_next("w1")
    assert store.set_progress(job_id, "w1", 40, "iteration 3")
    assert store.set_progress(job_id, "w1", 20, "late message")
    rec = store.get_job(job_id)
    assert rec is not None and rec.progress == 40 and rec.message == "late message"
    assert not store.set_progress(job_id, "other", 90, "stale worker")
    assert store.get_job(job_id).progress == 40  # type: ignore[union-attr]


def test_complete_stores_results_for_the_holder_only(store: Store) -> None:
    job_id = new_job(store)
    store.claim_next("w1")
    assert not store.complete(job_id, "w2", '{"x": 1}', "done")
    assert store.complete(job_id, "w1", '{"x": 1}', "done")
    rec = store.get_job(job_id)
    assert rec is not None
    assert (rec.status, rec.progress, rec.results) == (JobStatus.successful, 100, {"x": 1})
    assert rec.finished is not None
    assert not store.complete(job_id, "w1", '{"x": 2}', "again")  # successful -> successful refused


def test_stale_worker_cannot_finish_a_requeued_job(store: Store) -> None:
    job_id = new_job(store)
    store.claim_next("w1")
    requeued, failed = store.recover_interrupted(max_attempts=2)
    assert requeued == [job_id] and failed == []
    rec = store.get_job(job_id)
    assert rec is not None and rec.status == JobStatus.accepted and "re-queued" in rec.message
    assert not store.complete(job_id, "w1", "{}", "stale")
    again = store.claim_next("w2")
    assert again is not None and again.attempts == 2
    requeued, failed = store.recover_interrupted(max_attempts=2)
    assert requeued == [] and failed == [job_id]
    rec = store.get_job(job_id)
    assert rec is not None and rec.status == JobStatus.failed and "2 times" in rec.message


def test_requeue_without_counting_the_attempt(store: Store) -> None:
    job_id = new_job(store)
    store.claim_next("w1")
    assert store.requeue(job_id, "w1", "server stopping", count_attempt=False)
    rec = store.get_job(job_id)
    assert rec is not None and (rec.status, rec.attempts, rec.worker) == (
        JobStatus.accepted,
        0,
        None,
    )


def test_cancel_accepted_running_and_finished(store: Store) -> None:
    queued = new_job(store)
    rec = store.request_cancel(queued)
    assert rec is not None and rec.status == JobStatus.dismissed

    running = new_job(store)
    store.claim_next("w1")
    rec = store.request_cancel(running)
    assert rec is not None and rec.status == JobStatus.running and rec.cancel_requested == "user"
    assert store.cancel_requested(running) == "user"
    assert store.finish_cancelled(running, "w1", "cancelled by the user")
    assert store.get_job(running).status == JobStatus.dismissed  # type: ignore[union-attr]

    done = new_job(store)
    store.claim_next("w1")
    store.complete(done, "w1", '{"r": 1}', "ok")
    rec = store.request_cancel(done)
    assert rec is not None and rec.status == JobStatus.dismissed
    assert rec.results is None and rec.document is None
    assert store.request_cancel("missing") is None
    assert store.request_cancel(done).status == JobStatus.dismissed  # type: ignore[union-attr]


def test_fail_and_fail_jobs_of_worker(store: Store) -> None:
    a, b = new_job(store), new_job(store)
    store.claim_next("dead")
    assert store.fail_jobs_of_worker("dead", "worker died") == [a]
    rec = store.get_job(a)
    assert (
        rec is not None
        and rec.status == JobStatus.failed
        and rec.error == {"code": "worker_died"}
    )
    assert store.fail(b, "cannot run", {"code": "no_solution"})
    assert not store.fail(b, "twice")


def test_finished_since(store: Store) -> None:
    t0 = datetime.now(timezone.utc) - timedelta(seconds=1)
    job_id = new_job(store)
    store.claim_next("w")
    store.complete(job_id, "w", "{}", "ok")
    runs = store.finished_since(t0)
    assert [r.id for r in runs] == [job_id] and runs[0].finished >= runs[0].started


def test_users_and_keys(store: Store) -> None:
    key, user = create_key(store, "alice", max_queued_jobs=3)
    assert key.startswith("pba_") and user.max_queued_jobs == 3 and not user.is_admin
    assert user_for_key(store, key) == user
    assert user_for_key(store, key + "x") is None
    assert store.user_for_key_hash(hash_key(key)) is not None
    again = store.create_user("alice", is_admin=True)
    assert again.id == user.id and again.is_admin and again.max_queued_jobs == 3  # kept
    key2, same = create_key(store, "alice")  # a second key changes nothing else
    assert same == again and user_for_key(store, key2) == again
    prefix = key.split("_")[1]
    assert store.revoke_api_key(prefix)
    assert user_for_key(store, key) is None


def test_camera_versions(store: Store) -> None:
    c1 = store.add_camera("prism-n", "first", {"focal_mm": 1939.0}, "u1")
    c2 = store.add_camera("prism-n", "second", {"focal_mm": 1939.1}, "u1", source_job="j1")
    store.add_camera("other", "", {"focal_mm": 1.0}, "u2")
    assert (c1.version, c2.version) == (1, 2) and c1.owner == "u1" and not c1.shared
    latest = store.get_camera("prism-n", owner="u1")
    assert latest is not None and latest.version == 2 and latest.source_job == "j1"
    first = store.get_camera("prism-n", 1, owner="u1")
    assert first is not None and first.definition == {"focal_mm": 1939.0}
    assert store.get_camera("prism-n", 0, owner="u1") == first  # 0: the first version
    assert store.get_camera("prism-n", 3, owner="u1") is None
    cams, total = store.list_cameras(owners=["u1", "u2"])
    assert total == 2 and {(c.name, c.version) for c in cams} == {("prism-n", 2), ("other", 1)}
    cams, total = store.list_cameras("prism-n", owners=["u1"])
    assert total == 2 and [c.version for c in cams] == [2, 1]


def test_camera_version_exact_insert(store: Store) -> None:
    first = store.add_camera_version("p", 1, "one", {"focal_mm": 1.0}, "presets", owner=SHARED)
    assert first is not None and first.version == 1 and first.definition == {"focal_mm": 1.0}
    # the same version again (another server was first): refused, nothing renumbered
    assert store.add_camera_version("p", 1, "one", {"focal_mm": 9.0}, "presets", owner=SHARED) is None
    cams, total = store.list_cameras("p", owners=[SHARED])
    assert total == 1 and cams[0].definition == {"focal_mm": 1.0}


def test_presets_published_once_by_servers_starting_together(store: Store) -> None:
    """Several API servers start at once on one store (scale-out): every preset version is
    stored exactly once (before, two servers could each add version 1, the second as 2)."""
    from service.cameras import ensure_presets
    from solver.importers.presets import PRESETS

    n = 4
    barrier = threading.Barrier(n)
    errors: list[BaseException] = []

    def start_server() -> None:
        try:
            barrier.wait(timeout=30)
            ensure_presets(store)
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=start_server) for _ in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert not errors, errors
    for name, versions in PRESETS.items():
        cams, total = store.list_cameras(name, 1000, 0, owners=[SHARED])
        assert total == len(versions), (name, [c.version for c in cams])
        assert sorted(c.version for c in cams) == list(range(1, len(versions) + 1))


def test_camera_namespaces_are_separate(store: Store) -> None:
    """The same name in two users' namespaces and the shared one: versions count per
    namespace, lookups never cross namespaces."""
    store.add_camera("cam", "", {"focal_mm": 1.0}, "u1")
    b = store.add_camera("cam", "", {"focal_mm": 2.0}, "u2")
    s = store.add_camera("cam", "", {"focal_mm": 3.0}, "u1", owner=SHARED)
    assert (b.version, b.owner, s.version, s.shared) == (1, "u2", 1, True)
    own = store.get_camera("cam", owner="u1")
    assert own is not None and own.definition == {"focal_mm": 1.0}
    assert store.get_camera("cam", owner="u3") is None
    cams, total = store.list_cameras(owners=["u1", SHARED])
    assert total == 2 and [c.shared for c in cams] == [False, True]  # own first on a tie


# -- retention and compressed payloads ----------------------------------------------------
def _finish(store: Store, job_id: str, report: str = '{"ok": true}') -> None:
    assert store.claim(job_id, "w") is not None
    assert store.complete(job_id, "w", report, "done")


def _age(store: Store, job_id: str, days: float) -> None:
    """Pretend a job finished ``days`` ago (the store stamps finished itself)."""
    from sqlalchemy import update

    from service.store.sql import JobRow

    when = datetime.now(timezone.utc) - timedelta(days=days)
    with store.engine.begin() as conn:  # type: ignore[attr-defined]
        conn.execute(update(JobRow).where(JobRow.id == job_id).values(finished=when, created=when))


def test_prune_deletes_only_old_finished_jobs(store: Store) -> None:
    old_ok = store.create_job("u", "bundle-adjustment", DOC, 1, "old-ok")
    _finish(store, old_ok.id)
    old_failed = store.create_job("u", "bundle-adjustment", DOC, 1, "old-failed")
    store.fail(old_failed.id, "bad")
    old_dismissed = store.create_job("u", "bundle-adjustment", DOC, 1, "old-dismissed")
    store.request_cancel(old_dismissed.id)
    new_ok = store.create_job("u", "bundle-adjustment", DOC, 1, "new-ok")
    _finish(store, new_ok.id)
    accepted = store.create_job("u", "bundle-adjustment", DOC, 1, "queued")
    running = store.create_job("u", "bundle-adjustment", DOC, 1, "running")
    store.claim(running.id, "w")
    for j in (old_ok, old_failed, old_dismissed, accepted, running):
        _age(store, j.id, 40)  # accepted/running ones old too: they must stay anyway
    cutoff = datetime.now(timezone.utc) - timedelta(days=30)
    dry = store.prune_jobs(cutoff, dry_run=True)
    assert {p.id for p in dry} == {old_ok.id, old_failed.id, old_dismissed.id}
    assert store.get_job(old_ok.id) is not None  # a dry run deletes nothing
    done = store.prune_jobs(cutoff)
    assert {p.id for p in done} == {old_ok.id, old_failed.id, old_dismissed.id}
    for j in (old_ok, old_failed, old_dismissed):
        assert store.get_job(j.id) is None and store.get_document(j.id) is None
    for j in (new_ok, accepted, running):
        assert store.get_job(j.id) is not None
    assert store.get_results_text(new_ok.id) == '{"ok": true}'
    assert store.prune_jobs(cutoff) == []


def test_payloads_are_stored_compressed_and_counted(store: Store) -> None:
    from sqlalchemy import select

    from service.store.sql import JobPayloadRow

    rows = [{"id": i, "residual_px": [0.5, -0.25]} for i in range(2000)]
    report = json.dumps({"observations": rows})
    doc = {"job": {"name": "x", "points": [{"id": f"p{i}"} for i in range(500)]}}
    rec = store.create_job("u", "bundle-adjustment", doc, 1, "x")
    _finish(store, rec.id, report)
    assert store.get_results_text(rec.id) == report and store.get_document(rec.id) == doc
    with store.engine.connect() as conn:  # type: ignore[attr-defined]
        row = conn.execute(select(JobPayloadRow).where(JobPayloadRow.job_id == rec.id)).one()
    assert row.results is None and row.document is None  # nothing plain in new rows
    assert len(row.results_z) < len(report) / 5  # repeated keys deflate well
    assert store.storage_used("u") == len(row.results_z) + len(row.document_z)
    assert store.storage_used("other") == 0
    store.request_cancel(rec.id)  # dismissing drops the payloads and their bytes
    assert store.storage_used("u") == 0


def test_plain_rows_written_before_compression_are_read(store: Store) -> None:
    from sqlalchemy import update

    from service.store.sql import JobPayloadRow

    rec = store.create_job("u", "bundle-adjustment", DOC, 1, "x")
    _finish(store, rec.id)
    with store.engine.begin() as conn:  # type: ignore[attr-defined]  # as revision 0002 wrote it
        conn.execute(
            update(JobPayloadRow)
            .where(JobPayloadRow.job_id == rec.id)
            .values(document=json.dumps(DOC), results='{"old": 1}', document_z=None, results_z=None)
        )
    assert store.get_document(rec.id) == DOC
    assert store.get_results_text(rec.id) == '{"old": 1}'
