"""SQLAlchemy 2.0 implementation of :class:`service.store.base.Store` (SQLite and PostgreSQL).

Status changes are single conditional ``UPDATE`` statements (compare-and-set), atomic on both
databases without explicit locks; claiming the next job adds ``FOR UPDATE SKIP LOCKED`` on
PostgreSQL so that concurrent workers do not queue up on one row. SQLite runs in WAL mode
with a busy timeout so the server and its worker processes can share the file.
"""

from __future__ import annotations

import enum
import json
import os
import uuid
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any, Iterable

from sqlalchemy import (
    case,
    create_engine,
    delete,
    event,
    func,
    insert,
    literal,
    null,
    select,
    text,
    union_all,
    update,
)
from sqlalchemy.engine import Connection, Engine, make_url
from sqlalchemy.exc import IntegrityError
from sqlalchemy.pool import NullPool

from service.states import FailureCode, JobStatus, check_transition
from service.store.base import (
    SHARED,
    CameraRecord,
    FinishedRun,
    JobRecord,
    PrunedJob,
    QuotaExceeded,
    UsageRecord,
    UserRecord,
)
from service.store.fair import Head, OwnerLoad, Waiting, pick
from service.store.payloads import pack, unpack
from service.store.rows import ApiKeyRow, CameraRow, JobPayloadRow, JobRow, UsageRow, UserRow
from service.store.schema import ensure_schema


def utcnow() -> datetime:
    """The current time, timezone-aware UTC."""
    return datetime.now(timezone.utc)


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cur = dbapi_connection.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA busy_timeout=30000")
    cur.execute("PRAGMA synchronous=NORMAL")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.close()


PRIVATE_FILE_MODE = 0o600
PRIVATE_DIR_MODE = 0o700


def create_private_sqlite_file(url: str) -> None:
    """Create the SQLite file of ``url`` readable by its owner only (0600; its directory 0700
    when created here). SQLite gives the -wal and -shm files the database file's mode. An
    existing file keeps its mode; in-memory databases are left alone."""
    database = make_url(url).database
    if not database or database == ":memory:" or database.startswith("file:"):
        return
    path = os.path.abspath(database)
    os.makedirs(os.path.dirname(path), mode=PRIVATE_DIR_MODE, exist_ok=True)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, PRIVATE_FILE_MODE)
    except FileExistsError:
        return
    os.fchmod(fd, PRIVATE_FILE_MODE)  # the umask may have removed bits, never added: be exact
    os.close(fd)


def make_engine(url: str) -> Engine:
    """An engine for ``url`` with the settings this store relies on."""
    if url.startswith("sqlite"):
        create_private_sqlite_file(url)
        engine = create_engine(
            url, connect_args={"check_same_thread": False, "timeout": 30}, poolclass=NullPool
        )
        event.listen(engine, "connect", _sqlite_pragmas)
        return engine
    return create_engine(url, pool_pre_ping=True, pool_size=5, max_overflow=10)


@dataclass(frozen=True)
class RunningJob:
    """A running job as a claim sees it: id, holder (run token) and lease time (UTC: the
    last heartbeat, else the start, else the last update)."""

    id: str
    worker: str | None
    lease: datetime


def _as_utc(t: datetime) -> datetime:
    """SQLite returns aggregates and COALESCE of timestamps without their zone: UTC."""
    if isinstance(t, str):  # SQLite: an expression over timestamps comes back as text
        t = datetime.fromisoformat(t)
    return t if t.tzinfo else t.replace(tzinfo=timezone.utc)


class LostRace(enum.Enum):
    """The type of :data:`LOST_RACE`."""

    LOST_RACE = "lost_race"


LOST_RACE = LostRace.LOST_RACE  # a claim attempt found every candidate taken: try again


def _heads_and_running_statement() -> Any:
    """Built once: composing a SELECT costs more client CPU than running this one."""
    heads = (
        select(
            literal("a").label("kind"),
            JobRow.owner.label("owner"),
            JobRow.small.label("small"),
            func.min(JobRow.created).label("t"),
            null().label("id"),
            null().label("worker"),
        )
        .where(JobRow.status == JobStatus.accepted.value)
        .group_by(JobRow.owner, JobRow.small)
    )
    running = select(
        literal("r"),
        null(),
        null(),
        func.coalesce(JobRow.heartbeat, JobRow.started, JobRow.updated),
        JobRow.id,
        JobRow.worker,
    ).where(JobRow.status == JobStatus.running.value)
    return union_all(heads, running)


_HEADS_AND_RUNNING = _heads_and_running_statement()


def _status_change(target: JobStatus, allowed_from: Iterable[JobStatus]) -> list[str]:
    """The source states of a compare-and-set, each checked against the state machine."""
    sources = list(allowed_from)
    for s in sources:
        check_transition(s, target)
    return [s.value for s in sources]


class SqlStore:
    """The job store on SQLAlchemy Core (see module docstring)."""

    def __init__(self, url: str, create: bool = True) -> None:
        self.url = url
        self.engine = make_engine(url)
        if create:
            self.create_schema()

    # -- lifecycle -------------------------------------------------------------------------
    def create_schema(self) -> None:
        """Create or migrate the tables to the newest revision (idempotent; service.store.schema)."""
        ensure_schema(self.engine)

    def ping(self) -> None:
        """Raise if the database does not answer."""
        with self.engine.connect() as conn:
            conn.execute(text("SELECT 1"))

    def close(self) -> None:
        """Release connections."""
        self.engine.dispose()

    # -- helpers ---------------------------------------------------------------------------
    def _record(self, row: Any) -> JobRecord:
        return JobRecord(
            id=row.id,
            owner=row.owner,
            process_id=row.process_id,
            name=row.name,
            status=JobStatus(row.status),
            progress=row.progress,
            message=row.message,
            created=row.created,
            updated=row.updated,
            started=row.started,
            finished=row.finished,
            attempts=row.attempts,
            worker=row.worker,
            cancel_requested=row.cancel_requested,
            n_observations=row.n_observations,
            error=json.loads(row.error) if row.error else None,
            small=bool(row.small),
            share=float(row.share if row.share is not None else 1.0),
            cpu_s=row.cpu_s,
            solve_s=row.solve_s,
            _load_results=self.get_results_text,
            _load_document=self.get_document,
        )

    def _fetch(self, conn: Connection, job_id: str) -> JobRecord | None:
        row = conn.execute(select(JobRow).where(JobRow.id == job_id)).first()
        return self._record(row) if row else None

    def _cas(
        self,
        conn: Connection,
        job_id: str,
        target: JobStatus,
        allowed_from: Iterable[JobStatus],
        worker: str | None = None,
        **values: Any,
    ) -> bool:
        """Compare-and-set the status of one job; True when this call changed it."""
        sources = _status_change(target, allowed_from)
        stmt = update(JobRow).where(JobRow.id == job_id, JobRow.status.in_(sources))
        if worker is not None:
            stmt = stmt.where(JobRow.worker == worker)
        now = utcnow()
        values.setdefault("updated", now)
        if target in (JobStatus.successful, JobStatus.failed, JobStatus.dismissed):
            values.setdefault("finished", now)
        res = conn.execute(stmt.values(status=target.value, **values))
        return res.rowcount == 1

    # -- jobs: API side --------------------------------------------------------------------
    def create_job(
        self,
        owner: str,
        process_id: str,
        document: dict[str, Any],
        n_observations: int,
        name: str,
        small: bool = False,
        quota_bytes: int = 0,
        share: float = 1.0,
    ) -> JobRecord:
        """Insert an ``accepted`` job with its execute inputs (``small``: the small-job lane;
        ``quota_bytes``: see :meth:`_reserve`; ``share``: what it counts for in its user's
        share while it runs, service.store.fair)."""
        now = utcnow()
        job_id = str(uuid.uuid4())
        packed = pack(json.dumps(document))
        with self.engine.begin() as conn:
            self._reserve(conn, owner, len(packed), quota_bytes)
            conn.execute(
                insert(JobRow).values(
                    id=job_id,
                    owner=owner,
                    process_id=process_id,
                    name=name[:200],
                    status=JobStatus.accepted.value,
                    progress=0,
                    message="queued",
                    created=now,
                    updated=now,
                    attempts=0,
                    n_observations=n_observations,
                    stored_bytes=len(packed),
                    small=small,
                    share=share,
                )
            )
            conn.execute(insert(JobPayloadRow).values(job_id=job_id, document_z=packed))
            rec = self._fetch(conn, job_id)
        assert rec is not None
        return rec

    def get_job(self, job_id: str) -> JobRecord | None:
        """One job or None."""
        with self.engine.connect() as conn:
            return self._fetch(conn, job_id)

    def list_jobs(
        self,
        owner: str | None,
        statuses: Iterable[JobStatus] | None = None,
        process_id: str | None = None,
        limit: int = 10,
        offset: int = 0,
    ) -> tuple[list[JobRecord], int]:
        """Jobs newest first (of ``owner``, or all when None), and the total matching."""
        conds = []
        if owner is not None:
            conds.append(JobRow.owner == owner)
        if statuses:
            conds.append(JobRow.status.in_([JobStatus(s).value for s in statuses]))
        if process_id is not None:
            conds.append(JobRow.process_id == process_id)
        with self.engine.connect() as conn:
            total = conn.execute(
                select(func.count()).select_from(JobRow).where(*conds)
            ).scalar_one()
            rows = conn.execute(
                select(JobRow)
                .where(*conds)
                .order_by(JobRow.created.desc(), JobRow.id.desc())
                .limit(limit)
                .offset(offset)
            ).all()
        return [self._record(r) for r in rows], int(total)

    def count_queued(self, owner: str) -> int:
        """Accepted + running jobs of a user."""
        with self.engine.connect() as conn:
            return int(
                conn.execute(
                    select(func.count())
                    .select_from(JobRow)
                    .where(
                        JobRow.owner == owner,
                        JobRow.status.in_([JobStatus.accepted.value, JobStatus.running.value]),
                    )
                ).scalar_one()
            )

    @staticmethod
    def _drop_payloads(conn: Connection, job_id: str) -> None:
        """Forget a dismissed job's inputs and report (and their bytes in the quota)."""
        conn.execute(
            update(JobPayloadRow)
            .where(JobPayloadRow.job_id == job_id)
            .values(document=None, results=None, document_z=None, results_z=None)
        )
        conn.execute(update(JobRow).where(JobRow.id == job_id).values(stored_bytes=0))

    def request_cancel(self, job_id: str, reason: str = "user") -> JobRecord | None:
        """Dismiss an accepted or finished job (dropping its payloads) or flag a running one."""
        with self.engine.begin() as conn:
            rec = self._fetch(conn, job_id)
            if rec is None:
                return None
            if self._cas(
                conn,
                job_id,
                JobStatus.dismissed,
                [JobStatus.accepted],
                message="dismissed before it started",
            ):
                self._drop_payloads(conn, job_id)
            elif self._cas(
                conn,
                job_id,
                JobStatus.dismissed,
                [JobStatus.successful, JobStatus.failed],
                message="dismissed; results deleted",
                finished=rec.finished,
            ):
                self._drop_payloads(conn, job_id)
            else:
                conn.execute(
                    update(JobRow)
                    .where(
                        JobRow.id == job_id,
                        JobRow.status == JobStatus.running.value,
                        JobRow.cancel_requested.is_(None),
                    )
                    .values(
                        cancel_requested=reason, message="cancellation requested", updated=utcnow()
                    )
                )
            return self._fetch(conn, job_id)

    # -- jobs: worker side -----------------------------------------------------------------
    def _claim_values(self, worker: str) -> dict[str, Any]:
        now = utcnow()
        return dict(
            status=JobStatus.running.value,
            worker=worker,
            started=now,
            updated=now,
            attempts=JobRow.attempts + 1,
            message="running",
            cancel_requested=None,
        )

    def _loads(self, conn: Connection, owners: list[str], default_cap: int) -> dict[str, OwnerLoad]:
        """The fair-share inputs of ``owners`` (service.store.fair), read in ``conn``: running
        counts, their shares and last starts in one grouped query, weights and caps in another."""
        is_running = case((JobRow.status == JobStatus.running.value, 1), else_=0)
        running_share = case((JobRow.status == JobStatus.running.value, JobRow.share), else_=0.0)
        per_owner = {
            o: (int(n or 0), float(share or 0.0), started)
            for o, n, share, started in conn.execute(
                select(JobRow.owner, func.sum(is_running), func.sum(running_share), func.max(JobRow.started))
                .where(JobRow.owner.in_(owners))
                .group_by(JobRow.owner)
            ).all()
        }
        users = {
            r.id: r
            for r in conn.execute(
                select(UserRow.id, UserRow.weight, UserRow.max_running_jobs).where(
                    UserRow.id.in_(owners)
                )
            ).all()
        }
        loads = {}
        for o in owners:
            u = users.get(o)
            running, share, started = per_owner.get(o, (0, 0.0, None))
            if started is not None and started.tzinfo is None:
                started = started.replace(tzinfo=timezone.utc)
            loads[o] = OwnerLoad(
                running=running,
                running_share=share,
                weight=(u.weight if u is not None and u.weight else 1.0),
                max_running=(
                    u.max_running_jobs
                    if u is not None and u.max_running_jobs is not None
                    else default_cap
                ),
                last_started=started,
            )
        return loads

    def _heads(self, conn: Connection) -> list[Head]:
        return self.heads_and_running(conn)[0]

    def heads_and_running(self, conn: Connection) -> tuple[list[Head], list[RunningJob]]:
        """The waiting heads (oldest accepted job per owner and lane) and every running job's
        id, holder and lease time, in one round trip (a claim reads both for every message)."""
        found_heads: list[Head] = []
        found_running: list[RunningJob] = []
        for kind, owner, small, t, job_id, worker in conn.execute(_HEADS_AND_RUNNING):
            t = _as_utc(t)
            if kind == "a":
                found_heads.append(Head(owner, bool(small), t))
            else:
                found_running.append(RunningJob(job_id, worker, t))
        return found_heads, found_running

    def claim_next(
        self, worker: str, max_running_per_user: int = 0, small_only: bool = False, **extra: Any
    ) -> JobRecord | None:
        """Move the accepted job the fair-share policy picks (service.store.fair) to running
        for ``worker`` (atomic), or None when no job is accepted. ``max_running_per_user``:
        the cap of users without one of their own (0: none); ``small_only``: only jobs of the
        small-job lane (a worker reserved for it), in the same order; ``extra``: more columns
        to set (a distributed run's ``heartbeat``)."""
        for _ in range(20):
            with self.engine.begin() as conn:
                got = self.claim_next_in(conn, worker, max_running_per_user, small_only=small_only, **extra)
            if got is not LOST_RACE:
                return got
        return None

    def claim_next_in(
        self,
        conn: Connection,
        worker: str,
        max_running_per_user: int = 0,
        heads: list[Head] | None = None,
        small_only: bool = False,
        **extra: Any,
    ) -> JobRecord | None | LostRace:
        """One attempt of :meth:`claim_next` in the caller's transaction ``conn``: the claimed
        job, None when no job is accepted, or :data:`LOST_RACE` when every job of the picked
        head was being claimed by another transaction (try again in a new one). ``heads``: the
        waiting heads when the caller has just read them in ``conn``."""
        _status_change(JobStatus.running, [JobStatus.accepted])
        if heads is None:
            heads = self._heads(conn)
        if small_only:
            heads = [h for h in heads if h.small]
        if not heads:
            return None
        owners = sorted({h.owner for h in heads})
        # One user waiting: the loads cannot change the order (fair.pick), so skip them.
        loads = self._loads(conn, owners, max_running_per_user) if len(owners) > 1 else {}
        head = pick(heads, loads)
        assert head is not None
        candidate = (
            select(JobRow.id)
            .where(
                JobRow.status == JobStatus.accepted.value,
                JobRow.owner == head.owner,
                JobRow.small == head.small,
            )
            .order_by(JobRow.created, JobRow.id)
            .limit(1)
        )
        if conn.dialect.name == "postgresql":
            candidate = candidate.with_for_update(skip_locked=True)
        row = conn.execute(
            update(JobRow)
            .where(
                JobRow.id == candidate.scalar_subquery(),
                JobRow.status == JobStatus.accepted.value,
            )
            .values(**self._claim_values(worker), **extra)
            .returning(*JobRow.__table__.c)
        ).first()
        return self._record(row) if row is not None else LOST_RACE

    def claim(self, job_id: str, worker: str) -> JobRecord | None:
        """Move this accepted job to running for ``worker``; None if it is not accepted."""
        _status_change(JobStatus.running, [JobStatus.accepted])
        with self.engine.begin() as conn:
            res = conn.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.status == JobStatus.accepted.value)
                .values(**self._claim_values(worker))
            )
            return self._fetch(conn, job_id) if res.rowcount == 1 else None

    def cancel_requested(self, job_id: str) -> str | None:
        """The cancel reason of a job (``"user"``, ``"time_limit"``) or None."""
        with self.engine.connect() as conn:
            return conn.execute(
                select(JobRow.cancel_requested).where(JobRow.id == job_id)
            ).scalar_one_or_none()

    def set_progress(self, job_id: str, worker: str, progress: int, message: str) -> bool:
        """Raise the progress of a job this worker runs; never lowers it."""
        progress = max(0, min(100, int(progress)))
        with self.engine.begin() as conn:
            res = conn.execute(
                update(JobRow)
                .where(
                    JobRow.id == job_id,
                    JobRow.worker == worker,
                    JobRow.status == JobStatus.running.value,
                )
                .values(
                    progress=case((JobRow.progress < progress, progress), else_=JobRow.progress),
                    message=message[:2000],
                    updated=utcnow(),
                )
            )
            return res.rowcount == 1

    def _finish_run(
        self,
        conn: Connection,
        job_id: str,
        target: JobStatus,
        allowed_from: Iterable[JobStatus],
        worker: str | None,
        usage: tuple[float, float] | None,
        **values: Any,
    ) -> bool:
        """Compare-and-set a job to a finished status; with ``usage`` (CPU s, solve s of the
        run) also record it on the job and add it to its owner's totals (``user_usage``), in
        the same transaction. One UPDATE ... RETURNING does the status, the job's usage
        columns and yields the owner: a worker's finishing write is two or three statements."""
        sources = _status_change(target, allowed_from)
        stmt = update(JobRow).where(JobRow.id == job_id, JobRow.status.in_(sources))
        if worker is not None:
            stmt = stmt.where(JobRow.worker == worker)
        now = utcnow()
        values.setdefault("updated", now)
        values.setdefault("finished", now)
        if usage is not None:
            values.update(cpu_s=usage[0], solve_s=usage[1])
        owner = conn.execute(
            stmt.values(status=target.value, **values).returning(JobRow.owner)
        ).scalar_one_or_none()
        if owner is None:
            return False
        if usage is not None:
            self._add_usage(conn, owner, target, *usage)
        return True

    @staticmethod
    def _add_usage(
        conn: Connection, owner: str, status: JobStatus, cpu_s: float, solve_s: float
    ) -> None:
        """Add one finished run to ``owner``'s totals (``user_usage``), creating the row."""
        column = {
            JobStatus.successful: UsageRow.jobs_successful,
            JobStatus.failed: UsageRow.jobs_failed,
            JobStatus.dismissed: UsageRow.jobs_dismissed,
        }[status]
        add = {
            column.key: column + 1,
            "cpu_s": UsageRow.cpu_s + cpu_s,
            "solve_s": UsageRow.solve_s + solve_s,
        }
        for _ in range(3):
            stmt = update(UsageRow).where(UsageRow.user_id == owner).values(**add)
            if conn.execute(stmt).rowcount:
                return
            try:
                with conn.begin_nested():
                    conn.execute(
                        insert(UsageRow).values(
                            user_id=owner,
                            jobs_successful=0,
                            jobs_failed=0,
                            jobs_dismissed=0,
                            cpu_s=0.0,
                            solve_s=0.0,
                        )
                    )
            except IntegrityError:
                pass  # another transaction created it: update again

    def usage(self) -> list[UsageRecord]:
        """Per-user accounting, users by name (every user, zero when they ran nothing)."""
        with self.engine.connect() as conn:
            rows = conn.execute(
                select(UserRow.id, UserRow.name, UsageRow)
                .join(UsageRow, UsageRow.user_id == UserRow.id, isouter=True)
                .order_by(UserRow.name)
            ).all()
        return [
            UsageRecord(
                user_id=r.id,
                name=r.name,
                jobs_successful=r.jobs_successful or 0,
                jobs_failed=r.jobs_failed or 0,
                jobs_dismissed=r.jobs_dismissed or 0,
                cpu_s=r.cpu_s or 0.0,
                solve_s=r.solve_s or 0.0,
            )
            for r in rows
        ]

    def complete(
        self,
        job_id: str,
        worker: str,
        results_text: str,
        message: str,
        usage: tuple[float, float] | None = None,
    ) -> bool:
        """running -> successful, storing the report; only for the worker that runs it.
        ``usage``: (CPU seconds, solve seconds) of the run, for the accounting."""
        packed = pack(results_text)  # before the transaction: seconds for a big report
        with self.engine.begin() as conn:
            ok = self._finish_run(
                conn,
                job_id,
                JobStatus.successful,
                [JobStatus.running],
                worker,
                usage if usage is not None else (0.0, 0.0),
                progress=100,
                message=message,
                stored_bytes=JobRow.stored_bytes + len(packed),
            )
            if ok:
                conn.execute(
                    update(JobPayloadRow)
                    .where(JobPayloadRow.job_id == job_id)
                    .values(results_z=packed)
                )
            return ok

    def fail(
        self,
        job_id: str,
        message: str,
        error: dict[str, Any] | None = None,
        worker: str | None = None,
        usage: tuple[float, float] | None = None,
    ) -> bool:
        """accepted/running -> failed (only this worker's run when ``worker`` is given);
        ``usage`` as in :meth:`complete` (a run the worker measured)."""
        sources = [JobStatus.running] if worker else [JobStatus.accepted, JobStatus.running]
        with self.engine.begin() as conn:
            return self._finish_run(
                conn,
                job_id,
                JobStatus.failed,
                sources,
                worker,
                usage,
                message=message[:4000],
                error=json.dumps(error) if error else None,
            )

    def finish_cancelled(
        self, job_id: str, worker: str, message: str, usage: tuple[float, float] | None = None
    ) -> bool:
        """running -> dismissed after a cancel request, for the worker that ran it."""
        with self.engine.begin() as conn:
            return self._finish_run(
                conn, job_id, JobStatus.dismissed, [JobStatus.running], worker, usage, message=message
            )

    def requeue(self, job_id: str, worker: str, message: str, count_attempt: bool = True) -> bool:
        """running -> accepted for this worker's run (``count_attempt=False`` forgives the run)."""
        extra: dict[str, Any] = {} if count_attempt else {"attempts": JobRow.attempts - 1}
        with self.engine.begin() as conn:
            return self._requeue(conn, job_id, worker, message, extra)

    def _requeue(
        self, conn: Connection, job_id: str, worker: str | None, message: str, extra: dict[str, Any]
    ) -> bool:
        sources = _status_change(JobStatus.accepted, [JobStatus.running])
        stmt = update(JobRow).where(JobRow.id == job_id, JobRow.status.in_(sources))
        if worker is not None:
            stmt = stmt.where(JobRow.worker == worker)
        res = conn.execute(
            stmt.values(
                status=JobStatus.accepted.value,
                worker=None,
                started=None,
                cancel_requested=None,
                message=message,
                updated=utcnow(),
                **extra,
            )
        )
        return res.rowcount == 1

    def recover_interrupted(self, max_attempts: int) -> tuple[list[str], list[str]]:
        """Running jobs (their workers are gone) back to accepted, or failed after
        ``max_attempts`` runs. Returns (re-queued ids, failed ids)."""
        requeued: list[str] = []
        failed: list[str] = []
        with self.engine.begin() as conn:
            rows = conn.execute(
                select(JobRow.id, JobRow.attempts, JobRow.worker).where(
                    JobRow.status == JobStatus.running.value
                )
            ).all()
            for job_id, attempts, worker in rows:
                if attempts < max_attempts:
                    if self._requeue(
                        conn,
                        job_id,
                        worker,
                        f"re-queued after the server restarted during run {attempts}",
                        {},
                    ):
                        requeued.append(job_id)
                elif self._cas(
                    conn,
                    job_id,
                    JobStatus.failed,
                    [JobStatus.running],
                    worker=worker,
                    message=(
                        f"interrupted by a server restart {attempts} times "
                        f"(limit {max_attempts}); not retried again"
                    ),
                    error=json.dumps({"code": FailureCode.interrupted}),
                ):
                    failed.append(job_id)
        return requeued, failed

    def fail_jobs_of_worker(self, worker: str, message: str) -> list[str]:
        """Fail every job a (dead) worker was running."""
        with self.engine.begin() as conn:
            ids = (
                conn.execute(
                    select(JobRow.id).where(
                        JobRow.worker == worker, JobRow.status == JobStatus.running.value
                    )
                )
                .scalars()
                .all()
            )
            done = []
            for job_id in ids:
                if self._cas(
                    conn,
                    job_id,
                    JobStatus.failed,
                    [JobStatus.running],
                    worker=worker,
                    message=message,
                    error=json.dumps({"code": FailureCode.worker_died}),
                ):
                    done.append(job_id)
            return done

    def running_jobs(self) -> list[JobRecord]:
        """All running jobs."""
        with self.engine.connect() as conn:
            rows = conn.execute(
                select(JobRow).where(JobRow.status == JobStatus.running.value)
            ).all()
        return [self._record(r) for r in rows]

    # -- jobs: reading ---------------------------------------------------------------------
    def get_results_text(self, job_id: str) -> str | None:
        """The stored report as JSON text (compressed rows and pre-0003 plain rows alike)."""
        with self.engine.connect() as conn:
            row = conn.execute(
                select(JobPayloadRow.results_z, JobPayloadRow.results).where(
                    JobPayloadRow.job_id == job_id
                )
            ).first()
        return unpack(row.results_z, row.results) if row else None

    def get_document(self, job_id: str) -> dict[str, Any] | None:
        """The stored execute inputs (compressed rows and pre-0003 plain rows alike)."""
        with self.engine.connect() as conn:
            row = conn.execute(
                select(JobPayloadRow.document_z, JobPayloadRow.document).where(
                    JobPayloadRow.job_id == job_id
                )
            ).first()
        doc = unpack(row.document_z, row.document) if row else None
        return json.loads(doc) if doc else None

    # -- retention -------------------------------------------------------------------------
    def storage_used(self, owner: str) -> int:
        """Bytes of stored payloads of a user's jobs and of the camera versions they created."""
        with self.engine.connect() as conn:
            return self._storage_used(conn, owner)

    @staticmethod
    def _storage_used(conn: Connection, owner: str) -> int:
        jobs = conn.execute(
            select(func.coalesce(func.sum(JobRow.stored_bytes), 0)).where(JobRow.owner == owner)
        ).scalar_one()
        cameras = conn.execute(
            select(func.coalesce(func.sum(func.length(CameraRow.definition)), 0)).where(
                CameraRow.created_by == owner
            )
        ).scalar_one()
        return int(jobs) + int(cameras)

    def _reserve(self, conn: Connection, owner: str, need: int, quota_bytes: int) -> None:
        """In the caller's writing transaction: with ``quota_bytes`` > 0, serialise the writers
        of ``owner`` (PostgreSQL: a transaction-scoped advisory lock on the owner; SQLite: the
        database's write lock, taken by a first write) and raise QuotaExceeded when ``need``
        more bytes would take the owner's storage over the quota. Check and insert are then one
        transaction: concurrent submissions cannot both pass."""
        if quota_bytes <= 0:
            return
        if conn.dialect.name == "postgresql":
            conn.execute(text("SELECT pg_advisory_xact_lock(hashtext(:k))"), {"k": f"pba-quota:{owner}"})
        else:
            conn.execute(update(UserRow).where(UserRow.id == owner).values(name=UserRow.name))
        used = self._storage_used(conn, owner)
        if used + need > quota_bytes:
            raise QuotaExceeded(used, need)

    def prune_jobs(self, finished_before: datetime, dry_run: bool = False) -> list[PrunedJob]:
        """Delete finished jobs (successful, failed, dismissed) that finished before
        ``finished_before``, with their payloads; accepted and running jobs are never touched.
        Returns what was (or, with ``dry_run``, would be) deleted, oldest first."""
        finished = [JobStatus.successful.value, JobStatus.failed.value, JobStatus.dismissed.value]
        conds = (
            JobRow.status.in_(finished),
            JobRow.finished.is_not(None),
            JobRow.finished < finished_before,
        )
        with self.engine.begin() as conn:
            rows = conn.execute(
                select(JobRow.id, JobRow.owner, JobRow.status, JobRow.finished, JobRow.stored_bytes)
                .where(*conds)
                .order_by(JobRow.finished, JobRow.id)
            ).all()
            pruned = [
                PrunedJob(r.id, r.owner, JobStatus(r.status), r.finished, r.stored_bytes)
                for r in rows
            ]
            if dry_run or not pruned:
                return pruned
            for start in range(0, len(pruned), 500):
                ids = [p.id for p in pruned[start : start + 500]]
                conn.execute(delete(JobPayloadRow).where(JobPayloadRow.job_id.in_(ids)))
                conn.execute(delete(JobRow).where(JobRow.id.in_(ids), *conds))
        return pruned

    def compact(self) -> None:
        """Give the space of deleted rows back to the file system (SQLite ``VACUUM``; on
        PostgreSQL autovacuum reuses it, so nothing is done)."""
        if self.engine.dialect.name != "sqlite":
            return
        with self.engine.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
            conn.exec_driver_sql("VACUUM")

    def counts_by_status(self) -> dict[JobStatus, int]:
        """Jobs per status, every status present (zero when none)."""
        with self.engine.connect() as conn:
            rows = conn.execute(select(JobRow.status, func.count()).group_by(JobRow.status)).all()
        counts = {s: 0 for s in JobStatus}
        for status, n in rows:
            counts[JobStatus(status)] = int(n)
        return counts

    def queue_snapshot(
        self, max_running_per_user: int = 0
    ) -> tuple[list[Waiting], dict[str, OwnerLoad], list[JobRecord]]:
        """What the fair-share policy sees now: the accepted jobs, their users' loads, and the
        running jobs (for positions and start estimates; service.queue_view)."""
        with self.engine.connect() as conn:
            rows = conn.execute(
                select(JobRow.id, JobRow.owner, JobRow.small, JobRow.created, JobRow.share).where(
                    JobRow.status == JobStatus.accepted.value
                )
            ).all()
            waiting = [
                Waiting(
                    r.id,
                    r.owner,
                    bool(r.small),
                    r.created if r.created.tzinfo else r.created.replace(tzinfo=timezone.utc),
                    float(r.share if r.share is not None else 1.0),
                )
                for r in rows
            ]
            owners = sorted({w.owner for w in waiting})
            loads = self._loads(conn, owners, max_running_per_user) if owners else {}
            running = conn.execute(
                select(JobRow).where(JobRow.status == JobStatus.running.value)
            ).all()
        return waiting, loads, [self._record(r) for r in running]

    def recent_runs(self, limit: int) -> list[FinishedRun]:
        """The ``limit`` solves that finished last (with a start time), newest first."""
        with self.engine.connect() as conn:
            rows = conn.execute(
                select(JobRow.id, JobRow.status, JobRow.started, JobRow.finished)
                .where(JobRow.finished.is_not(None), JobRow.started.is_not(None))
                .order_by(JobRow.finished.desc())
                .limit(limit)
            ).all()
        return [FinishedRun(r.id, JobStatus(r.status), r.started, r.finished) for r in rows]

    def active_by_owner(self) -> dict[str, tuple[int, int]]:
        """(accepted, running) jobs per owner that has any."""
        active = [JobStatus.accepted.value, JobStatus.running.value]
        with self.engine.connect() as conn:
            rows = conn.execute(
                select(JobRow.owner, JobRow.status, func.count())
                .where(JobRow.status.in_(active))
                .group_by(JobRow.owner, JobRow.status)
            ).all()
        out: dict[str, tuple[int, int]] = {}
        for owner, status, n in rows:
            waiting, running = out.get(owner, (0, 0))
            if status == JobStatus.accepted.value:
                waiting += int(n)
            else:
                running += int(n)
            out[owner] = (waiting, running)
        return out

    def finished_since(self, after: datetime) -> list[FinishedRun]:
        """Solves that finished after ``after`` (with a start time), oldest first."""
        with self.engine.connect() as conn:
            rows = conn.execute(
                select(JobRow.id, JobRow.status, JobRow.started, JobRow.finished)
                .where(JobRow.finished > after, JobRow.started.is_not(None))
                .order_by(JobRow.finished)
            ).all()
        return [FinishedRun(r.id, JobStatus(r.status), r.started, r.finished) for r in rows]

    # -- users and keys --------------------------------------------------------------------
    @staticmethod
    def _user(row: Any) -> UserRecord:
        return UserRecord(
            id=row.id,
            name=row.name,
            is_admin=row.is_admin,
            created=row.created,
            max_queued_jobs=row.max_queued_jobs,
            max_job_observations=row.max_job_observations,
            weight=row.weight,
            max_running_jobs=row.max_running_jobs,
        )

    def create_user(
        self,
        name: str,
        is_admin: bool | None = None,
        max_queued_jobs: int | None = None,
        max_job_observations: int | None = None,
        weight: float | None = None,
        max_running_jobs: int | None = None,
    ) -> UserRecord:
        """Create a user, or update the existing one of that name; arguments left at None keep
        the existing values (a new user: not admin, the server's default limits)."""
        with self.engine.begin() as conn:
            row = conn.execute(select(UserRow).where(UserRow.name == name)).first()
            if row is None:
                try:
                    with conn.begin_nested():
                        conn.execute(
                            insert(UserRow).values(
                                id=str(uuid.uuid4()),
                                name=name,
                                is_admin=bool(is_admin),
                                created=utcnow(),
                                max_queued_jobs=max_queued_jobs,
                                max_job_observations=max_job_observations,
                                weight=weight,
                                max_running_jobs=max_running_jobs,
                            )
                        )
                except IntegrityError:
                    pass
            else:
                given = {
                    k: v
                    for k, v in (
                        ("is_admin", is_admin),
                        ("max_queued_jobs", max_queued_jobs),
                        ("max_job_observations", max_job_observations),
                        ("weight", weight),
                        ("max_running_jobs", max_running_jobs),
                    )
                    if v is not None
                }
                if given:
                    conn.execute(update(UserRow).where(UserRow.name == name).values(**given))
            row = conn.execute(select(UserRow).where(UserRow.name == name)).one()
            return self._user(row)

    def list_users(self) -> list[UserRecord]:
        """Every user, by name."""
        with self.engine.connect() as conn:
            rows = conn.execute(select(UserRow).order_by(UserRow.name)).all()
        return [self._user(r) for r in rows]

    def get_user(self, user_id: str) -> UserRecord | None:
        """A user by id."""
        with self.engine.connect() as conn:
            row = conn.execute(select(UserRow).where(UserRow.id == user_id)).first()
        return self._user(row) if row else None

    def add_api_key(self, user_id: str, key_hash: str, prefix: str) -> None:
        """Store the hash of a new key."""
        with self.engine.begin() as conn:
            conn.execute(
                insert(ApiKeyRow).values(
                    key_hash=key_hash, prefix=prefix, user_id=user_id, created=utcnow()
                )
            )

    def user_for_key_hash(self, key_hash: str) -> UserRecord | None:
        """The user owning a key hash, or None."""
        with self.engine.connect() as conn:
            row = conn.execute(
                select(UserRow)
                .join(ApiKeyRow, ApiKeyRow.user_id == UserRow.id)
                .where(ApiKeyRow.key_hash == key_hash)
            ).first()
        return self._user(row) if row else None

    def revoke_api_key(self, prefix: str) -> bool:
        """Delete the keys whose public prefix is ``prefix``."""
        with self.engine.begin() as conn:
            return conn.execute(delete(ApiKeyRow).where(ApiKeyRow.prefix == prefix)).rowcount > 0

    # -- cameras ---------------------------------------------------------------------------
    @staticmethod
    def _camera(row: Any) -> CameraRecord:
        return CameraRecord(
            name=row.name,
            version=row.version,
            description=row.description,
            definition=json.loads(row.definition),
            created=row.created,
            created_by=row.created_by,
            source_job=row.source_job,
            owner=row.owner,
        )

    def add_camera(
        self,
        name: str,
        description: str,
        definition: dict[str, Any],
        created_by: str,
        source_job: str | None = None,
        owner: str | None = None,
        quota_bytes: int = 0,
    ) -> CameraRecord:
        """Store the next version of ``name`` in the namespace ``owner`` (default: the
        creator's own); retries when two writers race."""
        owner = owner or created_by
        for _ in range(10):
            with self.engine.connect() as conn:
                latest = conn.execute(
                    select(func.max(CameraRow.version)).where(
                        CameraRow.owner == owner, CameraRow.name == name
                    )
                ).scalar_one_or_none()
            rec = self.add_camera_version(
                name, (latest or 0) + 1, description, definition, created_by, owner, source_job, quota_bytes
            )
            if rec is not None:
                return rec  # else another writer took that version: read the latest again
        raise RuntimeError(f"could not store a new version of camera {name!r}")

    def add_camera_version(
        self,
        name: str,
        version: int,
        description: str,
        definition: dict[str, Any],
        created_by: str,
        owner: str,
        source_job: str | None = None,
        quota_bytes: int = 0,
    ) -> CameraRecord | None:
        """Store exactly ``version`` of ``name`` in namespace ``owner``; None when that version
        exists already (the unique key decides between writers racing for it). ``quota_bytes``:
        the creator's quota (:meth:`_reserve`)."""
        text_definition = json.dumps(definition)
        try:
            with self.engine.begin() as conn:
                self._reserve(conn, created_by, len(text_definition), quota_bytes)
                conn.execute(
                    insert(CameraRow).values(
                        owner=owner,
                        name=name,
                        version=version,
                        description=description,
                        definition=text_definition,
                        created=utcnow(),
                        created_by=created_by,
                        source_job=source_job,
                    )
                )
        except IntegrityError:
            return None
        return self.get_camera(name, version, owner=owner)

    def get_camera(
        self, name: str, version: int | None = None, *, owner: str
    ) -> CameraRecord | None:
        """One version of a camera of namespace ``owner`` (the latest when ``version`` is
        None; the first with ``version=0``)."""
        stmt = select(CameraRow).where(CameraRow.owner == owner, CameraRow.name == name)
        if version is None:
            stmt = stmt.order_by(CameraRow.version.desc()).limit(1)
        elif version == 0:
            stmt = stmt.order_by(CameraRow.version).limit(1)
        else:
            stmt = stmt.where(CameraRow.version == version)
        with self.engine.connect() as conn:
            row = conn.execute(stmt).first()
        return self._camera(row) if row else None

    def list_cameras(
        self,
        name: str | None = None,
        limit: int = 100,
        offset: int = 0,
        *,
        owners: Iterable[str],
    ) -> tuple[list[CameraRecord], int]:
        """All versions of ``name`` (newest first), or the latest version of every name, in
        the namespaces ``owners``; ordered by name, then namespace."""
        owners = list(owners)
        with self.engine.connect() as conn:
            if name is not None:
                cond = CameraRow.owner.in_(owners) & (CameraRow.name == name)
            else:
                latest = (
                    select(
                        CameraRow.owner, CameraRow.name, func.max(CameraRow.version).label("v")
                    )
                    .where(CameraRow.owner.in_(owners))
                    .group_by(CameraRow.owner, CameraRow.name)
                    .subquery()
                )
                cond = CameraRow.id.in_(
                    select(CameraRow.id).join(
                        latest,
                        (CameraRow.owner == latest.c.owner)
                        & (CameraRow.name == latest.c.name)
                        & (CameraRow.version == latest.c.v),
                    )
                )
            total = conn.execute(
                select(func.count()).select_from(CameraRow).where(cond)
            ).scalar_one()
            rows = conn.execute(
                select(CameraRow)
                .where(cond)
                .order_by(CameraRow.name, CameraRow.owner == SHARED, CameraRow.version.desc())
                .limit(limit)
                .offset(offset)
            ).all()
        return [self._camera(r) for r in rows], int(total)
