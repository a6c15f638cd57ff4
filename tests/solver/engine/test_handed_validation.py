"""A job validated once: the counts of a validation made elsewhere (a server's submission)
are handed to the solve as a value (:class:`solver.engine.validate.ValidatedJob`), which then
does not check that job again; a record made by other code, or a changed copy of the job, is
checked as before."""

from __future__ import annotations

from typing import Any

import pytest
from utils.scenes import single_image_job

import solver.api
import solver.engine.validate as validate
from solver.errors import JobError
from solver.schema.job import load_job


@pytest.fixture
def checks(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts the full checks (collect_problems) that run."""
    calls: list[int] = []
    real = validate.collect_problems

    def counted(job: Any) -> Any:
        calls.append(id(job))
        return real(job)

    monkeypatch.setattr(validate, "collect_problems", counted)
    return calls


def test_a_handed_validation_is_not_repeated(checks: list[int]) -> None:
    job = load_job(single_image_job("K2", seed=3)[0])
    summary = solver.api.validate(job)
    record = solver.api.validation_record(summary)
    assert len(checks) == 1
    report = solver.api.run(job, validated=record)
    assert checks == [id(job)]  # the solve took the handed counts
    assert report["adjustment"]["n_observations"] == summary["n_observations"]
    solver.api.run(job)  # nothing handed: checked again
    assert len(checks) == 2


def test_a_record_of_other_code_or_another_job_is_not_taken(checks: list[int]) -> None:
    job = load_job(single_image_job("K2", seed=3)[0])
    record = solver.api.validation_record(solver.api.validate(job))
    n = len(checks)
    other = validate.handed(job, {**record, "fingerprint": "other code"})
    assert other is job  # not taken: the job as it is
    validate.validated(other)
    assert len(checks) == n + 1  # checked
    taken = validate.handed(job, record)
    assert isinstance(taken, validate.ValidatedJob) and taken.job is job
    n = len(checks)
    assert validate.validated(taken).counts == record["counts"] and len(checks) == n  # not checked again
    copy = job.model_copy(update={"observations": job.observations[:2]})
    with pytest.raises(JobError):  # the copy lost its observations: checked, refused
        validate.validated(copy)
    assert len(checks) == n + 1


def test_a_comparison_takes_the_handed_validation_for_every_model(checks: list[int]) -> None:
    job = load_job(single_image_job("K2", seed=3)[0])
    record = solver.api.validation_record(solver.api.validate(job))
    n = len(checks)
    report = solver.api.compare(job, ["K1", "K2"], validated=record)
    assert len(checks) == n and set(report["reports"]) == {"K1", "K2"}
    solver.api.compare(job, ["K1", "K2"])  # nothing handed: the job is checked for each model
    assert len(checks) == n + 2
