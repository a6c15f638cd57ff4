"""openapi.yaml at the repository root is the app's generated OpenAPI document (make openapi)."""

from __future__ import annotations

from pathlib import Path

import yaml

from service.openapi_dump import openapi_document, render

ROOT = Path(__file__).resolve().parents[2]


def test_openapi_yaml_is_up_to_date() -> None:
    committed = (ROOT / "openapi.yaml").read_text()
    assert (
        yaml.safe_load(committed) == openapi_document()
    ), "openapi.yaml is out of date: run `make openapi` and commit it"
    assert committed == render()


def test_operation_ids_are_stable_and_unique() -> None:
    doc = openapi_document()
    ids = [op["operationId"] for item in doc["paths"].values() for op in item.values()]
    assert len(ids) == len(set(ids))
    assert "processes-execute" in ids and "jobs-get_status" in ids and "jobs-dismiss_job" in ids
    for path in (
        "/",
        "/conformance",
        "/processes",
        "/processes/{processId}/execution",
        "/jobs",
        "/jobs/{jobId}",
        "/jobs/{jobId}/results",
        "/jobs/{jobId}/events",
        "/jobs/validate",
        "/cameras",
        "/healthz",
        "/readyz",
        "/metrics",
    ):
        assert path in doc["paths"], path
