"""Benchmark of the HTTP service on loopback: submit-to-result latency and throughput.

Starts its own ``pba serve`` (127.0.0.1, a free port, a temporary data directory, local
workers), measures, stops the server and exits:

* latency of the example triplet, submit to result: synchronous execution (one request) and
  asynchronous (POST with ``Prefer: respond-async``, poll the status every 10 ms, GET results);
  median and p95 over ``--runs`` jobs after ``--warmup`` jobs;
* throughput: a burst of ``--burst`` triplet jobs submitted at once; jobs per minute from the
  first submission to the last result.

Usage: ``python bench/bench_service.py [--workers 2] [--runs 30] [--burst 200]``
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "prism-triplet.json"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(data_dir: Path, workers: int) -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    env = {
        **os.environ,
        "PBA_DATA_DIR": str(data_dir),
        "PBA_WORKERS": str(workers),
        "PBA_LOG_LEVEL": "WARNING",
        "PBA_MAX_QUEUED_JOBS": "100000",
    }
    pba = Path(sys.executable).with_name("pba")
    proc = subprocess.Popen(
        [str(pba), "serve", "--host", "127.0.0.1", "--port", str(port)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=open(data_dir / "server.log", "wb"),
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                return proc, url
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    proc.kill()
    raise SystemExit("server did not become ready")


def stop_server(proc: subprocess.Popen[bytes], data_dir: Path) -> None:
    """SIGTERM (kill after 30 s) the server of :func:`start_server`; remove its data."""
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        proc.kill()
    shutil.rmtree(data_dir, ignore_errors=True)


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    k = max(0, min(len(ordered) - 1, round(q * (len(ordered) - 1))))
    return ordered[k]


def run_async(c: httpx.Client, body: dict[str, Any]) -> float:
    t0 = time.perf_counter()
    r = c.post(
        "/processes/bundle-adjustment/execution", json=body, headers={"Prefer": "respond-async"}
    )
    r.raise_for_status()
    job = r.json()["jobID"]
    while c.get(f"/jobs/{job}").json()["status"] not in ("successful", "failed", "dismissed"):
        time.sleep(0.01)
    res = c.get(f"/jobs/{job}/results")
    res.raise_for_status()
    return time.perf_counter() - t0


def run_sync(c: httpx.Client, body: dict[str, Any]) -> float:
    t0 = time.perf_counter()
    r = c.post("/processes/bundle-adjustment/execution", json=body)
    r.raise_for_status()
    assert r.status_code == 200
    return time.perf_counter() - t0


def burst(url: str, body: dict[str, Any], n: int) -> float:
    """Seconds from the first submission of ``n`` jobs to the last result."""
    with httpx.Client(base_url=url, timeout=120) as c:
        t0 = time.perf_counter()

        def submit(_: int) -> str:
            r = c.post(
                "/processes/bundle-adjustment/execution",
                json=body,
                headers={"Prefer": "respond-async"},
            )
            r.raise_for_status()
            return r.json()["jobID"]

        with ThreadPoolExecutor(8) as pool:
            ids = set(pool.map(submit, range(n)))
        while True:
            jobs = c.get(
                "/jobs", params={"limit": 1000, "status": ["successful", "failed"]}
            ).json()["jobs"]
            done = {j["jobID"] for j in jobs} & ids
            if len(done) == n:
                return time.perf_counter() - t0
            time.sleep(0.05)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--burst", type=int, default=200)
    args = ap.parse_args()
    body = {"inputs": {"job": json.loads(EXAMPLE.read_text())}}
    data_dir = Path(tempfile.mkdtemp(prefix="pba-bench-"))
    proc, url = start_server(data_dir, args.workers)
    try:
        with httpx.Client(base_url=url, timeout=120) as c:
            for _ in range(args.warmup):
                run_sync(c, body)
            sync = [run_sync(c, body) for _ in range(args.runs)]
            asyn = [run_async(c, body) for _ in range(args.runs)]
        burst_s = burst(url, body, args.burst)
    finally:
        stop_server(proc, data_dir)
    result = {
        "job": EXAMPLE.name,
        "workers": args.workers,
        "runs": args.runs,
        "sync_latency_s": {"median": statistics.median(sync), "p95": percentile(sync, 0.95)},
        "async_latency_s": {"median": statistics.median(asyn), "p95": percentile(asyn, 0.95)},
        "burst_jobs": args.burst,
        "burst_s": burst_s,
        "jobs_per_minute": 60.0 * args.burst / burst_s,
    }
    print(f"submit-to-result latency, {EXAMPLE.name}, {args.runs} runs, {args.workers} workers:")
    for kind in ("sync", "async"):
        lat = result[f"{kind}_latency_s"]
        print(
            f"  {kind:5s}  median {lat['median'] * 1000:7.1f} ms   p95 {lat['p95'] * 1000:7.1f} ms"
        )
    print(
        f"throughput: {args.burst} jobs in {burst_s:.1f} s"
        f" = {result['jobs_per_minute']:.0f} jobs/min"
    )
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
