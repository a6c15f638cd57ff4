"""Harness of the scale-out tests: real PostgreSQL and Redis on 127.0.0.1, real ``pba worker``
processes (Celery, prefork pool) in subprocesses.

The servers are never mocked and a test never skips when one is missing: it fails and says
which server to start (``make test`` starts both: scripts/ensure-services.sh). Every test run
uses its own PostgreSQL databases (created and dropped here), its own Redis key prefix and
queue names, and a Redis database number derived from its run id, so runs never collide.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import pytest
from pba_service_harness import FINISHED, PBA
from tolerances import RECOMPUTED_REL

from service.store import JobRecord, Store

PG_ADMIN_URL = os.environ.get(
    "PBA_TEST_POSTGRES_ADMIN", "postgresql://postgres@127.0.0.1:5432/postgres"
)
REDIS_URL = os.environ.get("PBA_TEST_REDIS_URL", "redis://127.0.0.1:6379")
# report numbers that may be ~0 (means, offsets): the relative bound alone would demand equality there
NEAR_ZERO_ABS = 1e-12
RUN_ID = uuid.uuid4().hex[:10]
REDIS_DB = 1 + int(RUN_ID, 16) % 15  # 1..15; db 0 is left to people's own servers
KEY_PREFIX = f"pba-test-{RUN_ID}:"
READY_MESSAGE = "worker process ready"


def require_postgres() -> None:
    """Fail (never skip) with a clear message when PostgreSQL does not answer."""
    import psycopg

    try:
        with psycopg.connect(PG_ADMIN_URL, connect_timeout=5) as conn:
            conn.execute("SELECT 1")
    except Exception as exc:
        pytest.fail(
            f"PostgreSQL is not reachable at {PG_ADMIN_URL} ({exc}); these tests need the real "
            "server: run `make services` (scripts/ensure-services.sh) or set "
            "PBA_TEST_POSTGRES_ADMIN",
            pytrace=False,
        )


def require_redis() -> None:
    """Fail (never skip) with a clear message when Redis does not answer."""
    import redis

    try:
        redis.Redis.from_url(f"{REDIS_URL}/{REDIS_DB}", socket_connect_timeout=5).ping()
    except Exception as exc:
        pytest.fail(
            f"Redis is not reachable at {REDIS_URL} ({exc}); these tests need the real server: "
            "run `make services` (scripts/ensure-services.sh) or set PBA_TEST_REDIS_URL",
            pytrace=False,
        )


@contextmanager
def pg_database(label: str = "t") -> Iterator[str]:
    """A fresh PostgreSQL database for the duration of the block (dropped afterwards); its
    SQLAlchemy URL."""
    import psycopg

    require_postgres()
    name = f"pba_{label}_{RUN_ID}_{uuid.uuid4().hex[:6]}"
    with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    base = PG_ADMIN_URL.rsplit("/", 1)[0].replace("postgresql://", "postgresql+psycopg://")
    try:
        yield f"{base}/{name}"
    finally:
        with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def delete_redis_keys(prefix: str = KEY_PREFIX) -> int:
    """Delete this run's Redis keys; how many."""
    import redis

    client = redis.Redis.from_url(f"{REDIS_URL}/{REDIS_DB}")
    keys = list(client.scan_iter(match=f"{prefix}*", count=500))
    if keys:
        client.delete(*keys)
    return len(keys)


def celery_env(database_url: str, queue: str, **extra: Any) -> dict[str, str]:
    """PBA_* variables of a Celery deployment for this test run (short leases for tests)."""
    require_redis()
    env = {
        "PBA_QUEUE": "celery",
        "PBA_BROKER_URL": f"{REDIS_URL}/{REDIS_DB}",
        "PBA_BROKER_KEY_PREFIX": KEY_PREFIX,
        "PBA_CELERY_QUEUE": f"pba-test-{RUN_ID}-{queue}",
        "PBA_DATABASE_URL": database_url,
        "PBA_LEASE_S": "3",
        "PBA_HEARTBEAT_INTERVAL_S": "0.5",
        "PBA_SWEEP_INTERVAL_S": "1",
        "PBA_LOG_FORMAT": "json",
        "PBA_LOG_LEVEL": "INFO",
    }
    env.update({f"PBA_{k.upper()}": str(v) for k, v in extra.items()})
    return env


def settings_for(env: dict[str, str]) -> Any:
    """The Settings a process with ``env`` would read."""
    from service.settings import Settings

    fields = {k[4:].lower(): v for k, v in env.items() if k.startswith("PBA_")}
    return Settings(**fields)


class Worker:
    """A ``pba worker`` subprocess in its own process group, logging to a file."""

    def __init__(self, env: dict[str, str], log_dir: Path, name: str, concurrency: int = 1):
        # the Celery workers solve on the Python evaluation path (the local pool's on the compiled
        # one), so the service runs both; and the test strips then take seconds, time to cancel
        self.env = {**os.environ, "PBA_EVALUATION": "python", **env}
        self.name = name
        self.concurrency = concurrency
        self.log_path = Path(log_dir) / f"worker-{name}.log"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> "Worker":
        log = open(self.log_path, "ab")
        self.proc = subprocess.Popen(
            [
                str(PBA),
                "worker",
                "--concurrency",
                str(self.concurrency),
                "--name",
                f"{self.name}-{RUN_ID}@%h",
            ],
            env=self.env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        log.close()
        return self

    def wait_ready(self, timeout: float = 90.0) -> "Worker":
        """Wait until every pool process has imported the solver and opened the store."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            assert self.proc is not None
            if self.proc.poll() is not None:
                raise AssertionError(f"pba worker exited ({self.proc.returncode}):\n{self.tail()}")
            ready = [r for r in self.records() if r.get("message") == READY_MESSAGE]
            if len(ready) >= self.concurrency:
                return self
            time.sleep(0.2)
        raise AssertionError(f"pba worker not ready after {timeout} s:\n{self.tail()}")

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def kill_group(self) -> None:
        """SIGKILL the worker and its pool processes at once (its machine vanishes)."""
        if self.proc is None:
            return
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait(10)

    def stop(self, timeout: float = 30.0) -> None:
        """Warm shutdown (SIGTERM), then SIGKILL of the group if it hangs."""
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill_group()

    def records(self) -> list[dict[str, Any]]:
        """The JSON log lines of the worker and its pool processes."""
        out = []
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return out
        for line in text.splitlines():
            if line.startswith("{"):
                try:
                    out.append(json.loads(line))
                except ValueError:
                    continue
        return out

    def tail(self, n: int = 40) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return "(no log)"


@contextmanager
def workers(
    env: dict[str, str], log_dir: Path, n: int, concurrency: int = 1
) -> Iterator[list[Worker]]:
    """``n`` started and ready workers, stopped (and killed if need be) afterwards."""
    started = [Worker(env, log_dir, f"w{i}", concurrency).start() for i in range(n)]
    try:
        for w in started:
            w.wait_ready()
        yield started
    finally:
        for w in started:
            w.stop(timeout=20)


def run_outcomes(ws: list[Worker], job_id: str) -> list[tuple[str, str]]:
    """(run token, outcome) of every run of a job that ended, across workers' logs."""
    return [
        (r["worker"], r["status"])
        for w in ws
        for r in w.records()
        if r.get("job_id") == job_id and str(r.get("message", "")).startswith("run ended")
    ]


def ended_runs(
    ws: list[Worker], job_id: str, n: int = 1, timeout: float = 10.0
) -> list[tuple[str, str]]:
    """:func:`run_outcomes` once at least ``n`` runs have logged their end (the store changes
    a moment before the run writes its last log line); all of them after a short grace, so
    that a second completion would be seen too."""
    deadline = time.monotonic() + timeout
    while len(run_outcomes(ws, job_id)) < n and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    return run_outcomes(ws, job_id)


def wait_job(
    store: Store,
    job_id: str,
    statuses: set[str] = FINISHED,
    timeout: float = 120.0,
    min_progress: int = 0,
) -> JobRecord:
    """Poll the store until the job's status is in ``statuses`` (and progress reached)."""
    deadline = time.monotonic() + timeout
    while True:
        rec = store.get_job(job_id)
        assert rec is not None, job_id
        if rec.status.value in statuses and rec.progress >= min_progress:
            return rec
        if rec.status.value in FINISHED and rec.status.value not in statuses:
            raise AssertionError(f"job ended {rec.status.value}: {rec.message}")
        if time.monotonic() > deadline:
            raise AssertionError(f"job still {rec.status.value} after {timeout} s: {rec.message}")
        time.sleep(0.05)


def holder_pid(rec: JobRecord) -> int:
    """The pool process running a job (from its run token ``host:pid:token``)."""
    assert rec.worker and rec.worker.count(":") == 2, rec.worker
    return int(rec.worker.split(":")[1])


def same_numbers(a: Any, b: Any, path: str = "") -> None:
    """Reports equal up to 1e-9 relative (floats), exactly otherwise; timings ignored."""
    import math

    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), f"{path}: keys {set(a) ^ set(b)}"
        for k in a:
            if not (k.endswith("time_s") or k == "timings"):
                same_numbers(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), f"{path}: lengths"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same_numbers(x, y, f"{path}/{i}")
    elif isinstance(a, float) and isinstance(b, (int, float)):
        assert math.isclose(a, b, rel_tol=RECOMPUTED_REL, abs_tol=NEAR_ZERO_ABS), f"{path}: {a} != {b}"
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"
