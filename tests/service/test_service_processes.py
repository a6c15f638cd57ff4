"""The process table (service.processes): a process is one entry, and the routes, the job use
cases and the worker reach it only through the table (count, check, run), never by its id.

A fake process added to the table by one entry is listed, described, validated, counted
against the user's limits, stored with the counts it reported and run by the worker code
(``service.execution.run_claimed_job``, in this process) to a stored report; and no module
of the service outside service/processes.py names a process id.
"""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

import service.processes
from service.app import create_app
from service.auth import create_key
from service.errors import InvalidInput
from service.execution import RunLimits, run_claimed_job
from service.processes import PROCESSES, Checked, Process
from service.settings import Settings
from service.states import JobStatus

SERVICE = Path(service.processes.__file__).parent
FAKE = "echo-count"
FAKE_COUNT = 7  # observations the fake process says a job has (its own rule, not len(observations))


def _fake_check(job: Any, inputs: Any, caller: Any) -> Checked:
    if job.name == "refuse me":
        raise InvalidInput("the fake process refuses this job", [{"pointer": "/inputs/job/name", "code": "fake", "message": "refused"}])
    return Checked({"job": job.model_dump(mode="json")}, {"valid": True, "problems": [], "images": []})


def _fake_run(document: dict[str, Any], progress: Any, cancel: Any) -> dict[str, Any]:
    return {"kind": FAKE, "images": len(document["job"]["images"]), "nan": float("nan")}


@pytest.fixture()
def fake_process(monkeypatch: pytest.MonkeyPatch) -> Process:
    entry = Process(
        FAKE,
        "Echo",
        "Counts the images of a job (a test's process).",
        "Echo report",
        count=lambda job: FAKE_COUNT,
        check=_fake_check,
        run=_fake_run,
    )
    monkeypatch.setitem(PROCESSES, FAKE, entry)
    return entry


def test_a_process_added_by_one_table_entry_is_served_and_run(
    tmp_path: Path, triplet_doc: dict[str, Any], fake_process: Process
) -> None:
    app = create_app(Settings(data_dir=tmp_path, workers=0, require_api_keys=True, max_job_observations=1000))
    with TestClient(app) as c:
        store = app.state.services.store
        alice = {"X-API-Key": create_key(store, "alice")[0]}
        listed = c.get("/processes", headers=alice).json()["processes"]
        assert FAKE in {p["id"] for p in listed}
        described = c.get(f"/processes/{FAKE}", headers=alice).json()
        assert described["outputs"]["report"]["title"] == "Echo report"

        refused = c.post(
            f"/processes/{FAKE}/execution",
            json={"inputs": {"job": {**triplet_doc, "name": "refuse me"}}},
            headers={**alice, "Prefer": "respond-async"},
        )
        assert refused.status_code == 422 and refused.json()["errors"][0]["pointer"] == "/inputs/job/name"

        r = c.post(
            f"/processes/{FAKE}/execution",
            json={"inputs": {"job": triplet_doc}},
            headers={**alice, "Prefer": "respond-async"},
        )
        assert r.status_code == 201, r.text
        job_id = r.json()["jobID"]
        rec = store.get_job(job_id)
        assert rec.process_id == FAKE and rec.n_observations == FAKE_COUNT

        claimed = store.claim(job_id, "test-worker")
        assert claimed is not None
        assert run_claimed_job(store, claimed, "test-worker", RunLimits(job_time_limit_s=60)) == JobStatus.successful
        report = c.get(f"/jobs/{job_id}/results", headers=alice).json()["report"]
        assert report == {"kind": FAKE, "images": len(triplet_doc["images"]), "nan": None}


def test_the_table_counts_against_the_users_limit(
    tmp_path: Path, triplet_doc: dict[str, Any], fake_process: Process
) -> None:
    """The limit is applied to the process's count (7), not to the job's observation list."""
    app = create_app(Settings(data_dir=tmp_path, workers=0, require_api_keys=True, max_job_observations=FAKE_COUNT - 1))
    with TestClient(app) as c:
        alice = {"X-API-Key": create_key(app.state.services.store, "alice")[0]}
        triplet = {**triplet_doc, "observations": triplet_doc["observations"][:3]}
        r = c.post(
            f"/processes/{FAKE}/execution",
            json={"inputs": {"job": triplet}},
            headers={**alice, "Prefer": "respond-async"},
        )
        assert r.status_code == 413, r.text
        assert f"{FAKE_COUNT} observations" in r.json()["detail"]


def _branches_on_process(path: Path) -> list[int]:
    """Lines of ``path`` that compare something named like a process id (``process_id``,
    ``rec.process_id``, ``processId``) with a string or a constant's name, or that list
    process ids in a ``Literal``."""
    ids = set(PROCESSES)
    lines = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Compare):
            names = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}
            names |= {n.attr for n in ast.walk(node) if isinstance(n, ast.Attribute)}
            named_id = {n for n in names if n.isupper()} or {
                n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and isinstance(n.value, str)
            }
            if named_id and any("process" in name.lower() for name in names):
                lines.append(node.lineno)
        elif isinstance(node, ast.Subscript) and getattr(node.value, "id", "") == "Literal":
            if ids & {n.value for n in ast.walk(node.slice) if isinstance(n, ast.Constant)}:
                lines.append(node.lineno)
    return lines


def test_no_service_module_but_the_table_branches_on_a_process_id() -> None:
    offenders = {
        str(path.relative_to(SERVICE)): _branches_on_process(path)
        for path in SERVICE.rglob("*.py")
        if path.name != "processes.py" and "migrations" not in path.parts
    }
    assert not {k: v for k, v in offenders.items() if v}, offenders


def test_an_adjustment_is_validated_once_from_request_to_report(
    tmp_path: Path, small_doc: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The submission's validation is stored with the document and handed to the worker's
    run: one full check of the job between the request and the report."""
    import solver.engine.validate as validate

    calls: list[int] = []
    real = validate.collect_problems
    monkeypatch.setattr(validate, "collect_problems", lambda job: calls.append(1) or real(job))
    app = create_app(Settings(data_dir=tmp_path, workers=0, require_api_keys=True))
    with TestClient(app) as c:
        store = app.state.services.store
        alice = {"X-API-Key": create_key(store, "alice")[0]}
        r = c.post("/processes/bundle-adjustment/execution", json={"inputs": {"job": small_doc}}, headers={**alice, "Prefer": "respond-async"})
        assert r.status_code == 201, r.text
        job_id = r.json()["jobID"]
        assert store.get_document(job_id)["validation"]["fingerprint"] == validate.fingerprint()
        claimed = store.claim(job_id, "test-worker")
        assert run_claimed_job(store, claimed, "test-worker", RunLimits(job_time_limit_s=600)) == JobStatus.successful
        assert len(calls) == 1
        assert c.get(f"/jobs/{job_id}/results", headers=alice).json()["report"]["adjustment"]["converged"]


class _Document(dict):
    """A job document a test can watch (a plain dict cannot be weakly referenced)."""


@pytest.mark.parametrize("process_id", ["bundle-adjustment", "model-comparison"])
def test_the_worker_hands_the_job_over_and_keeps_no_reference(
    process_id: str, small_doc: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The worker's run hands the job document to the solver (``solver.api.Handover``) and holds
    it nowhere else: once the solver has taken it, nothing keeps it (a million observations'
    parsed document is about 550 MB, held for the whole solve otherwise)."""
    import weakref

    import solver.api

    job = _Document(small_doc)
    watched = weakref.ref(job)
    document = {"job": job, "models": ["K1", "K2"], "validation": None}
    del job
    freed: list[bool] = []

    def taking(handed: Any, *args: Any, **kwargs: Any) -> dict[str, Any]:
        assert isinstance(handed, solver.api.Handover)
        taken = handed.take()
        assert watched() is taken
        del taken
        freed.append(watched() is None)  # the solver held the last reference: freed once parsed
        return {}

    monkeypatch.setattr(solver.api, "run", taking)
    monkeypatch.setattr(solver.api, "compare", taking)
    PROCESSES[process_id].run(document, lambda *a: None, lambda: False)
    assert freed == [True]
