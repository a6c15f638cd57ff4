"""Job use cases behind the routes: prepare (resolve, validate), submit, view, cancel.

Everything here is plain Python called from route handlers (in FastAPI's thread pool); it
raises :mod:`service.errors` exceptions, mapped to HTTP in one place.
"""

from __future__ import annotations

from typing import Any

from service.cameras import resolve_camera_refs
from service.errors import JobFailed, JobTooLarge, NoSuchJob, ResultNotReady, TooManyJobs
from service.lanes import is_small, share_of
from service.processes import JOB_POINTER, Caller, process
from service.queue import QueueBackend
from service.queue_view import Placement, placement
from service.retention import quota_bytes, quota_error
from service.schemas import ExecuteInputs, Link, StatusInfo
from service.settings import Settings
from service.states import JobStatus
from service.store import JobRecord, QuotaExceeded, Store, UserRecord
from solver.schema.job import Job


def validate_inputs(
    process_id: str, inputs: ExecuteInputs, store: Store, user: UserRecord, settings: Settings
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Resolve camera refs (in ``user``'s camera namespaces) and run the process's check
    (:mod:`service.processes`: the solver's dry run for an adjustment).

    Returns (the document to store ``{"job": ..., "models": ...}``, the validation summary);
    raises InvalidInput with pointers into the request on any problem.
    """
    proc = process(process_id)
    job = resolve_camera_refs(inputs.job, store, user.id, JOB_POINTER)
    checked = proc.check(job, inputs, Caller(user.name, settings))
    return checked.document, checked.summary


class JobService:
    """Submission, listing and cancellation of jobs for one user at a time."""

    def __init__(self, settings: Settings, store: Store, backend: QueueBackend) -> None:
        self.settings = settings
        self.store = store
        self.backend = backend

    def limits_of(self, user: UserRecord) -> tuple[int, int]:
        """(max queued jobs, max observations per job) of a user."""
        return (
            user.max_queued_jobs or self.settings.max_queued_jobs,
            user.max_job_observations or self.settings.max_job_observations,
        )

    def submit(self, user: UserRecord, process_id: str, inputs: ExecuteInputs) -> JobRecord:
        """Validate, check the user's limits, store as accepted, and queue. The job's lane
        comes from what it will cost (service.lanes: adjustments of at most
        ``small_job_observations`` observations take the small-job lane, matchings never), and
        so does its share (what it counts for in the user's fair share while it runs)."""
        max_queued, max_obs = self.limits_of(user)
        n_obs = process(process_id).count(inputs.job)
        if n_obs > max_obs:
            raise JobTooLarge(f"the job has {n_obs} observations; your limit is {max_obs}")
        document, _ = validate_inputs(process_id, inputs, self.store, user, self.settings)
        if self.store.count_queued(user.id) >= max_queued:
            raise TooManyJobs(
                f"you already have {max_queued} jobs queued or running; wait for some to finish",
                headers={"Retry-After": "10"},
            )
        job: Job = inputs.job
        cost = process(process_id).cost_of(job, document)
        small = is_small(cost, self.settings.small_job_observations)
        share = share_of(cost, self.settings.small_job_observations)
        quota_mb = self.settings.user_storage_quota_mb
        try:
            rec = self.store.create_job(
                user.id, process_id, document, n_obs, job.name, small, quota_bytes(quota_mb), share
            )
        except QuotaExceeded as exc:
            raise quota_error(exc, quota_mb) from None
        self.backend.submit(rec.id)
        return rec

    def placement_of(self, rec: JobRecord) -> Placement | None:
        """Position and estimated start of an accepted job (service.queue_view), else None."""
        if rec.status != JobStatus.accepted:
            return None
        return placement(
            self.store, rec.id, self.backend.worker_count(), self.settings.max_running_per_user
        )

    def get_visible(self, job_id: str, user: UserRecord) -> JobRecord:
        """The job if ``user`` may see it (owner or admin), else NoSuchJob (404, not 403)."""
        rec = self.store.get_job(job_id) if len(job_id) <= 64 else None
        if rec is None or (rec.owner != user.id and not user.is_admin):
            raise NoSuchJob(job_id)
        return rec

    def cancel(self, job_id: str, user: UserRecord) -> JobRecord:
        """Dismiss (accepted or finished) or request cancellation (running)."""
        self.get_visible(job_id, user)
        rec = self.store.request_cancel(job_id, "user")
        if rec is None:
            raise NoSuchJob(job_id)
        if rec.status == JobStatus.running:
            self.backend.cancel(job_id)
        return rec


def results_text(rec: JobRecord) -> str:
    """The stored report of a successful job; the OGC errors otherwise."""
    if rec.status == JobStatus.successful:
        text = rec.results_text
        if text is not None:
            return text
        raise ResultNotReady("the job's results are missing")
    if rec.status == JobStatus.failed:
        raise JobFailed(rec.message, rec.error)
    if rec.status == JobStatus.dismissed:
        raise ResultNotReady("the job was dismissed; it has no results")
    raise ResultNotReady(f"the job is {rec.status.value}; results are not ready yet")


def status_info(
    rec: JobRecord, base_url: str, placement: Placement | None = None
) -> StatusInfo:
    """The OGC status document of a job (with an accepted job's ``placement`` when given)."""
    href = f"{base_url}jobs/{rec.id}"
    links = [
        Link(href=href, rel="self", type="application/json", title="job status"),
        Link(
            href=f"{href}/events", rel="monitor", type="text/event-stream", title="progress events"
        ),
    ]
    if rec.status == JobStatus.successful:
        links.append(
            Link(
                href=f"{href}/results",
                rel="http://www.opengis.net/def/rel/ogc/1.0/results",
                type="application/json",
                title="results",
            )
        )
        for table in process(rec.process_id).tables:
            links.append(
                Link(
                    href=f"{href}/results/{table}.csv",
                    rel="alternate",
                    type="text/csv",
                    title=f"{table} table",
                )
            )
    problems = None
    if rec.status == JobStatus.failed and rec.error:
        problems = rec.error.get("errors") or None
    return StatusInfo(
        jobID=rec.id,
        processID=rec.process_id,
        status=rec.status,
        message=rec.message,
        created=rec.created,
        started=rec.started,
        finished=rec.finished,
        updated=rec.updated,
        progress=rec.progress,
        problems=problems,
        queuePosition=placement.position if placement else None,
        estimatedStart=placement.estimated_start if placement else None,
        links=links,
    )
