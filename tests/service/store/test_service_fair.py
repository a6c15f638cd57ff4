"""Fair sharing in the store (service.store.fair): which accepted job a free worker claims,
and the per-user accounting of finished runs. Both databases (the store fixture)."""

from __future__ import annotations

from typing import Any, Callable

import pytest
from test_service_store import store  # noqa: F401 - the parameterised store fixture

from service.states import JobStatus
from service.store import Store
from service.store.fair import Head, OwnerLoad, pick
from service.store.leases import Claim, claim_for_message

DOC = {"job": {"name": "x"}}


def add(store: Store, owner: str, n: int, small: bool = False) -> list[str]:
    """``n`` accepted jobs of ``owner``, oldest first."""
    return [
        store.create_job(owner, "bundle-adjustment", DOC, 10, f"{owner}{i}", small).id
        for i in range(n)
    ]


def owner_of(store: Store, job_id: str) -> str:
    rec = store.get_job(job_id)
    assert rec is not None
    return rec.owner


def claim_owners(store: Store, n: int, cap: int = 0) -> list[str]:
    """Owners of the next ``n`` claims (none of the claimed jobs finishes)."""
    out = []
    for i in range(n):
        rec = store.claim_next(f"w{i}", cap)
        assert rec is not None
        out.append(rec.owner)
    return out


def test_users_take_turns_instead_of_oldest_first(store: Store) -> None:  # noqa: F811
    # user a queued four jobs before b queued two: strictly oldest first would run a's four
    add(store, "a", 4)
    add(store, "b", 2)
    assert claim_owners(store, 6) == ["a", "b", "a", "b", "a", "a"]
    assert store.claim_next("w-idle") is None


def test_least_recent_use_breaks_ties(store: Store) -> None:  # noqa: F811
    add(store, "a", 2)
    add(store, "b", 2)
    first = store.claim_next("w1")
    assert first is not None and first.owner == "a"
    store.complete(first.id, "w1", "{}", "done")
    # nobody runs anything now; b has never run, a just did: b goes first
    assert claim_owners(store, 2) == ["b", "a"]


def test_small_lane_goes_first(store: Store) -> None:  # noqa: F811
    big = add(store, "a", 3)
    small_b = add(store, "b", 1, small=True)
    small_a = add(store, "a", 1, small=True)
    claimed = [store.claim_next(f"w{i}") for i in range(5)]
    ids = [c.id for c in claimed if c is not None]
    # both small jobs before any big one, although every big job is older
    assert set(ids[:2]) == {small_b[0], small_a[0]}
    assert ids[2:] == big


def test_weight_and_cap_while_others_wait(store: Store) -> None:  # noqa: F811
    a = store.create_user("alice", weight=4.0, max_running_jobs=2).id
    b = store.create_user("bob").id
    add(store, a, 6)
    add(store, b, 3)
    # weight 4: alice gets up to 4 running per one of bob's, but her cap of 2 holds while bob
    # waits (without the cap the fourth claim would be alice's: 2/4 < 1/1)
    assert claim_owners(store, 4) == [a, b, a, b]
    assert claim_owners(store, 1) == [b]  # bob's last job; alice stays capped
    # only alice waits now: her cap does not leave a worker idle
    assert claim_owners(store, 4) == [a, a, a, a]


def test_default_cap_applies_to_users_without_their_own(store: Store) -> None:  # noqa: F811
    add(store, "a", 4)
    add(store, "b", 1)
    first = claim_owners(store, 2, cap=2)  # a (older), then b (fewer running)
    assert first == ["a", "b"]
    add(store, "c", 2)
    # a runs 1 and is below the cap of 2: the usual share order (c runs none)
    assert claim_owners(store, 3, cap=1) == ["c", "a", "c"]


def test_pick_is_pure_and_handles_empty() -> None:
    assert pick([], {}) is None
    from datetime import datetime, timezone

    t = datetime(2026, 1, 1, tzinfo=timezone.utc)
    heads = [Head("a", False, t), Head("b", False, t.replace(year=2027))]
    loads = {"a": OwnerLoad(running=1), "b": OwnerLoad(running=0)}
    assert pick(heads, loads) == heads[1]


def test_accounting_sums_the_runs(store: Store) -> None:  # noqa: F811
    u = store.create_user("dora").id
    ids = add(store, u, 3)
    for i, job_id in enumerate(ids):
        assert store.claim(job_id, "w") is not None
    assert store.complete(ids[0], "w", "{}", "ok", (1.5, 2.0))
    assert store.fail(ids[1], "bad", {"code": "no_solution"}, worker="w", usage=(0.25, 0.5))
    store.request_cancel(ids[2])
    assert store.finish_cancelled(ids[2], "w", "cancelled", (0.125, 0.25))
    # a failure the server records for a lost worker is counted by nobody's measurement
    lost = add(store, u, 1)[0]
    store.claim(lost, "dead")
    store.fail(lost, "worker died", {"code": "worker_died"}, worker="dead")
    (row,) = [r for r in store.usage() if r.user_id == u]
    assert (row.jobs_successful, row.jobs_failed, row.jobs_dismissed) == (1, 1, 1)
    jobs = [store.get_job(i) for i in ids]
    # sums of a few binary fractions: exact in floating point on every machine
    assert row.cpu_s == sum(j.cpu_s for j in jobs if j and j.cpu_s) == 1.875
    assert row.solve_s == sum(j.solve_s for j in jobs if j and j.solve_s) == 2.75
    assert jobs[0] is not None and jobs[0].status == JobStatus.successful
    assert [r.name for r in store.usage()] == sorted(r.name for r in store.usage())


@pytest.mark.parametrize("weight", [None, 2.5])
def test_user_weight_and_cap_round_trip(store: Store, weight: float | None) -> None:  # noqa: F811
    u = store.create_user("eve", weight=weight, max_running_jobs=3)
    again = store.create_user("eve")  # None keeps the stored values
    assert (again.weight, again.max_running_jobs) == (weight, 3) == (u.weight, 3)



def message(
    store: Any, job_id: str, worker: str, dead: Callable[[str | None], bool] = lambda _: False
) -> Claim:
    """What a Celery run holding the message of ``job_id`` claims (lease 30 s, 2 attempts)."""
    return claim_for_message(store, job_id, worker, 30.0, 2, 0, dead)


def test_a_message_is_a_wake_up_token(store: Store) -> None:  # noqa: F811
    a_jobs = add(store, "a", 2)
    b_job = add(store, "b", 1)[0]
    first = message(store, a_jobs[0], "h:1:x")
    assert (first.outcome, first.job and first.job.id) == ("claimed", a_jobs[0])
    # the message of a's second job runs b's job: a already runs one, b none
    second = message(store, a_jobs[1], "h:2:y")
    assert (second.outcome, second.job and second.job.id) == ("claimed", b_job)
    # b's message then finds a's second job still waiting and runs it: no job is left behind
    third = message(store, b_job, "h:3:z")
    assert (third.outcome, third.job and third.job.id) == ("claimed", a_jobs[1])
    # a duplicate with nothing accepted is dropped, saying what became of its job
    dup = message(store, b_job, "h:4:w")
    assert (dup.outcome, dup.holder) == ("held", "h:2:y")
    assert message(store, "nope", "h:5:v").outcome == "missing"


def test_a_dead_holders_job_is_taken_over_before_new_work(store: Store) -> None:  # noqa: F811
    running = add(store, "a", 1)[0]
    waiting = add(store, "b", 1)[0]
    first = message(store, running, "h:1:dead")
    assert first.job is not None and first.job.id == running
    # a message of another job, delivered after the holder died: the orphan is run first
    took = message(store, waiting, "h:2:new", lambda w: w == "h:1:dead")
    assert (took.outcome, took.job and took.job.id) == ("taken_over", running)
    rec = store.get_job(waiting)
    assert rec is not None and rec.status == JobStatus.accepted


def test_position_and_estimated_start_follow_the_policy(store: Store) -> None:  # noqa: F811
    from datetime import timedelta

    from sqlalchemy import update

    from service.queue_view import placement
    from service.store.sql import JobRow, utcnow

    done = add(store, "c", 1)[0]
    store.claim(done, "w")
    store.complete(done, "w", "{}", "ok")
    now = utcnow()
    with store.engine.begin() as conn:  # type: ignore[attr-defined]
        conn.execute(
            update(JobRow)
            .where(JobRow.id == done)
            .values(started=now - timedelta(seconds=10), finished=now)
        )
    a_running, a1, a2 = add(store, "a", 3)
    (b1,) = add(store, "b", 1)
    store.claim(a_running, "w1")
    # a runs one already: b's job is next although it is the newest
    places = {j: placement(store, j, workers=1) for j in (a1, a2, b1)}
    assert {j: p.position for j, p in places.items() if p} == {b1: 1, a1: 2, a2: 3}
    starts = [places[j].estimated_start for j in (b1, a1, a2)]  # type: ignore[union-attr]
    assert all(s is not None for s in starts)
    # one worker, a mean solve of 10 s: each later job starts one mean solve after the one
    # before it (datetime arithmetic on one heap: exact)
    gaps = [later - earlier for earlier, later in zip(starts, starts[1:])]  # type: ignore
    assert gaps == [timedelta(seconds=10)] * 2
    assert placement(store, a_running, workers=1) is None  # running: not waiting
    assert placement(store, b1, workers=0).estimated_start is None  # type: ignore[union-attr]
