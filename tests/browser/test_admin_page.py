"""The admin page (/ui/admin) in headless Chromium against a real server: an admin sees the
workers, the queue and accounting by user, running jobs and recent failures; another user
is told it is for admins only."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import httpx
import pytest
from pba_service_harness import Server, load_example, submit_async, wait_status
from playwright.sync_api import expect

pytestmark = pytest.mark.browser


def use_key(page: Any, server: Server, key: str) -> None:
    """Keep ``key`` in this tab (the main page's key form), then open the admin page."""
    page.goto(f"{server.url}/ui")
    page.fill("#api-key", key)
    page.click("#key-form button[type=submit]")
    page.goto(f"{server.url}/ui/admin")


def record_failure(server: Server, user: str) -> tuple[str, str]:
    """A failed job of ``user`` with its usage, written into the store as a worker records it
    (an invalid job is refused at submission, so it never reaches a worker): its id and stored
    message. Failed straight from accepted in one compare-and-set: the server's own workers poll
    the store, and one claimed the job between its creation and a separate claim here (in CI, 2
    runs of 2). A worker may even claim and fail the (empty) job before the compare-and-set: the
    job is then failed with the worker's message, which the page must show instead."""
    store = server.store()
    try:
        owner = next(u.id for u in store.list_users() if u.name == user)
        rec = store.create_job(owner, "bundle-adjustment", {"job": {}}, 1, "broken")
        if store.fail(rec.id, "no-such-image", {"code": "no_solution"}, None, (0.5, 1.0)):
            return rec.id, "no-such-image"
        stored = store.get_job(rec.id)
    finally:
        store.close()
    assert stored is not None and stored.status.value == "failed" and stored.message, stored
    return rec.id, stored.message.splitlines()[0][:40]


def test_admin_page_shows_queue_workers_failures_and_accounting(
    page: Any, keyed_server: Server, big_job_file: Path, artifacts: Path
) -> None:
    root = keyed_server.create_key("root", admin=True)
    dave = keyed_server.create_key("dave")
    with httpx.Client(base_url=keyed_server.url, headers={"X-API-Key": dave}, timeout=120) as c:
        done = submit_async(c, load_example("prism-triplet.json"))
        wait_status(c, done, {"successful"}, timeout=240)
        failed, message = record_failure(keyed_server, "dave")
        long = submit_async(c, json.loads(big_job_file.read_text()))
        wait_status(c, long, {"running"}, timeout=240)
        try:
            check_page(page, keyed_server, root, dave, failed, message, long, artifacts)
        finally:
            c.delete(f"/jobs/{long}")


def check_page(
    page: Any, server: Server, root: str, dave: str, failed: str, message: str, long: str, artifacts: Path
) -> None:
    use_key(page, server, dave)
    expect(page.locator("#admin-status")).to_contain_text("admins only")

    use_key(page, server, root)
    expect(page.locator("#admin-status")).to_contain_text("updated")
    expect(page.locator("#workers-alive")).to_have_text("2")
    row = page.locator("#users-table tbody tr", has_text="dave")
    expect(row).to_have_count(1)
    cells = row.locator("td")
    expect(cells.nth(5)).to_have_text("1")  # successful
    expect(cells.nth(6)).to_have_text("1")  # failed
    expect(page.locator("#failures-table tbody")).to_contain_text(failed)
    expect(page.locator("#failures-table tbody")).to_contain_text(message)
    running = page.locator("#running-table tbody tr", has_text=long)
    expect(running).to_have_count(1)
    expect(running.locator("td").nth(1)).to_have_text("dave")
    expect(running.locator("td").nth(2)).to_contain_text(":")  # the worker, host:pid
    page.screenshot(path=str(artifacts / "admin-page.png"), full_page=True)
