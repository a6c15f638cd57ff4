"""Job use cases behind the routes: prepare (resolve, validate), submit, view, cancel.

Everything here is plain Python called from route handlers (in FastAPI's thread pool); it
raises :mod:`service.errors` exceptions, mapped to HTTP in one place.
"""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from service.cameras import resolve_camera_refs
from service.errors import (
    InvalidInput,
    JobFailed,
    JobTooLarge,
    NoSuchJob,
    NoSuchProcess,
    ResultNotReady,
    TooManyJobs,
)
from service.problems import job_error_entries, problem_entries, pydantic_errors
from service.processes import MODEL_COMPARISON, PREANALYSIS, PROCESSES
from service.queue import QueueBackend
from service.queue_view import Placement, placement
from service.retention import quota_bytes, quota_error
from service.schemas import ExecuteInputs, Link, StatusInfo
from service.settings import Settings
from service.states import JobStatus
from service.store import JobRecord, QuotaExceeded, Store, UserRecord
from solver.errors import JobError
from solver.schema.job import Job

PREFIX = ("inputs", "job")


def check_process(process_id: str) -> None:
    """NoSuchProcess unless ``process_id`` is offered."""
    if process_id not in PROCESSES:
        raise NoSuchProcess(process_id)


def validate_inputs(
    process_id: str, inputs: ExecuteInputs, store: Store, user: UserRecord
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Resolve camera refs (in ``user``'s camera namespaces) and dry-run the solver's checks.

    Returns (the document to store ``{"job": ..., "models": ...}``, the solver's validation
    summary); raises InvalidInput with pointers into the request on any problem.
    """
    import solver.api

    check_process(process_id)
    job = resolve_camera_refs(inputs.job, store, user.id, PREFIX)
    models: list[str] | None = None
    if process_id == MODEL_COMPARISON:
        models = list(inputs.models or job.options.models)
        if not models:
            raise InvalidInput(
                "a model comparison needs the models to compare",
                [
                    {
                        "pointer": "/inputs/models",
                        "code": "missing",
                        "message": "give inputs.models or the job's options.models",
                    }
                ],
            )
        from solver.compare import comparison_problems

        where = ("inputs", "models") if inputs.models else (*PREFIX, "options", "models")
        problems = [p.to_dict() for p in comparison_problems(models, ())]
        if problems:
            raise InvalidInput(
                "; ".join(str(p["message"]) for p in problems[:5]), problem_entries(problems, where)
            )
    elif inputs.models:
        raise InvalidInput(
            "models is an input of model-comparison only",
            [
                {
                    "pointer": "/inputs/models",
                    "code": "unexpected",
                    "message": "not an input of this process",
                }
            ],
        )
    if process_id == PREANALYSIS:
        # planned points carry coordinates and no observations: the adjustment's own checks
        # (observations per point, degrees of freedom) do not apply before the planning
        problems = [p.to_dict() for p in solver.api.preanalysis_problems(job)]
        if problems:
            raise InvalidInput(
                "; ".join(str(p["message"]) for p in problems[:5]), problem_entries(problems, PREFIX)
            )
        summary = {
            "valid": True,
            "problems": [],
            "planned_points": len(job.points),
            "images": [{"id": im.id, "model": im.model.name} for im in job.images],
        }
        return {"job": job.model_dump(mode="json", exclude_unset=False)}, summary
    try:
        summary = solver.api.validate(job)
    except JobError as exc:
        raise InvalidInput(str(exc), job_error_entries(exc, PREFIX)) from None
    except ValidationError as exc:
        raise InvalidInput(
            "the job does not match the schema", pydantic_errors(exc.errors(), PREFIX)
        ) from None
    if not summary.get("valid", False):
        problems = summary.get("problems", [])
        raise InvalidInput(
            "; ".join(str(p.get("message", "")) for p in problems[:5]) or "the job is not valid",
            problem_entries(problems, PREFIX),
        )
    document: dict[str, Any] = {"job": job.model_dump(mode="json", exclude_unset=False)}
    if models is not None:
        document["models"] = models
    return document, summary


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

    def submit(
        self, user: UserRecord, process_id: str, inputs: ExecuteInputs, sync: bool = False
    ) -> JobRecord:
        """Validate, check the user's limits, store as accepted, and queue. Jobs of at most
        ``small_job_observations`` observations and ``sync`` requests (a client waiting for
        the answer) take the small-job lane (service.store.fair)."""
        check_process(process_id)
        max_queued, max_obs = self.limits_of(user)
        n_obs = len(inputs.job.observations)
        if process_id == PREANALYSIS:  # every planned point may be observed in every image
            n_obs = len(inputs.job.points) * len(inputs.job.images)
        if n_obs > max_obs:
            raise JobTooLarge(f"the job has {n_obs} observations; your limit is {max_obs}")
        document, _ = validate_inputs(process_id, inputs, self.store, user)
        if self.store.count_queued(user.id) >= max_queued:
            raise TooManyJobs(
                f"you already have {max_queued} jobs queued or running; wait for some to finish",
                headers={"Retry-After": "10"},
            )
        job: Job = inputs.job
        small = sync or n_obs <= self.settings.small_job_observations
        quota_mb = self.settings.user_storage_quota_mb
        try:
            rec = self.store.create_job(
                user.id, process_id, document, n_obs, job.name, small, quota_bytes(quota_mb)
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
        err = rec.error or {}
        raise JobFailed(rec.message, int(err.get("status", 500)), err.get("errors", []))
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
        for table in ("observations", "checkpoints", "parameters"):
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
