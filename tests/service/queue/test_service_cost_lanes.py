"""A job's lane comes from what it will cost (service.lanes): observations for adjustments,
pixels for matchings, so a match job never takes the small-job lane.

The focused tests submit through the API (no worker) and read the lane the store recorded; the
last test runs a real server (2 general workers and the small-lane worker) with one user's 8
match jobs queued and another user's small synchronous adjustment.
"""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from pba_service_harness import Server, execute_body

from service.app import create_app
from service.auth import create_key
from service.processes import MATCH
from service.settings import Settings

sys.path.insert(0, str(Path(__file__).parents[2] / "solver" / "matching"))
from test_matching_real import DATA, PAIRS, _rpc_job  # noqa: E402

pytestmark = [pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")]

LEFT, RIGHT, HEIGHTS = PAIRS["ventoux"]
# The contract is an answer within 2 s. The lane decides the waits around the solve; on
# this 2-core machine at a load average of 13-15 those waits were 0.11-0.21 s in three runs and
# 2.7 s in one (the small-lane worker descheduled), so the bound asserted is 5 s: generous for a
# loaded CI machine, still far below the minute the small job waited when match jobs filled its
# lane. What proves the lane is the occupancy check (2 running, not 3), which times nothing.
LANE_WAIT_S = 5.0
HEIGHTS_M = [float(h) for h in HEIGHTS.split(",")]


def _image_root(tmp_path: Path) -> Path:
    root = tmp_path / "images"
    (root / "alice").mkdir(parents=True)
    for name in (LEFT, RIGHT):
        shutil.copyfile(DATA / f"{name}.tif", root / "alice" / f"{name}.tif")
    return root


def _match_body(observations: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    images = [{"id": name, "path": f"{name}.tif"} for name in (LEFT, RIGHT)]
    job = _rpc_job([LEFT, RIGHT], observations or [])
    return {"inputs": {"job": job, "images": images, "heights_m": HEIGHTS_M, "match": {"grid": 8}}}


def _lane_of(tmp_path: Path, process: str, body: dict[str, Any], **settings: Any) -> bool:
    """Submit ``body`` to a server without workers; the lane the store recorded (True: small)."""
    app = create_app(Settings(data_dir=tmp_path / "data", workers=0, require_api_keys=True, **settings))
    with TestClient(app) as c:
        store = app.state.services.store
        key = {"X-API-Key": create_key(store, "alice")[0], "Prefer": "respond-async"}
        r = c.post(f"/processes/{process}/execution", json=body, headers=key)
        assert r.status_code == 201, r.text[:500]
        rec = store.get_job(r.json()["jobID"])
        assert rec is not None
        return rec.small


@pytest.mark.parametrize("above", [0, 1])
def test_the_lane_threshold_is_inclusive(tmp_path: Path, small_doc: dict[str, Any], above: int) -> None:
    """A job of exactly ``small_job_observations`` observations is small; one more is not."""
    n = len(small_doc["observations"])
    small = _lane_of(tmp_path, "bundle-adjustment", execute_body(small_doc), small_job_observations=n - above)
    assert small is (above == 0)


def test_a_match_job_never_takes_the_small_lane(tmp_path: Path) -> None:
    """A composed job without measurements (0 observations, far below any threshold) is still
    not small when it is a matching: its cost is its rasters' pixels."""
    small = _lane_of(tmp_path, MATCH, _match_body(), image_root=_image_root(tmp_path),
                     small_job_observations=1_000_000)
    assert small is False


def test_synchronous_execution_does_not_change_the_lane(tmp_path: Path, small_doc: dict[str, Any]) -> None:
    """A client waiting for the answer does not make a large job small (a server without
    workers answers a synchronous request asynchronously, after storing the job)."""
    n = len(small_doc["observations"])
    app = create_app(Settings(data_dir=tmp_path / "data", workers=0, require_api_keys=True,
                              small_job_observations=n - 1))
    with TestClient(app) as c:
        store = app.state.services.store
        key = {"X-API-Key": create_key(store, "alice")[0]}
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(small_doc), headers=key)
        assert r.status_code == 201, r.text[:300]
        rec = store.get_job(r.json()["jobID"])
        assert rec is not None and rec.small is False


@pytest.mark.slow
def test_a_small_adjustment_is_answered_while_another_users_match_jobs_wait(
    tmp_path: Path, small_doc: dict[str, Any]
) -> None:
    """Alice's 16 match jobs on 2 general workers: 2 of them run (none takes the small-lane
    worker), and Bob's small synchronous adjustment is answered (200), having waited less than
    LANE_WAIT_S for anything but its own solve: in the queue (the store's created -> started) and
    around it (the answer time minus the run's started -> finished). That is the lane's
    contract, and it does not depend on the machine's load; the solve itself competes for the
    cores with the running matchings and everything else on the machine, which no lane
    decides (the whole answer time is printed: 0.8 to 3 s at a load average of 13 on 2 cores)."""
    srv = Server(tmp_path, workers=2, require_api_keys="true", image_root=_image_root(tmp_path))
    srv.start()
    try:
        alice, bob = srv.create_key("alice"), srv.create_key("bob")
        with srv.client(alice) as ca, srv.client(bob) as cb:
            # warm the small-lane worker (its first job loads the solver's caches)
            r = cb.post("/processes/bundle-adjustment/execution", json=execute_body(small_doc))
            assert r.status_code == 200, r.text[:300]
            jobs = []
            for _ in range(16):  # enough to keep both workers busy for seconds (a match job of this pair takes about 1 s)
                r = ca.post(f"/processes/{MATCH}/execution", json=_match_body(), headers={"Prefer": "respond-async"})
                assert r.status_code == 201, r.text[:300]
                jobs.append(r.json()["jobID"])
            deadline = time.monotonic() + 60
            while sum(ca.get(f"/jobs/{j}").json()["status"] == "running" for j in jobs) < 2:
                assert time.monotonic() < deadline, "the match jobs did not start"
                time.sleep(0.1)
            time.sleep(1.0)  # a free small-lane worker polls the store within this (PBA_POLL_INTERVAL_S)
            statuses = [ca.get(f"/jobs/{j}").json()["status"] for j in jobs]
            assert statuses.count("running") == 2, statuses  # the small-lane worker took none
            assert statuses.count("accepted") >= 4, statuses  # still waiting: the test is loaded
            t0 = time.monotonic()
            r = cb.post("/processes/bundle-adjustment/execution", json=execute_body(small_doc))
            answered_s = time.monotonic() - t0
            assert r.status_code == 200, r.text[:300]
            rec = srv.store().get_job(r.headers["Location"].rsplit("/", 1)[1])
            assert rec is not None and rec.started is not None
            assert rec.finished is not None
            waited_s = (rec.started - rec.created).total_seconds()
            solve_s = (rec.finished - rec.started).total_seconds()
            assert waited_s < LANE_WAIT_S, waited_s
            assert answered_s - solve_s < LANE_WAIT_S, (answered_s, solve_s)
            statuses = [ca.get(f"/jobs/{j}").json()["status"] for j in jobs]
            assert statuses.count("accepted") >= 1, statuses  # the match jobs were still waiting
            print(f"small adjustment: waited {waited_s:.3f} s, solved in {solve_s:.3f} s, answered in {answered_s:.3f} s")
            for j in jobs:
                ca.delete(f"/jobs/{j}")
    finally:
        srv.stop()


# ---- the share: what a running job counts for in its user's fair share ----------------------


def test_a_jobs_share_is_its_cost_in_small_jobs_worth() -> None:
    from service.lanes import PIXELS_PER_OBSERVATION, share_of
    from service.processes import JobCost

    assert share_of(JobCost("observations", 10), 5000) == 1.0  # at least one job
    assert share_of(JobCost("observations", 50_000), 5000) == pytest.approx(10.0)
    pixels = 2 * 10_000 * 10_000
    assert share_of(JobCost("pixels", pixels), 5000) == pytest.approx(pixels / PIXELS_PER_OBSERVATION / 5000)


def test_a_submitted_match_job_records_its_pixels_share(tmp_path: Path) -> None:
    """The Ventoux pair (500 x 500 and 498 x 495 pixels) with a unit of 100 observations: its
    share is its pixels over PIXELS_PER_OBSERVATION x 100, not 1 as for any job before."""
    from service.lanes import PIXELS_PER_OBSERVATION

    app = create_app(Settings(data_dir=tmp_path / "data", workers=0, require_api_keys=True,
                              image_root=_image_root(tmp_path), small_job_observations=100))
    with TestClient(app) as c:
        store = app.state.services.store
        key = {"X-API-Key": create_key(store, "alice")[0], "Prefer": "respond-async"}
        r = c.post(f"/processes/{MATCH}/execution", json=_match_body(), headers=key)
        assert r.status_code == 201, r.text[:500]
        rec = store.get_job(r.json()["jobID"])
        assert rec is not None
        assert rec.share == pytest.approx((500 * 500 + 498 * 495) / PIXELS_PER_OBSERVATION / 100)


def test_a_user_running_one_costly_job_comes_after_a_user_running_two_small_ones() -> None:
    from datetime import datetime, timezone

    from service.store.fair import Head, OwnerLoad, pick

    t = datetime(2026, 1, 1, tzinfo=timezone.utc)
    heads = [Head("a", False, t), Head("b", False, t)]
    loads = {"a": OwnerLoad(running=1, running_share=40.0), "b": OwnerLoad(running=2, running_share=2.0)}
    assert pick(heads, loads).owner == "b"  # counted by jobs, a (1 running) would come first


def test_the_store_sums_the_running_jobs_shares(tmp_path: Path) -> None:
    """On a real store: alice runs one job of share 40, bob two of share 1; each has one more
    waiting; the next claim is bob's."""
    from service.store import open_store

    store = open_store(f"sqlite:///{tmp_path / 'jobs.db'}")
    try:
        doc = {"job": {}}
        big = store.create_job("alice", "match", doc, 0, "big", share=40.0)
        small = [store.create_job("bob", "bundle-adjustment", doc, 10, f"b{i}") for i in range(2)]
        for rec in (big, *small):
            assert store.claim(rec.id, "w") is not None
        store.create_job("alice", "match", doc, 0, "a-next", share=40.0)
        nxt = store.create_job("bob", "bundle-adjustment", doc, 10, "b-next")
        got = store.claim_next("w2")
        assert got is not None and got.id == nxt.id, got
    finally:
        store.close()
