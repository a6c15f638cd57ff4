"""Fixtures of the service tests: example jobs, a simulated large job, a shared real server."""

from __future__ import annotations

import json
import os
import subprocess
from typing import Any, Iterator

import pytest
from pba_service_harness import PBA, Server, load_example


@pytest.fixture(scope="session")
def triplet_doc() -> dict[str, Any]:
    """examples/prism-triplet.json (the simulator's PRISM triplet)."""
    return load_example("prism-triplet.json")


@pytest.fixture(scope="session")
def small_doc(triplet_doc: dict[str, Any]) -> dict[str, Any]:
    """A small fast job: the triplet without the covariance computation."""
    doc = json.loads(json.dumps(triplet_doc))
    doc.setdefault("options", {})["covariance"] = False
    doc["name"] = "small"
    return doc


@pytest.fixture(scope="session")
def big_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A job that solves for several seconds: 12 PRISM triplets, 24000 tie points, 72k image
    observations, 10 MB of JSON (pba simulate; about 10 s on this machine, 4 s of set-up and
    0.5 s per solver iteration). Tests that stop it fail loudly if it ever finishes first."""
    out = tmp_path_factory.mktemp("big") / "strip.json"
    subprocess.run(
        [
            str(PBA),
            "simulate",
            "strip",
            "--triplets",
            "12",
            "--tie-points",
            "24000",
            "-o",
            str(out),
        ],
        check=True,
        capture_output=True,
    )
    doc = json.loads(out.read_text())
    doc["name"] = "big"
    return doc


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """One real server for most end-to-end tests: keys required, 2 workers, 16 MB body limit."""
    with Server(
        tmp_path_factory.mktemp("server"),
        workers=2,
        require_api_keys="true",
        max_body_bytes=16_000_000,
        max_queued_jobs=400,
    ) as srv:
        yield srv


@pytest.fixture(scope="session")
def keys(server: Server) -> dict[str, str]:
    """API keys of alice, bob (users) and root (admin, created through ``pba admin create-key``)."""
    env = {**os.environ, "PBA_DATA_DIR": str(server.data_dir)}
    out = subprocess.run(
        [str(PBA), "admin", "create-key", "--user", "root", "--admin"],
        env=env,
        check=True,
        capture_output=True,
        text=True,
    )
    root_key = out.stdout.strip()
    assert root_key.startswith("pba_"), out
    return {"alice": server.create_key("alice"), "bob": server.create_key("bob"), "root": root_key}


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """On a failure, attach the tail of the shared server's log to the report."""
    outcome = yield
    report = outcome.get_result()  # type: ignore[attr-defined]
    srv = getattr(item, "funcargs", {}).get("server")
    if report.failed and isinstance(srv, Server):
        report.sections.append(("server log", srv.log_tail(40)))
