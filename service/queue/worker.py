"""The local worker process: claim accepted jobs from the store and solve them, one at a time.

Started by :class:`service.queue.local.LocalPoolBackend` with the ``spawn`` start method, so
nothing of the server (its event loop, sockets or signal handlers) is inherited. ``pyceres``
is imported here, never in the server process (../shared/PYCERES_NOTES.md).
"""

from __future__ import annotations

import logging
import os
import signal
import socket
from dataclasses import dataclass
from typing import Any

from service.execution import SHUTDOWN, RunLimits, run_claimed_job
from solver.raster_gate import lock_down_process

log = logging.getLogger("pba.worker")


@dataclass(frozen=True)
class WorkerConfig:
    """Everything a worker needs, picklable."""

    database_url: str
    parent_pid: int
    poll_interval_s: float
    limits: RunLimits
    log_level: str = "INFO"
    log_format: str = "json"
    max_running_per_user: int = 0  # PBA_MAX_RUNNING_PER_USER (service.store.fair)
    small_only: bool = False  # a worker reserved for the small-job lane (PBA_SMALL_JOB_WORKERS)


def worker_id(pid: int | None = None) -> str:
    """The name a worker writes into the jobs it runs: ``host:pid``."""
    return f"{socket.gethostname()}:{pid if pid is not None else os.getpid()}"


def warm_up() -> None:
    """Import the solver (and pyceres) before the first job, so its latency is not paid then.
    Kernels missing from the installation's cache compile here, before the worker takes a job,
    and the log says so (a minute or more)."""
    import solver.api  # noqa: F401

    try:
        import solver.adjust  # noqa: F401
        from solver.kernels.cache import compile_notices

        said: list[str] = []

        def say(message: str) -> None:
            said.append(message)
            log.warning(message)

        with compile_notices(say):
            import solver.kernels.lines  # noqa: F401  (loaded lazily by a solve: here from the disk cache, before the first job)
            from solver.engine import native

            if native.module() is not None:
                from solver.kernels import callbacks

                callbacks.load_all()  # the compiled path's C callbacks (loaded on first use otherwise)
        if said:  # a cold cache (no warm-up at installation): every other kernel now, not in the first jobs
            from solver.warmup import compile_kernels

            compile_kernels(say=log.warning)
    except (ImportError, RuntimeError) as exc:  # RuntimeError: PBA_EVALUATION=compiled without the extension
        log.warning("solver engine not importable yet: %s", exc)


def worker_main(cfg: WorkerConfig, stop: Any, wake: Any, ready: Any = None) -> None:
    """Process entry point: loop until ``stop`` is set or the server process is gone.
    ``ready`` (an event, optional) is set once the solver is loaded and its kernels compiled:
    the server's ``/readyz`` counts the workers that set it."""
    from service.logs import configure_logging
    from service.store import open_store

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the server, which stops us
    lock_down_process()  # rasters only inside a job's space (solver.raster_gate)
    configure_logging(cfg.log_level, cfg.log_format)
    me = worker_id()
    store = open_store(cfg.database_url, create=False)
    warm_up()
    if ready is not None:
        ready.set()
    log.info("worker ready", extra={"worker": me})

    def stop_reason() -> str | None:
        if stop.is_set() or os.getppid() != cfg.parent_pid:
            return SHUTDOWN
        return None

    try:
        while stop_reason() is None:
            try:
                job = store.claim_next(me, cfg.max_running_per_user, small_only=cfg.small_only)
            except Exception:
                log.exception("could not claim a job", extra={"worker": me})
                stop.wait(1.0)
                continue
            if job is None:
                if wake.wait(cfg.poll_interval_s):
                    wake.clear()
                continue
            log.info("claimed job", extra={"worker": me, "job_id": job.id})
            run_claimed_job(store, job, me, cfg.limits, stop_reason)
    finally:
        store.close()
        log.info("worker stopped", extra={"worker": me})
