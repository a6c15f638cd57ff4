"""Raster header checks at submission run outside the API's request threads, with a time
limit and a share per user (service.raster_checks): one user's held checks leave /healthz and
every other user's requests answering.

A "held" check is a check process stopped (SIGSTOP) while it holds alice's request, as a
file system that never answers would hold it: deterministic, no hostile file needed. The
app is the real one (TestClient: its event loop and request thread pool), the rasters the
real Pleiades pair of tests/data/matching.
"""

from __future__ import annotations

import base64
import os
import shutil
import signal
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient
from pba_service_harness import Server
from test_matching_real import DATA, PAIRS, _rpc_job

from service.app import create_app
from service.auth import create_key
from service.processes import MATCH
from service.raster_checks import PROCESS_NAME, stop_pool
from service.settings import Settings
from solver.raster_gate import create_raster

pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")

LEFT, RIGHT, _HEIGHTS = PAIRS["ventoux"]
TIMEOUT_S = 15.0
HELD = 45


@pytest.fixture()
def served(tmp_path: Path):
    root = tmp_path / "images"
    for user in ("alice", "bob"):
        (root / user).mkdir(parents=True)
        for name in (LEFT, RIGHT):
            shutil.copyfile(DATA / f"{name}.tif", root / user / f"{name}.tif")
    settings = Settings(data_dir=tmp_path / "data", workers=0, require_api_keys=True, image_root=root,
                        raster_check_processes=2, raster_checks_per_user=1, raster_check_timeout_s=TIMEOUT_S)
    app = create_app(settings)
    try:
        with TestClient(app, raise_server_exceptions=False) as c:
            store = app.state.services.store
            keys = {u: {"X-API-Key": create_key(store, u)[0]} for u in ("alice", "bob")}
            yield c, keys
    finally:
        stop_pool()


def _match(c: TestClient, key: dict[str, str], doc: dict[str, Any]):
    images = [{"id": LEFT, "path": f"{LEFT}.tif"}, {"id": RIGHT, "path": f"{RIGHT}.tif"}]
    return c.post(f"/processes/{MATCH}/execution", json={"inputs": {"job": doc, "images": images}},
                  headers={**key, "Prefer": "respond-async"})


def test_one_users_held_checks_leave_the_api_and_other_users_answering(served):
    from service import raster_checks

    c, keys = served
    doc = _rpc_job([LEFT, RIGHT], [])
    # two submissions start both check processes (handed out in turn); the next check takes the first
    assert _match(c, keys["bob"], doc).status_code == 201
    assert _match(c, keys["bob"], doc).status_code == 201
    checks = raster_checks._pool
    assert checks is not None and len(checks.pids()) == 2
    held_pid = checks._slots[0].process.pid
    os.kill(held_pid, signal.SIGSTOP)  # its next check never answers
    try:
        with ThreadPoolExecutor(HELD) as ex:
            started = time.monotonic()
            futures = [ex.submit(_match, c, keys["alice"], doc) for _ in range(HELD)]
            # alice's first check is held; the others are refused at once (her share is one)
            deadline = time.monotonic() + 60
            while sum(f.done() for f in futures) < HELD - 1:
                assert time.monotonic() < deadline, [f.result().status_code for f in futures if f.done()]
                time.sleep(0.05)
            refused = [f.result() for f in futures if f.done()]
            assert all(r.status_code == 503 for r in refused), {r.status_code for r in refused}
            assert all(r.headers.get("retry-after") for r in refused)
            assert "PBA_RASTER_CHECKS_PER_USER" in refused[0].json()["detail"]
            # while alice's check is held: liveness, bob's listing and bob's own match submission answer
            t0 = time.monotonic()
            assert c.get("/healthz").status_code == 200
            t_health = time.monotonic() - t0
            t0 = time.monotonic()
            assert c.get("/jobs", headers=keys["bob"]).status_code == 200
            t_list = time.monotonic() - t0
            t0 = time.monotonic()
            assert _match(c, keys["bob"], doc).status_code == 201  # the other check process
            t_bob = time.monotonic() - t0
            still_held = [f for f in futures if not f.done()]
            assert len(still_held) == 1, "alice's held request should still be waiting on its check"
            print(f"held: /healthz {t_health:.3f} s, bob GET /jobs {t_list:.3f} s, bob's match submission {t_bob:.3f} s")
            # the held check times out: a 422 pointing at the raster, the process replaced
            r = still_held[0].result(timeout=TIMEOUT_S + 60)
            assert time.monotonic() - started >= TIMEOUT_S * 0.9
            assert r.status_code == 422, r.text
            err = r.json()["errors"][0]
            assert err["pointer"] == "/inputs/images/0/path" and err["code"] == "timeout", r.text
            assert "PBA_RASTER_CHECK_TIMEOUT_S" in err["message"]
    finally:
        try:
            os.kill(held_pid, signal.SIGCONT)
        except ProcessLookupError:
            pass
    assert held_pid not in checks.pids()
    # the pool recovered: alice submits again
    assert _match(c, keys["alice"], doc).status_code == 201


def test_a_check_process_that_dies_is_a_422_and_replaced(served):
    """GDAL crashing on a file (here: the check process killed while it holds the check)
    refuses that raster and leaves the API answering."""
    from service import raster_checks

    c, keys = served
    doc = _rpc_job([LEFT, RIGHT], [])
    assert _match(c, keys["alice"], doc).status_code == 201
    assert _match(c, keys["alice"], doc).status_code == 201
    checks = raster_checks._pool
    assert checks is not None
    pid = checks._slots[0].process.pid  # the next check's
    os.kill(pid, signal.SIGSTOP)
    with ThreadPoolExecutor(1) as ex:
        f = ex.submit(_match, c, keys["alice"], doc)
        deadline = time.monotonic() + 60
        while not checks._running.get("alice"):  # the request has taken its share: its check is next
            assert time.monotonic() < deadline
            time.sleep(0.02)
        time.sleep(1.0)  # ... sent to the stopped process
        os.kill(pid, signal.SIGKILL)
        r = f.result(timeout=60)
    assert r.status_code == 422, r.text
    err = r.json()["errors"][0]
    assert err["pointer"] == "/inputs/images/0/path" and err["code"] == "unreadable", r.text
    assert c.get("/healthz").status_code == 200
    assert _match(c, keys["alice"], doc).status_code == 201
    assert pid not in checks.pids()


def _rss_mb(pid: int) -> float:
    """Resident memory of process ``pid`` (Linux /proc), MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def _check_processes(parent: int) -> list[int]:
    """The ``pba-raster`` processes of the server process ``parent``, oldest first."""
    out = subprocess.run(["pgrep", "-P", str(parent)], capture_output=True, text=True)
    named = []
    for pid in (int(x) for x in out.stdout.split()):
        try:
            if Path(f"/proc/{pid}/comm").read_text().strip() == PROCESS_NAME:
                named.append((float(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19]), pid))
        except (OSError, IndexError, ValueError):  # ended meanwhile
            continue
    return [pid for _, pid in sorted(named)]


@pytest.mark.slow
def test_a_real_server_answers_others_while_one_user_holds_45_requests(tmp_path: Path):
    """The same as above against a real ``pba serve`` (uvicorn, its own process): 45 held
    connections of alice, /healthz and bob answering. The times are printed, not asserted
    (they depend on the machine's load)."""
    root = tmp_path / "images"
    for user in ("alice", "bob"):
        (root / user).mkdir(parents=True)
        for name in (LEFT, RIGHT):
            shutil.copyfile(DATA / f"{name}.tif", root / user / f"{name}.tif")
    doc = _rpc_job([LEFT, RIGHT], [])
    images = [{"id": LEFT, "path": f"{LEFT}.tif"}, {"id": RIGHT, "path": f"{RIGHT}.tif"}]
    body = {"inputs": {"job": doc, "images": images}}
    with Server(tmp_path / "data", workers=0, require_api_keys="true", image_root=root, raster_check_processes=2,
                raster_checks_per_user=1, raster_check_timeout_s=TIMEOUT_S) as server:
        alice_key, bob_key = server.create_key("alice"), server.create_key("bob")
        async_ = {"Prefer": "respond-async"}
        with server.client(bob_key, timeout=60) as bob:
            for _ in range(2):  # both check processes started; the first takes the next check
                assert bob.post(f"/processes/{MATCH}/execution", json=body, headers=async_).status_code == 201
            assert server.proc is not None
            # a 16384 x 16384 uint16 raster (512 MiB decoded) in a file of a few kB: refused by its header
            bomb = tmp_path / "bomb.tif"
            with create_raster(bomb, driver="GTiff", width=16384, height=16384, count=1, dtype="uint16",
                               tiled=True, compress="deflate", sparse_ok=True):
                pass
            assert bomb.stat().st_size < 100_000
            value = base64.b64encode(bomb.read_bytes()).decode()
            r = bob.post(f"/processes/{MATCH}/execution", headers=async_, json={"inputs": {
                "job": doc, "images": [{"id": LEFT, "value": value}, {"id": RIGHT, "value": value}]}})
            assert r.status_code == 422 and r.json()["errors"][0]["code"] == "too_large", r.text
            rss_mb = _rss_mb(server.proc.pid)
            assert rss_mb < 400, rss_mb  # the API process (it loads no GDAL: the check processes do)
            pids = _check_processes(server.proc.pid)
            assert len(pids) == 2, pids
            os.kill(pids[0], signal.SIGSTOP)
            try:
                def alice_submits() -> Any:
                    with server.client(alice_key, timeout=TIMEOUT_S + 60) as alice:
                        return alice.post(f"/processes/{MATCH}/execution", json=body, headers=async_)

                with ThreadPoolExecutor(HELD) as ex:
                    futures = [ex.submit(alice_submits) for _ in range(HELD)]
                    deadline = time.monotonic() + 60
                    while sum(f.done() for f in futures) < HELD - 1:
                        assert time.monotonic() < deadline, [f.result().status_code for f in futures if f.done()]
                        time.sleep(0.05)
                    assert {f.result().status_code for f in futures if f.done()} == {503}
                    times = {}
                    for what, call in (("/healthz", lambda: httpx.get(f"{server.url}/healthz", timeout=10)),
                                       ("bob GET /jobs", lambda: bob.get("/jobs", timeout=10)),
                                       ("bob's match", lambda: bob.post(f"/processes/{MATCH}/execution", json=body,
                                                                        headers=async_, timeout=10))):
                        t0 = time.monotonic()
                        r = call()
                        times[what] = round(time.monotonic() - t0, 3)
                        assert r.status_code in (200, 201), (what, r.text)
                    assert sum(not f.done() for f in futures) == 1
                    print("real server, alice's check held:", times)
                    held = next(f for f in futures if not f.done()).result()
                    assert held.status_code == 422 and held.json()["errors"][0]["code"] == "timeout", held.text
            finally:
                try:
                    os.kill(pids[0], signal.SIGCONT)
                except ProcessLookupError:
                    pass
