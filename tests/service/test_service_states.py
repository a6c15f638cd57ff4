"""The written job state machine: allowed transitions, final states, pinned status values."""

from __future__ import annotations

import pytest

from service.states import (
    ALLOWED_TRANSITIONS,
    FINISHED,
    IllegalTransition,
    JobStatus,
    check_transition,
    sources_of,
)


def test_status_values_are_the_ogc_codes() -> None:
    assert [s.value for s in JobStatus] == [
        "accepted",
        "running",
        "successful",
        "failed",
        "dismissed",
    ]


def test_dismissed_is_final_and_finished_jobs_only_get_dismissed() -> None:
    assert ALLOWED_TRANSITIONS[JobStatus.dismissed] == frozenset()
    for s in (JobStatus.successful, JobStatus.failed):
        assert ALLOWED_TRANSITIONS[s] == {JobStatus.dismissed}
    assert FINISHED == {JobStatus.successful, JobStatus.failed, JobStatus.dismissed}


@pytest.mark.parametrize(
    "source,target",
    [
        ("accepted", "running"),
        ("accepted", "dismissed"),
        ("running", "successful"),
        ("running", "failed"),
        ("running", "dismissed"),
        ("running", "accepted"),
        ("successful", "dismissed"),
    ],
)
def test_allowed(source: str, target: str) -> None:
    check_transition(JobStatus(source), JobStatus(target))


@pytest.mark.parametrize(
    "source,target",
    [
        ("accepted", "successful"),
        ("successful", "running"),
        ("failed", "accepted"),
        ("dismissed", "accepted"),
        ("dismissed", "running"),
        ("successful", "failed"),
    ],
)
def test_refused(source: str, target: str) -> None:
    with pytest.raises(IllegalTransition):
        check_transition(JobStatus(source), JobStatus(target))


def test_sources_of_running_is_only_accepted() -> None:
    assert sources_of(JobStatus.running) == {JobStatus.accepted}


# -- failed jobs: the store keeps a code, the error mapping decides the HTTP status ----------
@pytest.mark.parametrize(
    "error, status",
    [
        ({"code": "worker_died"}, 500),
        ({"code": "time_limit"}, 500),
        ({"code": "interrupted"}, 500),
        ({"code": "internal"}, 500),
        (None, 500),  # no code recorded: the server cannot say the job's content was at fault
        ({"code": "rank_deficient", "errors": [{"pointer": "/inputs/job/images"}]}, 422),
        ({"code": "invalid-input"}, 422),
        ({"status": 422, "code": None}, 422),  # stored before codes alone were kept
        ({"status": 500}, 500),
    ],
)
def test_the_status_of_a_failed_job_comes_from_its_code(error: dict | None, status: int) -> None:
    from service.errors import JobFailed, failed_job_status

    assert failed_job_status(error) == status
    assert JobFailed("failed", error).status == status


def test_the_store_and_the_queues_write_no_http_status() -> None:
    """Stored errors carry codes; a literal HTTP status in the store or the queues would be a
    second place that decides it."""
    import re
    from pathlib import Path

    import service

    root = Path(service.__file__).parent
    sources = [*root.glob("store/*.py"), *root.glob("queue/*.py"), root / "execution.py"]
    offenders = [str(p) for p in sources if re.search(r"""["']status["']\s*:\s*\d{3}""", p.read_text())]
    assert offenders == []
