"""Capacity kept for the small-job lane, and the fair-share key order pinned.

The claim order (service.store.fair) is cap, then the small-job lane, then the weighted share,
then least recent use, then age: each test below builds two heads that only one key tells
apart, so swapping two keys of ``order_key`` fails one of them. A worker reserved for the small
lane (``PBA_SMALL_JOB_WORKERS``) claims only small jobs, in the same order; on a real server a
small synchronous job is answered while a big job holds the only general worker."""

from __future__ import annotations

import time
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from pba_service_harness import Server, execute_body
from test_service_fair import add
from test_service_store import store  # noqa: F401 - the parameterised store fixture

from service.store import Store
from service.store.fair import Head, OwnerLoad, pick

T0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
OLDER, NEWER = T0, T0 + timedelta(seconds=1)


def test_cap_comes_before_the_small_lane() -> None:
    heads = [Head("a", True, NEWER), Head("b", False, NEWER)]
    loads = {"a": OwnerLoad(running=1, max_running=1), "b": OwnerLoad(running=5)}
    assert pick(heads, loads).owner == "b"  # a is capped: its small job waits behind b's big one


def test_small_lane_comes_before_the_share() -> None:
    heads = [Head("a", True, NEWER), Head("b", False, OLDER)]
    loads = {"a": OwnerLoad(running=3), "b": OwnerLoad(running=0)}
    assert pick(heads, loads).owner == "a"  # share first would pick b


def test_share_comes_before_least_recent_use() -> None:
    heads = [Head("a", False, NEWER), Head("b", False, NEWER)]
    loads = {"a": OwnerLoad(running=0, last_started=NEWER), "b": OwnerLoad(running=1, last_started=OLDER)}
    assert pick(heads, loads).owner == "a"


def test_least_recent_use_comes_before_age() -> None:
    heads = [Head("a", False, OLDER), Head("b", False, NEWER)]
    loads = {"a": OwnerLoad(last_started=NEWER), "b": OwnerLoad(last_started=OLDER)}
    assert pick(heads, loads).owner == "b"


def test_weight_divides_the_share() -> None:
    heads = [Head("a", False, NEWER), Head("b", False, OLDER)]
    loads = {"a": OwnerLoad(running=2, weight=4.0), "b": OwnerLoad(running=1)}
    assert pick(heads, loads).owner == "a"  # 2/4 < 1/1


def test_a_reserved_worker_claims_only_small_jobs(store: Store) -> None:  # noqa: F811
    big = add(store, "a", 2)
    assert store.claim_next("reserved", small_only=True) is None
    small = add(store, "b", 1, small=True) + add(store, "a", 1, small=True)
    got = [store.claim_next("reserved", small_only=True) for _ in range(3)]
    assert [g.id for g in got if g is not None] == small  # fair order among the small ones
    assert store.claim_next("general").id == big[0]  # type: ignore[union-attr]


def test_a_small_sync_job_is_answered_while_a_big_one_holds_the_worker(
    tmp_path: Path, small_doc: dict[str, Any], big_doc: dict[str, Any]
) -> None:
    srv = Server(tmp_path, workers=1, require_api_keys="true")
    srv.start()
    try:
        a, b = srv.create_key("a"), srv.create_key("b")
        with srv.client(a) as ca, srv.client(b) as cb:
            r = ca.post("/processes/bundle-adjustment/execution", json=execute_body(big_doc), headers={"Prefer": "respond-async"})
            assert r.status_code == 201, r.text[:300]
            big = r.json()["jobID"]
            while ca.get(f"/jobs/{big}").json()["status"] == "accepted":
                time.sleep(0.05)
            r = cb.post("/processes/bundle-adjustment/execution", json=execute_body(small_doc))
            assert r.status_code == 200, r.text[:300]  # solved, not 201 after the sync timeout
            # the big job still holds the only general worker: the small one did not wait for it
            assert ca.get(f"/jobs/{big}").json()["status"] == "running"
            ca.delete(f"/jobs/{big}")
    finally:
        srv.stop()


def test_a_small_lane_message_claims_only_small_jobs(store: Store) -> None:  # noqa: F811
    from service.store.leases import claim_for_message

    big = add(store, "a", 1)[0]
    small = add(store, "b", 1, small=True)[0]
    got = claim_for_message(store, small, "h:1:x", 30.0, 2, small_only=True)  # type: ignore[arg-type]
    assert (got.outcome, got.job and got.job.id) == ("claimed", small)
    # nothing small is left: the lane's message is dropped, the big job waits for a general one
    dropped = claim_for_message(store, small, "h:2:y", 30.0, 2, small_only=True)  # type: ignore[arg-type]
    assert dropped.outcome == "held" and store.get_job(big).status.value == "accepted"  # type: ignore[union-attr]


def test_small_jobs_are_published_to_both_queues(monkeypatch: Any) -> None:
    from service.queue.celery_app import publish
    from service.settings import Settings

    sent: list[str] = []

    class App:
        def send_task(self, name: str, args: list[str], queue: str, **_: Any) -> None:
            sent.append(queue)

    settings = Settings(celery_queue="q", celery_small_queue="q-small")
    publish(App(), settings, "j1", small=True)  # type: ignore[arg-type]
    publish(App(), settings, "j2")  # type: ignore[arg-type]
    assert sent == ["q", "q-small", "q"]
