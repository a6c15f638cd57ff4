"""The store interface: jobs (with their documents and results), users and keys, cameras.

The service talks to a :class:`Store`; the SQLAlchemy implementation (:mod:`service.store.sql`)
serves SQLite (default) and PostgreSQL. Every status change is a compare-and-set on the
states that :mod:`service.states` allows, and every write made by a worker names the worker,
so a job can never be run to completion twice (a stale worker's writes match no row).

Times are timezone-aware UTC datetimes. Progress is an integer percentage that never
decreases (the store keeps the maximum).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Callable, Iterable, Protocol

from service.states import JobStatus

SHARED = "shared"
"""The ``owner`` of cameras in the shared namespace (user ids are UUIDs, so it names no user)."""


@dataclass
class JobRecord:
    """A job as stored (the persisted form; the public view is :class:`service.schemas.StatusInfo`).

    ``results`` (the solver's report dict) and ``document`` (the execute inputs, camera
    references resolved) are loaded from the store on first access.
    """

    id: str
    owner: str
    process_id: str
    name: str
    status: JobStatus
    progress: int
    message: str
    created: datetime
    updated: datetime
    started: datetime | None = None
    finished: datetime | None = None
    attempts: int = 0
    worker: str | None = None
    cancel_requested: str | None = None
    n_observations: int = 0
    error: dict[str, Any] | None = None
    small: bool = False  # the small-job lane (service.store.fair)
    share: float = 1.0  # what it counts for in its user's share while it runs (service.lanes)
    cpu_s: float | None = None  # CPU seconds of the solving process in the finishing run
    solve_s: float | None = None  # wall seconds of that run's solve
    _load_results: Callable[[str], str | None] | None = field(
        default=None, repr=False, compare=False
    )
    _load_document: Callable[[str], dict[str, Any] | None] | None = field(
        default=None, repr=False, compare=False
    )
    _results: Any = field(default=..., repr=False, compare=False)
    _document: Any = field(default=..., repr=False, compare=False)

    @property
    def results_text(self) -> str | None:
        """The report as stored JSON text (None unless successful)."""
        if self._load_results is None or self.status != JobStatus.successful:
            return None
        return self._load_results(self.id)

    @property
    def results(self) -> dict[str, Any] | None:
        """The solver's report dict of a successful job, else None."""
        if self._results is ...:
            text = self.results_text
            self._results = json.loads(text) if text is not None else None
        return self._results

    @property
    def document(self) -> dict[str, Any] | None:
        """The stored execute inputs ``{"job": ..., "models": ...}`` (None once dismissed)."""
        if self._document is ...:
            self._document = self._load_document(self.id) if self._load_document else None
        return self._document


@dataclass(frozen=True)
class UserRecord:
    """A user; limits of None mean the server's defaults."""

    id: str
    name: str
    is_admin: bool
    created: datetime
    max_queued_jobs: int | None = None
    max_job_observations: int | None = None
    weight: float | None = None  # fair-share weight (None: 1)
    max_running_jobs: int | None = None  # running cap while others wait (None: the default)


@dataclass(frozen=True)
class UsageRecord:
    """Per-user accounting of finished runs: counts by outcome, CPU and solve seconds."""

    user_id: str
    name: str
    jobs_successful: int
    jobs_failed: int
    jobs_dismissed: int
    cpu_s: float
    solve_s: float


@dataclass(frozen=True)
class CameraRecord:
    """One version of a named camera definition in the library; ``owner`` is the namespace
    (the owning user's id, or :data:`SHARED`)."""

    name: str
    version: int
    description: str
    definition: dict[str, Any]
    created: datetime
    created_by: str
    source_job: str | None = None
    owner: str = ""

    @property
    def shared(self) -> bool:
        """True for a camera of the shared namespace."""
        return self.owner == SHARED


@dataclass(frozen=True)
class PrunedJob:
    """A finished job deleted (or to be deleted) by retention; ``stored_bytes`` of payloads."""

    id: str
    owner: str
    status: JobStatus
    finished: datetime
    stored_bytes: int


@dataclass(frozen=True)
class FinishedRun:
    """A finished solve, for the metrics' duration histogram."""

    id: str
    status: JobStatus
    started: datetime
    finished: datetime


class QuotaExceeded(Exception):
    """A write refused by the storage quota: ``used`` bytes stored, ``need`` more asked."""

    def __init__(self, used: int, need: int) -> None:
        super().__init__(f"{used} bytes stored, {need} more asked")
        self.used = used
        self.need = need


class Store(Protocol):
    """What the API, the queue backends and the CLI need from persistence."""

    url: str

    # -- lifecycle -------------------------------------------------------------------------
    def create_schema(self) -> None:
        """Create missing tables (idempotent)."""

    def ping(self) -> None:
        """Raise if the database does not answer."""

    def close(self) -> None:
        """Release connections."""

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
        """Insert an ``accepted`` job (``small``: the small-job lane; ``share``: what it counts
        for in its user's share while it runs). With ``quota_bytes`` > 0
        the owner's storage is checked in the inserting transaction, writers of one owner
        serialised (QuotaExceeded when the job would take it over)."""

    def get_job(self, job_id: str) -> JobRecord | None:
        """One job or None."""

    def list_jobs(
        self,
        owner: str | None,
        statuses: Iterable[JobStatus] | None = None,
        process_id: str | None = None,
        limit: int = 10,
        offset: int = 0,
    ) -> tuple[list[JobRecord], int]:
        """Newest first, and the total matching."""

    def count_queued(self, owner: str) -> int:
        """Accepted + running jobs of a user."""

    def request_cancel(self, job_id: str, reason: str = "user") -> JobRecord | None:
        """Dismiss an accepted or finished job, or flag a running one; the record after."""

    # -- jobs: worker side -----------------------------------------------------------------
    def claim_next(
        self, worker: str, max_running_per_user: int = 0, small_only: bool = False, **extra: Any
    ) -> JobRecord | None:
        """The accepted job the fair-share policy picks (service.store.fair) -> running
        (``small_only``: among the small-job lane's jobs only)."""

    def claim(self, job_id: str, worker: str) -> JobRecord | None:
        """This job -> running."""

    def cancel_requested(self, job_id: str) -> str | None:
        """The cancel reason, if any."""

    def set_progress(self, job_id: str, worker: str, progress: int, message: str) -> bool:
        """Raise progress (never lowers it) of a job this worker runs."""

    def complete(
        self,
        job_id: str,
        worker: str,
        results_text: str,
        message: str,
        usage: tuple[float, float] | None = None,
    ) -> bool:
        """running -> successful with the report; ``usage`` (CPU s, solve s) is accounted."""

    def fail(
        self,
        job_id: str,
        message: str,
        error: dict[str, Any] | None = None,
        worker: str | None = None,
        usage: tuple[float, float] | None = None,
    ) -> bool:
        """accepted/running -> failed (only this worker's run when ``worker`` is given)."""

    def finish_cancelled(
        self, job_id: str, worker: str, message: str, usage: tuple[float, float] | None = None
    ) -> bool:
        """running -> dismissed after a cancel request."""

    def requeue(self, job_id: str, worker: str, message: str, count_attempt: bool = True) -> bool:
        """running -> accepted (this worker's run)."""

    def recover_interrupted(self, max_attempts: int) -> tuple[list[str], list[str]]:
        """Start-up: running jobs back to accepted, or failed after ``max_attempts`` runs."""

    def fail_jobs_of_worker(self, worker: str, message: str) -> list[str]:
        """Fail every job a (dead) worker was running."""

    def running_jobs(self) -> list[JobRecord]:
        """All running jobs."""

    # -- jobs: reading ---------------------------------------------------------------------
    def get_results_text(self, job_id: str) -> str | None:
        """Stored report JSON text."""

    def get_document(self, job_id: str) -> dict[str, Any] | None:
        """Stored execute inputs."""

    def counts_by_status(self) -> dict[JobStatus, int]:
        """Jobs per status (all users)."""

    def finished_since(self, after: datetime) -> list[FinishedRun]:
        """For metrics."""

    # -- retention -------------------------------------------------------------------------
    def storage_used(self, owner: str) -> int:
        """Bytes of stored payloads of a user's jobs plus the definitions of the camera versions
        they created (the quota's measure)."""

    def prune_jobs(self, finished_before: datetime, dry_run: bool = False) -> list[PrunedJob]:
        """Delete successful/failed/dismissed jobs finished before the cutoff (never accepted
        or running ones); what was (with ``dry_run``: would be) deleted."""

    def compact(self) -> None:
        """Return the space of deleted rows to the file system where the database needs it."""

    # -- users and keys --------------------------------------------------------------------
    def create_user(
        self,
        name: str,
        is_admin: bool | None = None,
        max_queued_jobs: int | None = None,
        max_job_observations: int | None = None,
        weight: float | None = None,
        max_running_jobs: int | None = None,
    ) -> UserRecord:
        """Create a user, or update the given fields of the existing one of that name."""

    def list_users(self) -> list[UserRecord]:
        """Every user, by name."""

    def usage(self) -> list[UsageRecord]:
        """Per-user accounting of finished runs."""

    def active_by_owner(self) -> dict[str, tuple[int, int]]:
        """(accepted, running) jobs per owner that has any."""

    def recent_runs(self, limit: int) -> list[FinishedRun]:
        """The ``limit`` solves that finished last, newest first."""

    def queue_snapshot(
        self, max_running_per_user: int = 0
    ) -> tuple[list[Any], dict[str, Any], list[JobRecord]]:
        """Accepted jobs (service.store.fair.Waiting), their users' loads, running jobs."""

    def get_user(self, user_id: str) -> UserRecord | None:
        """By id."""

    def add_api_key(self, user_id: str, key_hash: str, prefix: str) -> None:
        """Store a key hash."""

    def user_for_key_hash(self, key_hash: str) -> UserRecord | None:
        """Resolve a key hash."""

    def revoke_api_key(self, prefix: str) -> bool:
        """Delete keys starting with ``prefix``."""

    # -- cameras ---------------------------------------------------------------------------
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
        """Store the next version of ``name`` in namespace ``owner`` (default ``created_by``);
        ``quota_bytes`` as in :meth:`create_job`, for the creator."""

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
        exists already (another writer stored it first: no duplicate, no renumbering)."""

    def get_camera(
        self, name: str, version: int | None = None, *, owner: str
    ) -> CameraRecord | None:
        """A version of a camera of namespace ``owner`` (latest when None, first when 0)."""

    def list_cameras(
        self,
        name: str | None = None,
        limit: int = 100,
        offset: int = 0,
        *,
        owners: Iterable[str],
    ) -> tuple[list[CameraRecord], int]:
        """Latest version of each name, or all versions of one, in the given namespaces."""
