"""Benchmark of fair sharing: how long a user's synchronous small request takes while another
user's batch fills the queue (issue 19).

Starts its own ``pba serve`` (keys required, ``--workers`` local workers), has user A queue
``--batch`` simulated strips (``pba simulate strip``, several seconds each), then measures
user B's synchronous triplet (``examples/prism-triplet.json``) ``--runs`` times, and reports
the median and the worst latency beside the median solve time of A's strips, measured once
A's strips hold every general worker, and whether the median meets the 2 s goal. Strictly
oldest first, B's latency grows with A's batch; with capacity kept for the small-job lane (a
worker reserved for it, ``PBA_SMALL_JOB_WORKERS``) it is B's own solve.

Usage: ``python bench/bench_fair.py [--workers 2] [--batch 8] [--runs 5]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_service import EXAMPLE, start_server, stop_server  # noqa: E402

GOAL_S = 2.0  # the shared server's promise to a small synchronous job, whatever others queued


def strip_doc(directory: Path) -> dict:
    out = directory / "strip.json"
    pba = Path(sys.executable).with_name("pba")
    cmd = ["simulate", "strip", "--triplets", "10", "--tie-points", "10000", "-o", str(out)]
    subprocess.run([str(pba), *cmd], check=True, capture_output=True)
    doc = json.loads(out.read_text())
    doc.setdefault("options", {})["covariance"] = False
    return doc


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    from service.auth import create_key
    from service.store import open_store

    data_dir = Path(tempfile.mkdtemp(prefix="pba-bench-fair-"))
    os.environ["PBA_REQUIRE_API_KEYS"] = "true"
    proc, url = start_server(data_dir, args.workers)
    try:
        store = open_store(f"sqlite:///{data_dir / 'pba.sqlite3'}")
        key_a, key_b = create_key(store, "a")[0], create_key(store, "b")[0]
        store.close()
        strip = {"inputs": {"job": strip_doc(data_dir)}}
        triplet = {"inputs": {"job": json.loads(EXAMPLE.read_text())}}
        with httpx.Client(base_url=url, timeout=600, headers={"X-API-Key": key_b}) as b:
            b.post("/processes/bundle-adjustment/execution", json=triplet)  # warm-up
            with httpx.Client(base_url=url, timeout=600, headers={"X-API-Key": key_a}) as a:
                batch = [
                    a.post(
                        "/processes/bundle-adjustment/execution",
                        json=strip,
                        headers={"Prefer": "respond-async"},
                    ).json()["jobID"]
                    for _ in range(args.batch)
                ]
                # the scene of the promise: A's strips hold every general worker
                busy = min(args.batch, args.workers)
                deadline = time.monotonic() + 300
                while time.monotonic() < deadline and sum(
                    a.get(f"/jobs/{j}").json()["status"] == "running" for j in batch
                ) < busy:
                    time.sleep(0.2)
                latencies = []
                for _ in range(args.runs):
                    t0 = time.perf_counter()
                    r = b.post("/processes/bundle-adjustment/execution", json=triplet)
                    latencies.append(time.perf_counter() - t0)
                    assert r.status_code == 200, r.text[:300]
                for job_id in batch:  # let the batch finish for its solve times
                    while a.get(f"/jobs/{job_id}").json()["status"] in ("accepted", "running"):
                        time.sleep(0.5)
                solves = []
                for job_id in batch:
                    st = a.get(f"/jobs/{job_id}").json()
                    solves.append(
                        (
                            _t(st["finished"]) - _t(st["started"])
                            if st.get("started") and st.get("finished")
                            else float("nan")
                        )
                    )
    finally:
        stop_server(proc, data_dir)
    result = {
        "workers": args.workers,
        "batch": args.batch,
        "b_sync_latency_s": {"median": statistics.median(latencies), "max": max(latencies)},
        "a_strip_solve_s_median": statistics.median(solves),
    }
    print(
        f"user B's synchronous triplet while user A's {args.batch} strips are queued "
        f"({args.workers} workers): median {result['b_sync_latency_s']['median']:.2f} s, "
        f"max {result['b_sync_latency_s']['max']:.2f} s; one strip solves in "
        f"{result['a_strip_solve_s_median']:.2f} s"
    )
    median = result["b_sync_latency_s"]["median"]
    print(f"goal (a small synchronous job answers in at most {GOAL_S:g} s, median): {'met' if median <= GOAL_S else 'NOT met'}")
    print(json.dumps(result))
    return 0


def _t(stamp: str) -> float:
    from datetime import datetime

    return datetime.fromisoformat(stamp.replace("Z", "+00:00")).timestamp()


if __name__ == "__main__":
    sys.exit(main())
