"""GIS requests shared between users (service/gis_process.py): how long another user's 1-row
ground-to-image takes while a 10,000-row ground-to-image with sigmas runs.

Starts a real server (``pba serve``, keys required, one worker) with the settings given, solves
``examples/prism-nadir.json`` for alice and twice for bob, and reports:

* the large request alone (alice, 10,000 rows with sigmas);
* bob's 1-row transform alone, on a job whose model the GIS process holds (warm);
* bob's 1-row transforms while alice's large request runs: on the warm job, and on a job
  no GIS process has loaded yet (cold: the adjusted model is rebuilt first);
* the resident memory (VmRSS) of every ``pba-gis`` process at the end.

Run by hand (numbers in the notes, never in tests)::

    .venv/bin/python bench/bench_gis_sharing.py            # the lanes (default settings)
    .venv/bin/python bench/bench_gis_sharing.py --small-rows 0   # every request in one lane
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "service"))
from pba_service_harness import Server, execute_body, gis_processes, load_example  # noqa: E402

LARGE_ROWS = 10_000


def points(n: int) -> list[dict[str, float]]:
    return [{"lon": 138.7 + 1e-4 * (k % 100), "lat": 35.3 + 1e-4 * (k // 100), "height": 500.0} for k in range(n)]


def rss_mb(pid: int) -> float:
    for row in Path(f"/proc/{pid}/status").read_text().splitlines():
        if row.startswith("VmRSS:"):
            return int(row.split()[1]) / 1024
    return float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--small-rows", type=int, default=100, help="PBA_GIS_SMALL_ROWS")
    ap.add_argument("--processes", type=int, default=1, help="PBA_GIS_PROCESSES")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        srv = Server(Path(tmp), workers=1, require_api_keys="true", gis_small_rows=args.small_rows, gis_processes=args.processes)
        srv.start()
        try:
            alice, bob = srv.create_key("alice"), srv.create_key("bob")
            job = execute_body(load_example("prism-nadir.json"))
            with srv.client(alice, timeout=900) as ca, srv.client(bob, timeout=900) as cb:
                ids = []
                for c in (ca, cb, cb):
                    r = c.post("/processes/bundle-adjustment/execution", json=job)
                    r.raise_for_status()
                    ids.append(r.headers["location"].rsplit("/", 1)[1])
                job_a, warm, cold = ids
                one = {"image": "prism-nadir", "points": points(1)}
                large = {"image": "prism-nadir", "sigmas": True, "points": points(LARGE_ROWS)}

                def timed(c: Any, job_id: str, body: dict[str, Any]) -> float:
                    t0 = time.perf_counter()
                    r = c.post(f"/jobs/{job_id}/results/ground-to-image", json=body)
                    r.raise_for_status()
                    return time.perf_counter() - t0

                first = timed(cb, warm, one)
                ca.post(f"/jobs/{job_a}/results/ground-to-image", json=one).raise_for_status()
                alone_small = timed(cb, warm, one)
                alone_large = timed(ca, job_a, large)
                done: dict[str, float] = {}

                def run_large() -> None:
                    done["large_s"] = timed(ca, job_a, large)
                    done["end"] = time.perf_counter()

                thread = threading.Thread(target=run_large)
                thread.start()
                time.sleep(2.0)
                during_warm = timed(cb, warm, one)
                during_cold = timed(cb, cold, one)
                answered = time.perf_counter()
                thread.join()
                result = {
                    "settings": {"gis_small_rows": args.small_rows, "gis_processes": args.processes},
                    "load_average": os.getloadavg(),
                    "first_1_row_s (model load)": round(first, 3),
                    "1_row_alone_s": round(alone_small, 3),
                    "10k_rows_sigmas_alone_s": round(alone_large, 2),
                    "1_row_during_large_warm_model_s": round(during_warm, 3),
                    "1_row_during_large_cold_model_s": round(during_cold, 3),
                    "large_during_s": round(done["large_s"], 2),
                    "large_ended_after_small_s": round(done["end"] - answered, 2),
                    "gis_rss_mb": [round(rss_mb(p), 1) for p in gis_processes(srv.proc.pid)] if srv.proc else [],
                }
                print(json.dumps(result, indent=2))
        finally:
            srv.stop()


if __name__ == "__main__":
    main()
