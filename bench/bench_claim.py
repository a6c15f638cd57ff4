"""Cost of one distributed claim: SQL statements, wall and CPU time of the store calls a Celery
worker makes per message, without the broker or the solve.

Needs PostgreSQL on 127.0.0.1 (``make services``). Creates a temporary database, stores
``--jobs`` accepted jobs of one user (plus ``--running`` jobs of other users held by other
live runs, as on a busy server), then claims and completes every accepted job the way a pool
process does (:func:`service.store.leases.claim_for_message`, then ``complete``), and reports
per claim: the number of SQL statements (independent of the machine's load), and the median
wall and CPU time (load-dependent: compare on the same machine state). Drops the database.

Usage: ``python bench/bench_claim.py [--jobs 200] [--running 8]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PG_ADMIN = os.environ.get(
    "PBA_TEST_POSTGRES_ADMIN", "postgresql://postgres@127.0.0.1:5432/postgres"
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--job", default=str(ROOT / "examples" / "prism-nadir.json"))
    parser.add_argument("--jobs", type=int, default=200, help="accepted jobs to claim")
    parser.add_argument("--running", type=int, default=8, help="jobs running for others")
    args = parser.parse_args()

    import psycopg
    from sqlalchemy import event

    from service.store import leases, open_store
    from service.store.leases import run_token

    def claim_message(store, job_id, token):  # noqa: ANN001, ANN202
        if hasattr(leases, "claim_for_message"):
            return leases.claim_for_message(store, job_id, token, 60.0, 3, 0)
        return leases.claim_run(store, job_id, token, 60.0, 3)  # before fair sharing

    name = f"pba_bench_claim_{uuid.uuid4().hex[:8]}"
    with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    base = PG_ADMIN.rsplit("/", 1)[0].replace("postgresql://", "postgresql+psycopg://")
    store = open_store(f"{base}/{name}")
    try:
        doc = {"job": json.loads(Path(args.job).read_text())}
        n_obs = len(doc["job"]["observations"])
        for i in range(args.running):  # other users' runs, held by this (live) process
            store.claim(store.create_job(f"other{i}", "bundle-adjustment", doc, n_obs, "busy").id, run_token())
        ids = [
            store.create_job("bench", "bundle-adjustment", doc, n_obs, "bench").id
            for _ in range(args.jobs)
        ]
        statements = [0]

        @event.listens_for(store.engine, "before_cursor_execute")
        def count(*_a: object) -> None:
            statements[0] += 1

        per_claim: list[tuple[int, float, float]] = []
        report = json.dumps({"bench": True})
        for job_id in ids:
            token = run_token()
            s0, w0, c0 = statements[0], time.perf_counter(), time.process_time()
            claim = claim_message(store, job_id, token)
            assert claim.runnable and claim.job is not None, claim.outcome
            store.complete(claim.job.id, token, report, "done")
            per_claim.append(
                (statements[0] - s0, time.perf_counter() - w0, time.process_time() - c0)
            )
        n_sql = statistics.median(p[0] for p in per_claim)
        wall = statistics.median(p[1] for p in per_claim) * 1e3
        cpu = statistics.median(p[2] for p in per_claim) * 1e3
        load = os.getloadavg()[0]
        print(
            f"{args.jobs} claims + completions, {args.running} jobs running for other users: "
            f"median {n_sql:.0f} SQL statements, {wall:.2f} ms wall, {cpu:.2f} ms CPU per job "
            f"(1-minute load {load:.1f})"
        )
    finally:
        store.close()
        with psycopg.connect(PG_ADMIN, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
