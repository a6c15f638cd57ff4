"""Readiness: ``/readyz`` answers 503 while no worker has loaded the solver and compiled its
kernels (a fresh installation's first start takes minutes), 200 once one has; ``/healthz``
(liveness) answers 200 throughout.

The workers here are real processes of the local pool whose warm-up is held until the test
releases it (a file appears), so "not ready yet" is observed deterministically, not raced.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from service.app import create_app
from service.settings import Settings

RELEASE_ENV = "PBA_TEST_READINESS_RELEASE"


def held_worker(cfg: Any, stop: Any, wake: Any, ready: Any = None) -> None:
    """A worker whose warm-up lasts until the release file exists (then it is ready, and idle
    until stopped)."""
    release = Path(os.environ[RELEASE_ENV])
    while not release.exists() and not stop.is_set():
        time.sleep(0.05)
    if ready is not None and not stop.is_set():
        ready.set()
    stop.wait()


def _wait(c: TestClient, status: int, timeout_s: float = 120.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while True:
        r = c.get("/readyz")
        if r.status_code == status or time.monotonic() > deadline:
            assert r.status_code == status, r.text
            return r.json()
        time.sleep(0.1)


def test_readyz_waits_for_a_warmed_worker(tmp_path: Path, monkeypatch) -> None:
    release = tmp_path / "release"
    monkeypatch.setenv(RELEASE_ENV, str(release))  # inherited by the spawned workers
    monkeypatch.setattr("service.queue.local.worker_main", held_worker)  # the pool's entry point
    app = create_app(Settings(data_dir=tmp_path / "data", workers=2, small_job_workers=1))
    with TestClient(app) as c:
        # both general workers started (alive) but warming up: not ready, and says why
        body = _wait(c, 503)
        deadline = time.monotonic() + 120
        while "2 of 2 workers alive" not in body["checks"]["queue"] and time.monotonic() < deadline:
            time.sleep(0.1)
            body = c.get("/readyz").json()
        assert body["status"] == "unavailable", body
        assert body["checks"]["queue"] == "2 of 2 workers alive, 0 ready (2 starting: loading the solver, compiling its kernels)", body
        assert body["checks"]["store"] == "ok"
        assert c.get("/readyz").status_code == 503
        health = c.get("/healthz")
        assert health.status_code == 200 and health.json()["status"] == "ok"  # alive, only not ready
        release.touch()
        body = _wait(c, 200)
        assert body["status"] == "ok" and body["checks"]["queue"].startswith("2 of 2 workers alive"), body
        deadline = time.monotonic() + 60
        while c.get("/readyz").json()["checks"]["queue"] != "2 of 2 workers alive":  # the other one too
            assert time.monotonic() < deadline, c.get("/readyz").text
            time.sleep(0.1)


def test_readyz_without_workers_is_ready(tmp_path: Path) -> None:
    """An API-only server (PBA_WORKERS=0) has nothing to wait for."""
    app = create_app(Settings(data_dir=tmp_path / "data", workers=0))
    with TestClient(app) as c:
        r = c.get("/readyz")
        assert r.status_code == 200 and "no local workers" in r.json()["checks"]["queue"], r.text
