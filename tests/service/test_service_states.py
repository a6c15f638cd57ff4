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
