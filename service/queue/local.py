"""The default queue: a pool of local worker processes supervised by the server.

Workers (``spawn`` start method) claim accepted jobs from the store themselves; this class
only starts them, wakes them on submission, and supervises them from a thread of the server:

* a worker that dies (``kill -9``, SIGSEGV, glog FATAL) fails the job it held with a message
  naming the signal or exit code, and is replaced (with a back-off if it keeps dying at once);
* a worker whose job exceeds the time limit by ``kill_grace_s`` without stopping (the solver
  checks its cancel hook only between iterations) is killed and its job failed;
* at start-up, jobs left running by a previous server are re-queued, or failed once they have
  been interrupted ``max_attempts`` times;
* at shutdown, workers are asked to stop; a job being solved goes back to the queue.

Besides the ``PBA_WORKERS`` general workers, ``PBA_SMALL_JOB_WORKERS`` workers (when there are
general workers at all) take only jobs of the small-job lane, in the fair order: a small
synchronous job then starts at once even while big jobs occupy every general worker.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import threading
import time
from dataclasses import replace
from datetime import datetime, timezone
from typing import Any

from service.execution import RunLimits
from service.queue.worker import WorkerConfig, worker_id, worker_main
from service.settings import Settings
from service.states import FailureCode
from service.store import Store

log = logging.getLogger("pba.queue")

SUPERVISE_INTERVAL_S = 0.5
QUICK_DEATH_S = 5.0
MAX_BACKOFF_S = 30.0


def describe_exit(exitcode: int | None) -> str:
    """A sentence for a worker's exit code (negative: killed by a signal)."""
    if exitcode is None:
        return "is not responding"
    if exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        return f"was killed by {name}"
    return f"exited with status {exitcode}"


class _Slot:
    """One worker position in the pool."""

    def __init__(self, index: int, small_only: bool = False) -> None:
        self.index = index
        self.small_only = small_only
        self.process: mp.process.BaseProcess | None = None
        self.ready: Any = None  # set by the worker once warmed up (solver loaded, kernels compiled)
        self.started = 0.0
        self.quick_deaths = 0
        self.next_start = 0.0
        self.killed_for_time: str | None = None


class LocalPoolBackend:
    """Local worker processes (see module docstring)."""

    name = "local"

    def __init__(self, settings: Settings, store: Store) -> None:
        self.settings = settings
        self.store = store
        self.ctx = mp.get_context("spawn")
        self.stop_event = self.ctx.Event()
        self.wake = self.ctx.Event()
        reserved = settings.small_job_workers if settings.workers > 0 else 0
        self.slots = [_Slot(i) for i in range(settings.workers)] + [
            _Slot(settings.workers + i, small_only=True) for i in range(reserved)
        ]
        self.restarts = 0
        self.target: Any = worker_main  # a worker process's entry point (picklable)
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.config = WorkerConfig(
            database_url=settings.resolved_database_url,
            parent_pid=os.getpid(),
            poll_interval_s=settings.poll_interval_s,
            limits=RunLimits(
                job_time_limit_s=settings.job_time_limit_s,
                progress_interval_s=settings.progress_interval_s,
                cancel_poll_interval_s=settings.cancel_poll_interval_s,
            ),
            log_level=settings.log_level,
            log_format=settings.log_format,
            max_running_per_user=settings.max_running_per_user,
        )

    # -- QueueBackend ----------------------------------------------------------------------
    def start(self) -> None:
        """Recover interrupted jobs, start the workers and the supervisor thread."""
        requeued, failed = self.store.recover_interrupted(self.settings.max_attempts)
        for job_id in requeued:
            log.warning("re-queued a job interrupted by a restart", extra={"job_id": job_id})
        for job_id in failed:
            log.error("failed a job interrupted too often", extra={"job_id": job_id})
        with self._lock:
            for slot in self.slots:
                self._spawn(slot)
        self._thread = threading.Thread(target=self._supervise, name="pba-supervisor", daemon=True)
        self._thread.start()
        if self.slots:
            self.wake.set()

    def stop(self) -> None:
        """Ask workers to stop, wait ``shutdown_grace_s``, kill the rest, re-queue their jobs."""
        self._stopping.set()
        self.stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        deadline = time.monotonic() + self.settings.shutdown_grace_s
        with self._lock:
            for slot in self.slots:
                p = slot.process
                if p is None:
                    continue
                p.join(timeout=max(0.0, deadline - time.monotonic()))
                if p.is_alive():
                    p.kill()
                    p.join(timeout=5)
                    wid = worker_id(p.pid)
                    for job in self.store.running_jobs():
                        if job.worker == wid:
                            self.store.requeue(
                                job.id, wid, "re-queued: the server stopped during the solve", False
                            )

    def submit(self, job_id: str) -> None:
        """Wake an idle worker (they also poll the store)."""
        self.wake.set()

    def cancel(self, job_id: str) -> None:
        """Nothing to do: the worker polls the store's cancel flag."""

    def ready(self) -> tuple[bool, str]:
        """Ready when at least one general worker is alive and warmed up (its solver loaded,
        its kernels compiled: a fresh installation's first start compiles them for minutes),
        or when none are configured."""
        if not self.slots:
            return True, "no local workers configured (PBA_WORKERS=0)"
        general = [s for s in self.slots if not s.small_only]
        alive = [s for s in general if s.process is not None and s.process.is_alive()]
        warmed = sum(1 for s in alive if s.ready is not None and s.ready.is_set())
        text = f"{len(alive)} of {len(general)} workers alive"
        if warmed < len(alive):
            text += f", {warmed} ready ({len(alive) - warmed} starting: loading the solver, compiling its kernels)"
        return warmed > 0, text

    def worker_count(self) -> int:
        """General workers alive now (the small-lane workers are not counted: they take no
        job of the ordinary lane, which is what queue placements estimate)."""
        return sum(1 for s in self.slots if not s.small_only and s.process is not None and s.process.is_alive())

    def worker_pids(self) -> list[int]:
        """PIDs of the live workers."""
        return [
            s.process.pid
            for s in self.slots
            if s.process and s.process.is_alive() and s.process.pid
        ]

    # -- supervision -----------------------------------------------------------------------
    def _spawn(self, slot: _Slot) -> None:
        config = replace(self.config, small_only=True) if slot.small_only else self.config
        slot.ready = self.ctx.Event()
        p = self.ctx.Process(
            target=self.target,
            args=(config, self.stop_event, self.wake, slot.ready),
            name=f"pba-{'small-' if slot.small_only else ''}worker-{slot.index}",
            daemon=True,
        )
        p.start()
        slot.process = p
        slot.started = time.monotonic()
        slot.killed_for_time = None
        log.info("started worker %s", worker_id(p.pid))

    def _supervise(self) -> None:
        while not self._stopping.wait(SUPERVISE_INTERVAL_S):
            try:
                with self._lock:
                    if self._stopping.is_set():
                        return
                    self._check_workers()
                self._check_time_limits()
            except Exception:
                log.exception("supervisor error")

    def _check_workers(self) -> None:
        now = time.monotonic()
        for slot in self.slots:
            p = slot.process
            if p is not None and p.is_alive():
                continue
            if p is not None:
                self._bury(slot, p)
                slot.process = None
                lived = now - slot.started
                slot.quick_deaths = slot.quick_deaths + 1 if lived < QUICK_DEATH_S else 0
                backoff = min(MAX_BACKOFF_S, 0.5 * 2**slot.quick_deaths) if slot.quick_deaths else 0
                slot.next_start = now + backoff
            if now >= slot.next_start:
                self.restarts += 1
                self._spawn(slot)

    def _bury(self, slot: _Slot, p: mp.process.BaseProcess) -> None:
        wid = worker_id(p.pid)
        how = describe_exit(p.exitcode)
        if slot.killed_for_time:
            message = (
                f"time limit of {self.settings.job_time_limit_s:g} s exceeded and the solve did "
                f"not stop; its worker process was killed"
            )
            code = FailureCode.time_limit
        else:
            message = (
                f"the worker process running this job {how} (a crash in the solver or an "
                "external kill); the job was not retried"
            )
            code = FailureCode.worker_died
        for job in self.store.running_jobs():
            if job.worker == wid and self.store.fail(
                job.id, message, {"code": code}, worker=wid
            ):
                log.error("worker %s %s; job failed", wid, how, extra={"job_id": job.id})
        log.warning("worker %s %s; replacing it", wid, how)

    def _check_time_limits(self) -> None:
        limit = self.settings.job_time_limit_s + self.settings.kill_grace_s
        now = datetime.now(timezone.utc)
        by_worker = {worker_id(s.process.pid): s for s in self.slots if s.process and s.process.pid}
        for job in self.store.running_jobs():
            slot = by_worker.get(job.worker or "")
            if slot is None or job.started is None or slot.killed_for_time:
                continue
            if (now - job.started).total_seconds() > limit:
                log.error("job over its time limit; killing its worker", extra={"job_id": job.id})
                slot.killed_for_time = job.id
                assert slot.process is not None
                slot.process.kill()
