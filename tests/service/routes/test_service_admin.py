"""Admin endpoint, ``pba admin`` commands and /metrics for fair sharing and accounting
(issue 19)."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Any, Iterator

import pytest
from fastapi.testclient import TestClient
from pba_service_harness import PBA

from service.app import create_app
from service.auth import create_key
from service.settings import Settings
from service.store import Store, open_store


def store_of(tmp_path: Path) -> Store:
    return open_store(Settings(data_dir=tmp_path).resolved_database_url)


def run_job(store: Store, owner: str, usage: tuple[float, float]) -> str:
    """A job run to ``successful`` with the usage a worker measured."""
    rec = store.create_job(owner, "bundle-adjustment", {"inputs": {}}, 1, "t")
    assert store.claim(rec.id, "w") is not None
    assert store.complete(rec.id, "w", "{}", "finished", usage)
    return rec.id


@pytest.fixture
def deployment(tmp_path: Path) -> Iterator[tuple[TestClient, dict[str, str], Store]]:
    settings = Settings(data_dir=tmp_path, workers=0, log_format="text", require_api_keys=True)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        store = store_of(tmp_path)
        keys = {
            "root": create_key(store, "root", is_admin=True)[0],
            "bob": create_key(store, "bob")[0],
        }
        try:
            yield c, keys, store
        finally:
            store.close()


def test_admin_sees_accounting_others_do_not(deployment: Any) -> None:
    c, keys, store = deployment
    bob = next(u for u in store.list_users() if u.name == "bob")
    ids = [run_job(store, bob.id, (0.5, 1.25)), run_job(store, bob.id, (0.25, 0.5))]
    store.create_job(bob.id, "bundle-adjustment", {"inputs": {}}, 1, "waiting")
    assert c.get("/admin/users").status_code == 401
    r = c.get("/admin/users", headers={"X-API-Key": keys["bob"]})
    assert r.status_code == 403 and r.headers["content-type"].startswith("application/problem")
    r = c.get("/admin/users", headers={"X-API-Key": keys["root"]})
    assert r.status_code == 200, r.text
    row = next(u for u in r.json()["users"] if u["user"] == "bob")
    jobs = [store.get_job(i) for i in ids]
    # the table's totals are the sums of the jobs' own figures (binary fractions: exact)
    assert row["solve_seconds"] == sum(j.solve_s for j in jobs if j and j.solve_s) == 1.75
    assert row["cpu_seconds"] == sum(j.cpu_s for j in jobs if j and j.cpu_s) == 0.75
    assert (row["jobs_successful"], row["waiting"], row["running"]) == (2, 1, 0)


def test_admin_sets_weight_and_limits(deployment: Any) -> None:
    c, keys, store = deployment
    root = {"X-API-Key": keys["root"]}
    r = c.patch("/admin/users/bob", json={"weight": 3, "max_running_jobs": 1}, headers=root)
    assert r.status_code == 200, r.text
    assert (r.json()["weight"], r.json()["max_running_jobs"]) == (3.0, 1)
    bob = next(u for u in store.list_users() if u.name == "bob")
    assert (bob.weight, bob.max_running_jobs, bob.max_queued_jobs) == (3.0, 1, None)
    bad = c.patch("/admin/users/bob", json={"weight": -1}, headers=root)
    assert bad.status_code == 422
    assert any(e.get("pointer", "").endswith("/weight") for e in bad.json()["errors"]), bad.text
    assert c.patch("/admin/users/nobody", json={"weight": 2}, headers=root).status_code == 404
    forbidden = c.patch("/admin/users/bob", json={"weight": 9}, headers={"X-API-Key": keys["bob"]})
    assert forbidden.status_code == 403


def test_metrics_have_the_per_user_accounting(deployment: Any) -> None:
    c, keys, store = deployment
    bob = next(u for u in store.list_users() if u.name == "bob")
    run_job(store, bob.id, (2.0, 3.0))
    text = c.get("/metrics", headers={"X-API-Key": keys["root"]}).text
    assert 'pba_user_solve_seconds_total{user="bob"} 3.0' in text, text
    assert 'pba_user_cpu_seconds_total{user="bob"} 2.0' in text
    assert 'pba_user_jobs_total{status="successful",user="bob"} 1.0' in text


def test_pba_admin_set_user_and_usage(tmp_path: Path) -> None:
    env = {**os.environ, "PBA_DATA_DIR": str(tmp_path)}
    store = store_of(tmp_path)
    try:
        user = store.create_user("carol")
        run_job(store, user.id, (1.0, 4.0))
    finally:
        store.close()

    def pba(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [str(PBA), "admin", *args], env=env, capture_output=True, text=True, timeout=120
        )

    ok = pba("set-user", "--user", "carol", "--weight", "2", "--max-running-jobs", "1")
    assert ok.returncode == 0, ok.stderr
    assert pba("set-user", "--user", "nobody", "--weight", "2").returncode == 1
    assert pba("set-user", "--user", "carol", "--weight", "0").returncode == 2
    out = pba("usage", "--json")
    assert out.returncode == 0, out.stderr
    (row,) = [r for r in json.loads(out.stdout) if r["user"] == "carol"]
    assert (row["weight"], row["max_running_jobs"], row["solve_seconds"]) == (2.0, 1, 4.0)
    table = pba("usage")
    assert "carol" in table.stdout and "4.0" in table.stdout


def test_an_accepted_jobs_status_says_where_it_stands(deployment: Any) -> None:
    c, keys, store = deployment
    bob = next(u for u in store.list_users() if u.name == "bob")
    first = store.create_job(bob.id, "bundle-adjustment", {"inputs": {}}, 1, "1").id
    second = store.create_job(bob.id, "bundle-adjustment", {"inputs": {}}, 1, "2").id
    headers = {"X-API-Key": keys["bob"]}
    st = c.get(f"/jobs/{second}", headers=headers).json()
    assert st["status"] == "accepted" and st["queuePosition"] == 2, st
    assert "estimatedStart" not in st  # no worker in this deployment: no estimate
    store.claim(first, "w")
    assert "queuePosition" not in c.get(f"/jobs/{first}", headers=headers).json()
    assert c.get(f"/jobs/{second}", headers=headers).json()["queuePosition"] == 1


def test_overview_lists_running_jobs_and_failures(deployment: Any) -> None:
    c, keys, store = deployment
    bob = next(u for u in store.list_users() if u.name == "bob")
    running = store.create_job(bob.id, "bundle-adjustment", {"inputs": {}}, 1, "r").id
    store.claim(running, "host:42")
    broken = store.create_job(bob.id, "bundle-adjustment", {"inputs": {}}, 1, "f").id
    store.claim(broken, "host:43")
    store.fail(broken, "the solver gave up", {"code": "no_solution"}, worker="host:43")
    assert c.get("/admin/overview", headers={"X-API-Key": keys["bob"]}).status_code == 403
    r = c.get("/admin/overview", headers={"X-API-Key": keys["root"]})
    assert r.status_code == 200, r.text
    o = r.json()
    assert [(j["jobID"], j["user"], j["worker"]) for j in o["running"]] == [
        (running, "bob", "host:42")
    ]
    assert [(j["jobID"], j["message"]) for j in o["failures"]] == [(broken, "the solver gave up")]
    assert o["workers"] == 0 and {u["user"] for u in o["users"]} == {"root", "bob"}
