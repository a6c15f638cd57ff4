"""Test harness: a real ``pba serve`` (uvicorn + local worker processes) in a subprocess.

Each server gets a free loopback port and its own data directory; its log goes to
``<data_dir>/server.log`` (printed when a test fails to start it).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx

from service.auth import create_key
from service.gis_process import PROCESS_NAME as GIS_PROCESS_NAME
from service.store import Store, open_store

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
PBA = Path(sys.executable).with_name("pba")
FINISHED = {"successful", "failed", "dismissed"}


def free_port() -> int:
    """A currently free TCP port on 127.0.0.1."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """A ``pba serve`` subprocess (in its own process group)."""

    def __init__(self, data_dir: Path, workers: int = 2, **env: Any) -> None:
        self.data_dir = Path(data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.workers = workers
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.env = {
            **os.environ,
            "PBA_DATA_DIR": str(self.data_dir),
            "PBA_WORKERS": str(workers),
            "PBA_LOG_FORMAT": "json",
            **{f"PBA_{k.upper()}": str(v) for k, v in env.items()},
        }
        self.proc: subprocess.Popen[bytes] | None = None
        self.log_path = self.data_dir / "server.log"

    @property
    def database_url(self) -> str:
        return f"sqlite:///{(self.data_dir / 'pba.sqlite3').resolve()}"

    def store(self) -> Store:
        """A store on the server's database (the test's own connection)."""
        return open_store(self.database_url, create=True)

    def start(self, timeout: float = 180.0) -> "Server":
        """Start and wait until /readyz answers 200 (store up, a worker warmed up: the solver
        loaded, its kernels from the cache; slower on a loaded machine)."""
        log = open(self.log_path, "ab")
        self.proc = subprocess.Popen(
            [str(PBA), "serve", "--host", "127.0.0.1", "--port", str(self.port)],
            env=self.env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        log.close()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited ({self.proc.returncode}):\n{self.log_tail()}")
            try:
                if httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        raise RuntimeError(f"server not ready after {timeout} s:\n{self.log_tail()}")

    def stop(self, timeout: float = 30.0) -> int | None:
        """Graceful stop (SIGTERM), then SIGKILL of the group if it hangs."""
        if self.proc is None or self.proc.poll() is not None:
            return self.proc.returncode if self.proc else None
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill_group()
            return None

    def __enter__(self) -> "Server":
        """``with Server(...) as srv``: started, and stopped however the block ends."""
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def kill_group(self) -> None:
        """SIGKILL the server and all its workers at once (a crash of the whole machine)."""
        if self.proc is None:
            return
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait(10)

    def log_tail(self, n: int = 60) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return "(no log)"

    def log_records(self) -> list[dict[str, Any]]:
        """The server's (and its workers') JSON log lines."""
        out = []
        for line in self.log_path.read_text(errors="replace").splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                continue
        return out

    def create_key(self, user: str, admin: bool = False, **limits: Any) -> str:
        """A new API key, written straight into the server's store."""
        store = self.store()
        try:
            key, _ = create_key(
                store,
                user,
                admin,
                limits.get("max_queued_jobs"),
                limits.get("max_job_observations"),
            )
        finally:
            store.close()
        return key

    def client(self, key: str | None = None, timeout: float = 120.0) -> httpx.Client:
        """An HTTP client for this server, with an API key when given."""
        headers = {"X-API-Key": key} if key else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=timeout)


def execute_body(job: dict[str, Any], **inputs: Any) -> dict[str, Any]:
    """An OGC execute request for a job document."""
    return {"inputs": {"job": job, **inputs}}


def submit_async(
    client: httpx.Client, job: dict[str, Any], process: str = "bundle-adjustment"
) -> str:
    """Submit with Prefer: respond-async; the job id."""
    r = client.post(
        f"/processes/{process}/execution",
        json=execute_body(job),
        headers={"Prefer": "respond-async"},
    )
    assert r.status_code == 201, r.text
    return r.json()["jobID"]


def wait_status(
    client: httpx.Client,
    job_id: str,
    statuses: set[str] = FINISHED,
    timeout: float = 120.0,
    min_progress: int = 0,
) -> dict[str, Any]:
    """Poll a job's status document until its status is in ``statuses``."""
    deadline = time.monotonic() + timeout
    while True:
        st = client.get(f"/jobs/{job_id}").json()
        if st["status"] in statuses and st["progress"] >= min_progress:
            return st
        if st["status"] in FINISHED and st["status"] not in statuses:
            raise AssertionError(f"job ended {st['status']}: {st['message']}")
        if time.monotonic() > deadline:
            raise AssertionError(f"job still {st['status']} after {timeout} s: {st}")
        time.sleep(0.1)


def solved_report(client: httpx.Client, job: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """Submit ``job``, wait until it succeeds (asserted) and return its id and report."""
    job_id = submit_async(client, job)
    st = wait_status(client, job_id)
    assert st["status"] == "successful", st
    return job_id, client.get(f"/jobs/{job_id}/results").json()["report"]


def load_example(name: str) -> dict[str, Any]:
    return json.loads((EXAMPLES / name).read_text())


def gis_processes(parent: int) -> list[int]:
    """The ``pba-gis`` processes (service/gis_process.py) the server process ``parent`` started
    (pgrep and Linux /proc)."""
    out = subprocess.run(["pgrep", "-P", str(parent)], capture_output=True, text=True)
    named = []
    for pid in (int(x) for x in out.stdout.split()):
        try:
            if Path(f"/proc/{pid}/comm").read_text().strip() == GIS_PROCESS_NAME:
                named.append(pid)
        except OSError:  # ended meanwhile
            continue
    return named
