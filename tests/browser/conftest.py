"""Fixtures of the browser tests: a real ``pba serve`` (the service tests' harness), Debian's
Chromium driven by Playwright (no browser download), screenshots under test-artifacts/browser/.

Chromium missing is a failure with the command that installs it, never a skip.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "service"))

from pba_service_harness import PBA, ROOT, Server  # noqa: E402

CHROMIUM = Path(os.environ.get("PBA_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
ARTIFACTS = ROOT / "test-artifacts" / "browser"
VIEWPORT = {"width": 1400, "height": 900}


@pytest.fixture(scope="session")
def chromium_context() -> Iterator[Any]:
    """Headless Debian Chromium with a fresh user-data directory (one per test session)."""
    if not CHROMIUM.is_file():
        pytest.fail(
            f"Chromium is not installed at {CHROMIUM}: the browser tests need Debian's chromium "
            "(`make system-deps`, i.e. `apt-get install chromium`; or set PBA_CHROMIUM to a "
            "Chromium binary). Playwright's own browser download is not used.",
            pytrace=False,
        )
    try:
        from playwright.sync_api import sync_playwright
    except ImportError as exc:  # pragma: no cover - dev extras missing
        pytest.fail(f"playwright is not installed ({exc}): pip install -e '.[dev]'", pytrace=False)
    profile = tempfile.mkdtemp(prefix="pba-chromium-")
    with sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            profile,
            executable_path=str(CHROMIUM),
            headless=True,
            args=CHROMIUM_ARGS,
            viewport=VIEWPORT,
            accept_downloads=True,
        )
        context.set_default_timeout(30_000)
        try:
            yield context
        finally:
            context.close()


@pytest.fixture
def page(chromium_context: Any, request: pytest.FixtureRequest) -> Iterator[Any]:
    """A new tab (its own sessionStorage); page errors fail the test; on failure a screenshot
    goes to test-artifacts/browser/FAILED-<test>.png."""
    pg = chromium_context.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda exc: errors.append(str(exc)))
    try:
        yield pg
        assert not errors, f"JavaScript errors on the page: {errors}"
    finally:
        rep = getattr(request.node, "rep_call", None)
        if rep is not None and rep.failed:
            ARTIFACTS.mkdir(parents=True, exist_ok=True)
            try:
                pg.screenshot(
                    path=str(ARTIFACTS / f"FAILED-{request.node.name}.png"), full_page=True
                )
            except Exception:  # noqa: BLE001 - best effort
                pass
        pg.close()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """Keep each phase's report on the item (for the failure screenshot); on a failure attach
    the tail of the server's log."""
    outcome = yield
    report = outcome.get_result()  # type: ignore[attr-defined]
    setattr(item, f"rep_{report.when}", report)
    for name in ("keyed_server", "local_server"):
        srv = getattr(item, "funcargs", {}).get(name)
        if report.failed and isinstance(srv, Server):
            report.sections.append((f"{name} log", srv.log_tail(40)))


@pytest.fixture(scope="session")
def keyed_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A real server with keys required and 2 worker processes."""
    with Server(tmp_path_factory.mktemp("ui-server"), workers=2, require_api_keys="true") as srv:
        yield srv


@pytest.fixture(scope="session")
def api_key(keyed_server: Server) -> str:
    return keyed_server.create_key("carol")


@pytest.fixture(scope="session")
def local_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A real server in local single-user mode (127.0.0.1, no keys), 1 worker process."""
    with Server(tmp_path_factory.mktemp("ui-local"), workers=1, require_api_keys="false") as srv:
        yield srv


@pytest.fixture(scope="session")
def big_job_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A job that solves for several seconds (8 simulated PRISM triplets, 12000 tie points)."""
    out = tmp_path_factory.mktemp("big") / "strip.json"
    subprocess.run(
        [str(PBA), "simulate", "strip", "--triplets", "8", "--tie-points", "12000", "-o", str(out)],
        check=True,
        capture_output=True,
    )
    doc = json.loads(out.read_text())
    doc["name"] = "big strip (cancel me)"
    out.write_text(json.dumps(doc))
    return out


@pytest.fixture(scope="session")
def artifacts() -> Path:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    return ARTIFACTS
