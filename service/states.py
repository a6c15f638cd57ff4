"""The job state machine (OGC API - Processes status codes).

::

    accepted --claim--> running --report--> successful --DELETE--> dismissed
       |                  |  \\--error / crash / time limit--> failed --DELETE--> dismissed
       |                  |--cancel (DELETE)--> dismissed
       |                  \\--server stopped (attempts left)--> accepted
       |--cancel (DELETE)--> dismissed
       \\--interrupted too often / unrunnable--> failed

``dismissed`` is final. Every store operation that changes a status is a compare-and-set on
the states allowed here, so two processes can never both move a job out of one state.
"""

from __future__ import annotations

from enum import StrEnum


class JobStatus(StrEnum):
    """Status codes of OGC API - Processes 1.0 (statusCode.yaml)."""

    accepted = "accepted"
    running = "running"
    successful = "successful"
    failed = "failed"
    dismissed = "dismissed"


ALLOWED_TRANSITIONS: dict[JobStatus, frozenset[JobStatus]] = {
    JobStatus.accepted: frozenset({JobStatus.running, JobStatus.dismissed, JobStatus.failed}),
    JobStatus.running: frozenset(
        {JobStatus.successful, JobStatus.failed, JobStatus.dismissed, JobStatus.accepted}
    ),
    JobStatus.successful: frozenset({JobStatus.dismissed}),
    JobStatus.failed: frozenset({JobStatus.dismissed}),
    JobStatus.dismissed: frozenset(),
}

QUEUED = frozenset({JobStatus.accepted, JobStatus.running})
FINISHED = frozenset({JobStatus.successful, JobStatus.failed, JobStatus.dismissed})


class IllegalTransition(ValueError):
    """A state change the machine does not allow (a programming error, not user input)."""


def sources_of(target: JobStatus) -> frozenset[JobStatus]:
    """All states from which ``target`` may be reached."""
    return frozenset(s for s, targets in ALLOWED_TRANSITIONS.items() if target in targets)


def check_transition(source: JobStatus, target: JobStatus) -> None:
    """Raise :class:`IllegalTransition` unless ``source -> target`` is allowed."""
    if target not in ALLOWED_TRANSITIONS[source]:
        raise IllegalTransition(f"{source.value} -> {target.value} is not allowed")


class FailureCode(StrEnum):
    """Why the server, not the job's content, failed a job (the ``code`` of its stored error).

    A job that fails for its content keeps the solver's problem code instead (e.g.
    ``rank_deficient``) or ``invalid-input`` (schema). The store keeps codes only; the HTTP
    status of a failed job's results is decided in one place, :func:`service.errors.failed_job_status`.
    """

    time_limit = "time_limit"
    worker_died = "worker_died"
    interrupted = "interrupted"
    internal = "internal"
