"""Load test of the distributed queue on loopback: throughput of 1 and 2 ``pba worker``
processes on the same burst of real jobs, and the scaling ratio.

Needs PostgreSQL and Redis on 127.0.0.1 (``make services``). Creates a temporary PostgreSQL
database and uses its own Redis key prefix and queue, starts ``pba worker`` subprocesses
(one pool process each), measures, stops them, drops the database, deletes its Redis keys
and exits; every wait is bounded (``--timeout``).

For each worker count: start the workers, warm every pool process up (imports and numba
caches), then store a burst of ``--burst`` jobs and publish them the way the API does after
validating a submission (the HTTP side is measured by bench_service.py), and time from the
first publication to the last job finished (the store's ``finished`` times). Each round is
repeated ``--rounds`` times; the median is reported.

Usage: ``python bench/bench_celery.py [--job examples/prism-nadir.json] [--burst 150]``
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PG_ADMIN = os.environ.get(
    "PBA_TEST_POSTGRES_ADMIN", "postgresql://postgres@127.0.0.1:5432/postgres"
)
REDIS = os.environ.get("PBA_TEST_REDIS_URL", "redis://127.0.0.1:6379")
LOOPBACK = ("127.0.0.1", "localhost", "[::1]")


def check_loopback(url: str) -> None:
    if not any(f"@{h}" in url or f"//{h}" in url for h in LOOPBACK):
        raise SystemExit(f"refusing a non-loopback server: {url}")


class Bench:
    def __init__(self, args: argparse.Namespace) -> None:
        import psycopg

        check_loopback(PG_ADMIN)
        check_loopback(REDIS)
        self.args = args
        self.run_id = uuid.uuid4().hex[:8]
        self.db_name = f"pba_bench_{self.run_id}"
        with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{self.db_name}"')
        base = PG_ADMIN.rsplit("/", 1)[0].replace("postgresql://", "postgresql+psycopg://")
        self.redis_db = 1 + int(self.run_id, 16) % 15
        self.prefix = f"pba-bench-{self.run_id}:"
        self.env = {
            "PBA_QUEUE": "celery",
            "PBA_DATABASE_URL": f"{base}/{self.db_name}",
            "PBA_BROKER_URL": f"{REDIS}/{self.redis_db}",
            "PBA_BROKER_KEY_PREFIX": self.prefix,
            "PBA_CELERY_QUEUE": f"bench-{self.run_id}",
            "PBA_LOG_LEVEL": "WARNING",
            "PBA_LOG_FORMAT": "json",
        }
        os.environ.update(self.env)
        from service.queue.celery_backend import CeleryBackend
        from service.settings import Settings
        from service.store import open_store

        self.settings = Settings()
        self.store = open_store(self.settings.resolved_database_url)
        self.backend = CeleryBackend(self.settings, self.store)
        self.doc = {"job": json.loads(Path(args.job).read_text())}
        self.n_obs = len(self.doc["job"]["observations"])
        self.tmp = Path(tempfile.mkdtemp(prefix="pba-bench-celery-"))
        self.procs: list[subprocess.Popen[bytes]] = []

    # -- workers ---------------------------------------------------------------------------
    def start_workers(self, n: int) -> None:
        pba = Path(sys.executable).with_name("pba")
        for i in range(n):
            log = open(self.tmp / f"worker-{len(self.procs)}.log", "ab")
            self.procs.append(
                subprocess.Popen(
                    [
                        str(pba),
                        "worker",
                        "--concurrency",
                        "1",
                        "--name",
                        f"bench{i}-{self.run_id}@%h",
                    ],
                    env={**os.environ, **self.env},
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    start_new_session=True,
                )
            )
            log.close()

    def stop_workers(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in self.procs:
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(10)
        self.procs = []

    # -- jobs ------------------------------------------------------------------------------
    def create(self, n: int) -> list[str]:
        return [
            self.store.create_job("bench", "bundle-adjustment", self.doc, self.n_obs, "bench").id
            for _ in range(n)
        ]

    def wait(self, ids: list[str]) -> list[Any]:
        """Until no job is accepted or running (one COUNT query per poll: the bench must not
        load the machine it measures), then the records."""
        from service.states import JobStatus

        deadline = time.monotonic() + self.args.timeout
        while True:
            counts = self.store.counts_by_status()
            if counts[JobStatus.accepted] + counts[JobStatus.running] == 0:
                break
            if time.monotonic() > deadline:
                raise SystemExit(f"jobs unfinished after {self.args.timeout} s: {counts}")
            for p in self.procs:
                if p.poll() is not None:
                    raise SystemExit(f"a worker exited ({p.returncode}); see {self.tmp}")
            time.sleep(0.05)
        recs = [self.store.get_job(j) for j in ids]
        bad = [r for r in recs if r.status.value != "successful"]
        if bad:
            raise SystemExit(f"{len(bad)} jobs did not succeed: {bad[0].message}")
        return recs

    def warm_up(self, n_workers: int) -> None:
        """Jobs until every pool process has solved a few (imports, numba caches loaded)."""
        deadline = time.monotonic() + self.args.timeout
        while True:
            recs = self.wait_ids(self.create(4 * n_workers))
            holders: dict[str, int] = {}
            for r in recs:
                pid = r.worker.split(":")[1]
                holders[pid] = holders.get(pid, 0) + 1
            if len(holders) >= n_workers:
                return
            if time.monotonic() > deadline:
                raise SystemExit("warm-up did not reach every worker")

    def wait_ids(self, ids: list[str]) -> list[Any]:
        for job_id in ids:
            self.backend.submit(job_id)
        return self.wait(ids)

    def burst(self) -> dict[str, float]:
        ids = self.create(self.args.burst)
        t0 = datetime.now(timezone.utc)
        m0 = time.monotonic()
        for job_id in ids:
            self.backend.submit(job_id)
        publish_s = time.monotonic() - m0
        recs = self.wait(ids)
        last = max(r.finished for r in recs)
        elapsed = (last - t0).total_seconds()
        solve = statistics.median((r.finished - r.started).total_seconds() for r in recs)
        return {
            "elapsed_s": elapsed,
            "jobs_per_s": len(ids) / elapsed,
            "publish_s": publish_s,
            "median_run_s": solve,
        }

    def measure(self, n_workers: int) -> dict[str, Any]:
        self.start_workers(n_workers)
        try:
            self.warm_up(n_workers)
            rounds = [self.burst() for _ in range(self.args.rounds)]
        finally:
            self.stop_workers()
        jps = statistics.median(r["jobs_per_s"] for r in rounds)
        return {"workers": n_workers, "rounds": rounds, "jobs_per_s": jps}

    def close(self) -> None:
        import psycopg
        import redis

        self.stop_workers()
        self.backend.stop()
        self.store.close()
        with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{self.db_name}" WITH (FORCE)')
        client = redis.Redis.from_url(f"{REDIS}/{self.redis_db}")
        keys = list(client.scan_iter(match=f"{self.prefix}*", count=500))
        if keys:
            client.delete(*keys)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--job", default=str(ROOT / "examples" / "prism-nadir.json"))
    parser.add_argument("--burst", type=int, default=150, help="jobs per burst")
    parser.add_argument("--rounds", type=int, default=3, help="bursts per worker count")
    parser.add_argument("--timeout", type=float, default=300.0, help="bound of every wait, s")
    args = parser.parse_args()
    bench = Bench(args)
    t_start = time.monotonic()
    load_before = os.getloadavg()[0]
    try:
        results = [bench.measure(n) for n in (1, 2)]
    finally:
        bench.close()
    one, two = results
    print(
        f"job: {Path(args.job).name} ({bench.n_obs} observations), burst of {args.burst} "
        f"jobs, {args.rounds} rounds, PostgreSQL store, Redis broker, 1 pool process per "
        f"worker, {os.cpu_count()} cores"
    )
    for r in results:
        per_round = ", ".join(f"{x['jobs_per_s']:.1f}" for x in r["rounds"])
        print(
            f"{r['workers']} worker process(es): {r['jobs_per_s']:.1f} jobs/s "
            f"({r['jobs_per_s'] * 60:.0f} jobs/min; rounds {per_round}; median run "
            f"{statistics.median(x['median_run_s'] for x in r['rounds']) * 1000:.0f} ms)"
        )
    print(f"scaling ratio (2 workers / 1 worker): {two['jobs_per_s'] / one['jobs_per_s']:.2f}")
    print(
        f"bench took {time.monotonic() - t_start:.0f} s; 1-minute load average "
        f"{load_before:.1f} before, {os.getloadavg()[0]:.1f} after (other processes share "
        "the cores: compare the ratio only on a quiet machine)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
