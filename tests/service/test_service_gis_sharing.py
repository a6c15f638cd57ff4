"""GIS requests shared fairly (service/gis_process.py, service/fair_slots.py): on a real server,
another user's 1-row ground-to-image is answered in under 2 s while a 10,000-row
ground-to-image with sigmas runs (about 17 s alone on the reference machine when it had the
GIS process to itself).

The 2 s bound is the issue's contract for a small request, not a speed claim: the 1-row
transform alone takes about 0.02 s once its job's adjusted model is loaded, and the small lane's
process is idle, so what the bound catches is waiting behind the large request (15.8 s before
the lanes). The test asserts that the large request was still running when the small one was
answered, so it cannot pass by the large one finishing first.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from pba_service_harness import Server, execute_body, load_example

pytestmark = [pytest.mark.slow]

LARGE_ROWS = 10_000
SMALL_ANSWER_S = 2.0


def _points(n: int) -> list[dict[str, float]]:
    """``n`` ground points on a 100 x (n / 100) grid of 1e-4 degrees around the nadir scene."""
    return [{"lon": 138.7 + 1e-4 * (k % 100), "lat": 35.3 + 1e-4 * (k // 100), "height": 500.0} for k in range(n)]


def _solved(c: httpx.Client) -> str:
    r = c.post("/processes/bundle-adjustment/execution", json=execute_body(load_example("prism-nadir.json")))
    assert r.status_code == 200, r.text[:500]
    return r.headers["location"].rsplit("/", 1)[1]


def test_a_small_transform_is_answered_while_another_users_large_one_runs(tmp_path: Path) -> None:
    srv = Server(tmp_path, workers=1, require_api_keys="true")
    srv.start()
    try:
        alice, bob = srv.create_key("alice"), srv.create_key("bob")
        with srv.client(alice, timeout=600) as ca, srv.client(bob) as cb:
            job_a, job_b = _solved(ca), _solved(cb)
            one = {"image": "prism-nadir", "points": _points(1)}
            assert cb.post(f"/jobs/{job_b}/results/ground-to-image", json=one).status_code == 200  # loads bob's model
            large: dict[str, Any] = {}

            def run_large() -> None:
                body = {"image": "prism-nadir", "sigmas": True, "points": _points(LARGE_ROWS)}
                r = ca.post(f"/jobs/{job_a}/results/ground-to-image", json=body)
                large["status"], large["rows"] = r.status_code, len(r.json().get("rows", []))
                large["done"] = time.monotonic()

            thread = threading.Thread(target=run_large)
            thread.start()
            time.sleep(2.0)  # the large request is being computed (it takes far longer than this)
            assert "done" not in large, "the large request finished before the small one was sent"
            t0 = time.monotonic()
            r = cb.post(f"/jobs/{job_b}/results/ground-to-image", json=one)
            answered = time.monotonic()
            assert r.status_code == 200, r.text[:500]
            assert len(r.json()["rows"]) == 1 and "line" in r.json()["rows"][0]
            thread.join(600)
            assert large["status"] == 200 and large["rows"] == LARGE_ROWS, large
            assert large["done"] > answered, "the large request ended first: the test proved nothing"
            print(f"1-row transform answered in {answered - t0:.3f} s; the large one ended {large['done'] - answered:.1f} s later")
            assert answered - t0 < SMALL_ANSWER_S, answered - t0
    finally:
        srv.stop()
