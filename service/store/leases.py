"""Leases of distributed runs: the store's guarantee that a job is run to completion once.

A distributed worker (Celery, :mod:`service.queue.celery_app`) runs a job under a *fencing token*:
the ``worker`` string it writes when it claims the job, ``host:pid:token`` with a fresh random
token per run. Every write of a run (progress, report, failure) is a compare-and-set on that
token (:mod:`service.store.sql`), so once a job has been taken away from a run - re-queued
after its lease expired, taken over by a redelivered message, cancelled - nothing that run
writes lands, even if its process is still alive somewhere.

The run renews its lease by writing ``jobs.heartbeat`` (:func:`renew`) every
``PBA_HEARTBEAT_INTERVAL_S``; a running job whose heartbeat is older than ``PBA_LEASE_S`` is
presumed orphaned:

* a redelivered message for it (``acks_late`` + ``reject_on_worker_lost``) takes it over at
  once when its holder is known dead (:func:`claim_run`), and otherwise after the lease;
* a sweeper (API server and every worker, :func:`expire_leases`) re-queues it - or fails it
  when it has been run ``PBA_MAX_ATTEMPTS`` times or is past its time limit - so a job whose
  whole worker machine vanished is not left running.

Times come from the clocks of the machines writing them: keep them synchronised (NTP); a
lease of tens of seconds tolerates the usual skew. Local workers (``PBA_QUEUE=local``) leave
``heartbeat`` NULL and are supervised by their server instead; the two queues must not share
one database.
"""

from __future__ import annotations

import json
import os
import secrets
import socket
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from typing import Callable, Literal

from sqlalchemy import func, select, update

from service.states import FINISHED, FailureCode, JobStatus
from service.store.base import JobRecord
from service.store.rows import JobRow
from service.store.sql import LOST_RACE, RunningJob, SqlStore, _status_change, utcnow

ClaimOutcome = Literal[
    "claimed", "taken_over", "held", "finished", "failed", "missing", "contended"
]


@dataclass(frozen=True)
class Claim:
    """What :func:`claim_run` did. ``job`` is the record after the claim (running for this
    run when ``outcome`` is ``claimed``/``taken_over``); ``holder`` the run holding it when
    ``held``."""

    outcome: ClaimOutcome
    job: JobRecord | None
    holder: str | None = None

    @property
    def runnable(self) -> bool:
        """True when this run now holds the job and must solve it."""
        return self.outcome in ("claimed", "taken_over")


def run_token(pid: int | None = None) -> str:
    """A fencing token for one run: ``host:pid:random``."""
    return (
        f"{socket.gethostname()}:{pid if pid is not None else os.getpid()}:{secrets.token_hex(4)}"
    )


def parse_token(worker: str | None) -> tuple[str, int] | None:
    """(host, pid) of a run token, or None when it is not one."""
    if not worker:
        return None
    parts = worker.rsplit(":", 2)
    if len(parts) != 3 or not parts[1].isdigit():
        return None
    return parts[0], int(parts[1])


def _pid_gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            state = f.read().rsplit(b")", 1)[1].split()[0]
        return state in (b"Z", b"X")  # a zombie has already died
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:
            return False
        return False


def holder_is_dead_here(worker: str | None) -> bool:
    """True when ``worker`` is a run token of this host whose process no longer exists.

    A holder on another host cannot be checked from here: its lease decides.
    """
    parsed = parse_token(worker)
    if parsed is None:
        return False
    host, pid = parsed
    return host == socket.gethostname() and pid != os.getpid() and _pid_gone(pid)


def _lease_of(job: JobRecord, heartbeat: datetime | None) -> datetime:
    return heartbeat or job.started or job.updated


def _heartbeat_is(observed: datetime | None):  # noqa: ANN202 - a SQLAlchemy condition
    return JobRow.heartbeat.is_(None) if observed is None else JobRow.heartbeat == observed


def claim_run(
    store: SqlStore,
    job_id: str,
    worker: str,
    lease_s: float,
    max_attempts: int,
    holder_dead: Callable[[str | None], bool] = holder_is_dead_here,
) -> Claim:
    """Take ``job_id`` for the run ``worker``: claim it when accepted, take it over when it is
    running under an expired lease (or a holder known dead), else say why not.

    Taking over counts an attempt; a job already run ``max_attempts`` times is failed instead,
    and one whose cancellation was requested is dismissed. Every change is a compare-and-set
    on the holder's token *and* the heartbeat value read, so a holder renewing its lease at
    the same moment keeps the job.
    """
    _status_change(JobStatus.running, [JobStatus.accepted])
    for _ in range(5):
        now = utcnow()
        with store.engine.begin() as conn:
            res = conn.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.status == JobStatus.accepted.value)
                .values(
                    status=JobStatus.running.value,
                    worker=worker,
                    started=now,
                    updated=now,
                    heartbeat=now,
                    attempts=JobRow.attempts + 1,
                    message="running",
                    cancel_requested=None,
                )
            )
            if res.rowcount == 1:
                return Claim("claimed", store._fetch(conn, job_id))
            row = conn.execute(select(JobRow).where(JobRow.id == job_id)).first()
            if row is None:
                return Claim("missing", None)
            job = store._record(row)
            if job.status in FINISHED:
                return Claim("finished", job)
            if job.status == JobStatus.accepted:
                continue  # changed under us: try again
            expired = _lease_of(job, row.heartbeat) < now - timedelta(seconds=lease_s)
            if not (expired or holder_dead(job.worker)):
                return Claim("held", job, job.worker)
            same_run = (
                JobRow.id == job_id,
                JobRow.status == JobStatus.running.value,
                JobRow.worker == job.worker,
                _heartbeat_is(row.heartbeat),
            )
            if job.cancel_requested:
                _status_change(JobStatus.dismissed, [JobStatus.running])
                done = conn.execute(
                    update(JobRow)
                    .where(*same_run)
                    .values(
                        status=JobStatus.dismissed.value,
                        message="cancelled by the user (its worker had stopped)",
                        updated=now,
                        finished=now,
                    )
                ).rowcount
                if done:
                    return Claim("finished", store._fetch(conn, job_id))
                continue
            if job.attempts >= max_attempts:
                _status_change(JobStatus.failed, [JobStatus.running])
                done = conn.execute(
                    update(JobRow)
                    .where(*same_run)
                    .values(
                        status=JobStatus.failed.value,
                        message=lost_message(job.attempts, max_attempts),
                        error=json.dumps({"code": FailureCode.worker_died}),
                        updated=now,
                        finished=now,
                    )
                ).rowcount
                if done:
                    return Claim("failed", store._fetch(conn, job_id))
                continue
            took = conn.execute(
                update(JobRow)
                .where(*same_run)
                .values(
                    worker=worker,
                    started=now,
                    updated=now,
                    heartbeat=now,
                    attempts=JobRow.attempts + 1,
                    message=f"running again (the worker of run {job.attempts} was lost)",
                )
            ).rowcount
            if took:
                return Claim("taken_over", store._fetch(conn, job_id))
    job = store.get_job(job_id)
    return Claim("held", job, job.worker if job else None)


def _orphans(
    running: list[RunningJob],
    job_id: str,
    worker: str,
    lease_s: float,
    holder_dead: Callable[[str | None], bool],
) -> list[str]:
    """Running jobs a message's run should try to take over (:func:`claim_run` decides,
    atomically): the named job when its lease has expired or its holder is known dead, and
    any other job whose holder is known dead."""
    cutoff = utcnow() - timedelta(seconds=lease_s)
    found = []
    for job in running:
        if job.id == job_id:
            if job.lease < cutoff or holder_dead(job.worker):
                found.append(job.id)
        elif job.worker != worker and holder_dead(job.worker):
            found.append(job.id)
    return found


def claim_for_message(
    store: SqlStore,
    job_id: str,
    worker: str,
    lease_s: float,
    max_attempts: int,
    max_running_per_user: int = 0,
    holder_dead: Callable[[str | None], bool] = holder_is_dead_here,
    small_only: bool = False,
) -> Claim:
    """What the run ``worker`` holding the message of ``job_id`` does: the message is a
    wake-up token, not an assignment (docs/how-to/lab-server.md "Fair sharing").

    1. the named job, or any running job whose holder is known dead, is taken over at once
       (:func:`claim_run`: the delivery guarantees of a redelivered message are unchanged);
    2. otherwise the run claims the accepted job the fair-share policy picks
       (:meth:`SqlStore.claim_next`), which may be another job than the named one;
    3. with nothing accepted the message is dropped, saying what became of the named job.

    Every accepted job has at least one message outstanding (one is sent whenever a job
    becomes accepted; a message claims at most one job and is only dropped when none is
    accepted), so a job whose message was used for another job is run by a later message.
    ``contended``: accepted jobs remain but every claim lost a race; keep the message.
    ``small_only`` (a small-lane worker's message): only small-lane jobs are claimed and no
    orphan is taken over (the general queue's messages do that).
    """
    # The common case in one transaction: no orphan, so claim what the policy picks.
    with store.engine.begin() as conn:
        heads, running = store.heads_and_running(conn)
        orphans = [] if small_only else _orphans(running, job_id, worker, lease_s, holder_dead)
        first = (
            None
            if orphans
            else store.claim_next_in(
                conn, worker, max_running_per_user, heads=heads, small_only=small_only, heartbeat=utcnow()
            )
        )
    if isinstance(first, JobRecord):
        return Claim("claimed", first)
    for orphan in orphans:
        claim = claim_run(store, orphan, worker, lease_s, max_attempts, holder_dead)
        if claim.runnable:
            return claim
    job = (
        store.claim_next(worker, max_running_per_user, small_only=small_only, heartbeat=utcnow())
        if orphans or first is LOST_RACE
        else None
    )
    if job is not None:
        return Claim("claimed", job)
    named = store.get_job(job_id)
    if (not small_only or first is LOST_RACE) and accepted_job_ids(store, limit=1):
        return Claim("contended", named)
    if named is None:
        return Claim("missing", None)
    if named.status in FINISHED:
        return Claim("finished", named)
    return Claim("held", named, named.worker)


def lost_message(attempts: int, max_attempts: int) -> str:
    """The failure message of a job whose worker was lost on its last allowed run."""
    return (
        f"the worker running this job was lost {attempts} time(s) (killed, crashed in the "
        f"solver, or its machine stopped); limit {max_attempts} runs, not retried again"
    )


def renew(store: SqlStore, job_id: str, worker: str) -> bool:
    """Renew the lease of a run; False when the run no longer holds the job (stop it)."""
    with store.engine.begin() as conn:
        res = conn.execute(
            update(JobRow)
            .where(
                JobRow.id == job_id,
                JobRow.worker == worker,
                JobRow.status == JobStatus.running.value,
            )
            .values(heartbeat=utcnow())
        )
        return res.rowcount == 1


@dataclass(frozen=True)
class Expired:
    """A job found under an expired lease by :func:`expire_leases`, and what was done."""

    job_id: str
    holder: str | None
    action: Literal["requeued", "failed", "time_limit", "dismissed"]


def expire_leases(
    store: SqlStore, lease_s: float, max_attempts: int, job_time_limit_s: float
) -> list[Expired]:
    """Running jobs whose lease expired: re-queue them (the caller then sends a message), or
    fail them when past their time limit or run ``max_attempts`` times, or dismiss them when
    their cancellation was requested. Safe to run from several processes at once."""
    now = utcnow()
    cutoff = now - timedelta(seconds=lease_s)
    lease = func.coalesce(JobRow.heartbeat, JobRow.started, JobRow.updated)
    done: list[Expired] = []
    with store.engine.connect() as conn:
        rows = conn.execute(
            select(JobRow).where(JobRow.status == JobStatus.running.value, lease < cutoff)
        ).all()
    for row in rows:
        job = store._record(row)
        same_run = (
            JobRow.id == job.id,
            JobRow.status == JobStatus.running.value,
            JobRow.worker == job.worker,
            _heartbeat_is(row.heartbeat),
        )
        ran_s = (now - job.started).total_seconds() if job.started else 0.0
        if job.cancel_requested:
            target, action = JobStatus.dismissed, "dismissed"
            values = {"message": "cancelled by the user (its worker had stopped)"}
        elif ran_s > job_time_limit_s:
            target, action = JobStatus.failed, "time_limit"
            values = {
                "message": (
                    f"time limit of {job_time_limit_s:g} s exceeded and the solve did not stop; "
                    "its worker process was killed"
                ),
                "error": json.dumps({"code": FailureCode.time_limit}),
            }
        elif job.attempts >= max_attempts:
            target, action = JobStatus.failed, "failed"
            values = {
                "message": lost_message(job.attempts, max_attempts),
                "error": json.dumps({"code": FailureCode.worker_died}),
            }
        else:
            target, action = JobStatus.accepted, "requeued"
            values = {
                "message": (
                    f"re-queued: the worker of run {job.attempts} ({job.worker}) stopped "
                    "renewing its lease"
                ),
                "worker": None,
                "started": None,
                "heartbeat": None,
            }
        _status_change(target, [JobStatus.running])
        if target != JobStatus.accepted:
            values["finished"] = now
        with store.engine.begin() as conn:
            changed = conn.execute(
                update(JobRow).where(*same_run).values(status=target.value, updated=now, **values)
            ).rowcount
        if changed:
            done.append(Expired(job.id, job.worker, action))  # type: ignore[arg-type]
    return done


def accepted_job_ids(store: SqlStore, limit: int = 100_000) -> list[str]:
    """Ids of accepted jobs, oldest first (re-sent to the broker when an API server starts)."""
    with store.engine.connect() as conn:
        return list(
            conn.execute(
                select(JobRow.id)
                .where(JobRow.status == JobStatus.accepted.value)
                .order_by(JobRow.created, JobRow.id)
                .limit(limit)
            ).scalars()
        )


def heartbeat_of(store: SqlStore, job_id: str) -> datetime | None:
    """The last lease renewal of a job (for tests and diagnostics)."""
    with store.engine.connect() as conn:
        value = conn.execute(
            select(JobRow.heartbeat).where(JobRow.id == job_id)
        ).scalar_one_or_none()
    if value is not None and value.tzinfo is None:
        value = value.replace(tzinfo=timezone.utc)
    return value
