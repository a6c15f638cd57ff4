"""The Celery side of the distributed queue (``PBA_QUEUE=celery``): the app, its one task, and
``pba worker``.

Messages carry only a job id; the store holds everything else (inputs, status, progress,
cancel flag, report), so any worker that reaches the broker and the database can run any job.
A message is a wake-up token: the run that receives it takes over an orphaned job if there is
one, else claims the job the fair-share policy picks (:func:`service.store.leases.
claim_for_message`; docs/how-to/lab-server.md "Fair sharing"), which need not be the job the message names.

* **Delivery**: ``acks_late`` + ``reject_on_worker_lost``: a message is acknowledged when its
  run ends; if the pool process dies (``kill -9``, SIGSEGV, glog FATAL in a solve) Celery puts
  the message back at once, and if the whole worker vanishes Redis hands it out again after
  ``PBA_BROKER_VISIBILITY_TIMEOUT_S``. Prefetch is one message per pool process.
* **Exactly one completion**: a run claims the job in the store under a fresh fencing token
  and renews a lease while it solves (:mod:`service.store.leases`). A redelivered message
  takes the job over only when its holder is known dead or its lease expired; a duplicate of a
  job held by a live run is dropped. Every write is conditioned on the token, so a run that
  lost its job can no longer change it. Sweepers (here and in the API server) re-queue jobs
  whose lease expired, so a job is never left running by a worker that is gone.
* **Isolation**: solves run in Celery's prefork pool processes (``pyceres`` is imported there,
  never in the worker's main process); a native crash kills one pool process, which Celery
  replaces, and that job is re-run up to ``PBA_MAX_ATTEMPTS`` times in all, then failed.
* **Progress, cancellation, time limit**: the solver's hooks write progress to the store and
  poll its cancel flag (:mod:`service.execution`), so ``DELETE /jobs/{id}`` stops a solve
  within one iteration on whichever worker holds it. ``PBA_JOB_TIME_LIMIT_S`` stops a solve
  through the same hook; Celery's hard time limit kills the pool process
  ``PBA_KILL_GRACE_S`` later if the solve does not stop, and the sweeper fails the job.
* **Shutdown**: a warm shutdown (SIGTERM) stops running solves at their next iteration, puts
  their jobs back to ``accepted`` in the store (the run is not counted as an attempt) and
  rejects their messages with requeue, so the broker hands the same message to another worker.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import socket
import threading
import time
from typing import Any

from celery import Celery, signals
from celery.exceptions import Reject

from service.settings import Settings

log = logging.getLogger("pba.worker")

TASK_NAME = "pba.run_job"
READY_MESSAGE = "worker process ready"
STORE_RETRY_S = 5.0


class StoreUnavailable(RuntimeError):
    """The store could not be reached before a run claimed its job (the message is retried)."""


def broker_transport_options(settings: Settings) -> dict[str, Any]:
    """Redis transport options: visibility timeout and key prefix."""
    options: dict[str, Any] = {"visibility_timeout": settings.broker_visibility_timeout_s}
    if settings.broker_key_prefix:
        options["global_keyprefix"] = settings.broker_key_prefix
    return options


def check_settings(settings: Settings) -> None:
    """Refuse lease settings under which live runs would lose their jobs."""
    if settings.heartbeat_interval_s * 2 > settings.lease_s:
        raise ValueError(
            f"PBA_LEASE_S ({settings.lease_s:g}) must be at least twice "
            f"PBA_HEARTBEAT_INTERVAL_S ({settings.heartbeat_interval_s:g})"
        )


def create_celery(settings: Settings) -> Celery:
    """The Celery app for these settings, with the job task registered."""
    check_settings(settings)
    app = Celery("pba", set_as_current=False)
    app.conf.update(
        broker_url=settings.broker_url,
        broker_transport_options=broker_transport_options(settings),
        broker_connection_retry_on_startup=True,
        result_backend=None,
        task_ignore_result=True,
        task_serializer="json",
        accept_content=["json"],
        task_default_queue=settings.celery_queue,
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        task_acks_on_failure_or_timeout=True,
        task_time_limit=settings.job_time_limit_s + settings.kill_grace_s,
        worker_prefetch_multiplier=1,
        worker_hijack_root_logger=False,
        worker_redirect_stdouts=False,
        worker_proc_alive_timeout=120.0,  # pool processes import the solver when they start
        worker_send_task_events=False,
        enable_utc=True,
    )

    @app.task(name=TASK_NAME, bind=True, ignore_result=True)
    def run_job(self: Any, job_id: str) -> str:
        """Run one job (in a pool process)."""
        try:
            return execute_job(job_id)
        except StoreUnavailable as exc:  # keep the message: try again when the store answers
            raise self.retry(exc=exc, countdown=STORE_RETRY_S, max_retries=None) from None

    return app


def publish(app: Celery, settings: Settings, job_id: str, small: bool = False) -> None:
    """Send a job's message to the queue, and a small-lane job's also to the small-job lane's
    queue (``PBA_CELERY_SMALL_QUEUE``, read by ``pba worker --small-lane``): messages are wake-up
    tokens, so every accepted job keeps one in the general queue whichever worker runs it.
    Raises when the broker cannot be reached."""
    for queue in (settings.celery_queue, settings.celery_small_queue) if small else (settings.celery_queue,):
        app.send_task(
            TASK_NAME,
            args=[job_id],
            queue=queue,
            retry=True,
            retry_policy={"max_retries": 3, "interval_start": 0.2, "interval_step": 0.5},
        )


# -- worker side ------------------------------------------------------------------------------
class _Runtime:
    """Per-process state of a ``pba worker``: settings, the shutdown flag shared with the pool
    processes (forked from the main process), and each pool process's store."""

    settings: Settings | None = None
    shutdown: Any = None  # multiprocessing Event, created before the pool forks
    main_pid: int = 0
    store: Any = None
    small_only: bool = False  # pba worker --small-lane: claims only small-lane jobs


RT = _Runtime()


def _store() -> Any:
    if RT.store is None:
        from service.store import open_store

        assert RT.settings is not None
        RT.store = open_store(RT.settings.resolved_database_url, create=False)
    return RT.store


class _Heartbeat(threading.Thread):
    """Renews a run's lease every ``interval_s``; sets :attr:`lost` when the store says the
    run no longer holds the job."""

    def __init__(self, store: Any, job_id: str, token: str, interval_s: float) -> None:
        super().__init__(name="pba-heartbeat", daemon=True)
        self.store, self.job_id, self.token, self.interval_s = store, job_id, token, interval_s
        self.lost = False
        self._halt = threading.Event()

    def run(self) -> None:
        from service.store.leases import renew

        while not self._halt.wait(self.interval_s):
            try:
                if not renew(self.store, self.job_id, self.token):
                    self.lost = True
                    return
            except Exception:  # the database is unreachable: keep trying; the lease decides
                log.warning("could not renew the lease", extra={"job_id": self.job_id})

    def stop(self) -> None:
        self._halt.set()
        self.join(timeout=5)


def execute_job(job_id: str) -> str:
    """Claim and run one job in this pool process; returns what happened (for the logs).

    Raises :class:`celery.exceptions.Reject` (requeue) when the run was handed back at
    shutdown."""
    from service.execution import SHUTDOWN, RunLimits, run_claimed_job
    from service.states import JobStatus
    from service.store.leases import claim_for_message, run_token

    settings = RT.settings
    assert settings is not None, "execute_job runs in a pba worker"
    store = _store()
    token = run_token()
    extra = {"job_id": job_id, "worker": token}
    try:
        claim = claim_for_message(
            store,
            job_id,
            token,
            settings.lease_s,
            settings.max_attempts,
            settings.max_running_per_user,
            small_only=RT.small_only,
        )
    except Exception as exc:
        log.warning("could not claim the job: %s", exc, extra=extra)
        raise StoreUnavailable(str(exc)) from exc
    if claim.outcome == "contended":
        raise StoreUnavailable("every claim lost a race with other workers")
    if not claim.runnable:
        log.info("message dropped: job %s", claim.outcome, extra={**extra, "status": claim.outcome})
        return claim.outcome
    assert claim.job is not None
    job_id = claim.job.id  # the message is a wake-up token: the policy chose the job
    extra = {"job_id": job_id, "worker": token}
    log.info(
        "claimed job (%s, run %d)",
        claim.outcome,
        claim.job.attempts,
        extra={**extra, "status": claim.outcome},
    )
    beat = _Heartbeat(store, job_id, token, settings.heartbeat_interval_s)
    beat.start()

    def stop_reason() -> str | None:
        if beat.lost:
            return SHUTDOWN  # fenced out: our writes are refused anyway
        if RT.shutdown is not None and RT.shutdown.is_set():
            return SHUTDOWN
        if RT.main_pid and os.getppid() != RT.main_pid:
            return SHUTDOWN  # the worker's main process is gone
        return None

    limits = RunLimits(
        job_time_limit_s=settings.job_time_limit_s,
        progress_interval_s=settings.progress_interval_s,
        cancel_poll_interval_s=settings.cancel_poll_interval_s,
    )
    try:
        status = run_claimed_job(store, claim.job, token, limits, stop_reason)
    finally:
        beat.stop()
    if status is not None:
        log.info("run ended: %s", status.value, extra={**extra, "status": status.value})
        return status.value
    rec = store.get_job(job_id)
    if rec is not None and rec.status == JobStatus.accepted:
        # Handed back at shutdown: the broker puts this very message back at the head of the
        # queue, so another worker takes it. Publishing a new message instead would lose the
        # job if this worker died between acknowledging the old one and sending the new one;
        # a rejected message that never reaches Redis is restored by its visibility timeout.
        # Checked before ``beat.lost``: the heartbeat may fire between the hand-back and its
        # stop and find the job no longer ours, and acknowledging the message then would leave
        # an accepted job without one. (If the sweeper re-queued it after a lost lease and sent
        # a message of its own, the extra wake-up message is dropped when nothing waits.)
        log.info("run handed back to the queue", extra={**extra, "status": "requeued"})
        raise Reject("handed back at shutdown", requeue=True)
    if beat.lost:
        log.warning(
            "run stopped: the job was taken from this run", extra={**extra, "status": "lost"}
        )
        return "lost"
    log.info("run ended without a result of its own", extra={**extra, "status": "none"})
    return "none"


def _on_process_init(**_: Any) -> None:
    """In each pool process: logging, a store of its own, and the solver imported."""
    from service.logs import configure_logging
    from service.queue.worker import warm_up
    from solver.raster_gate import lock_down_process

    assert RT.settings is not None
    lock_down_process()  # rasters only inside a job's space (solver.raster_gate)
    configure_logging(RT.settings.log_level, RT.settings.log_format)
    RT.store = None  # never use a connection pool inherited from the main process
    _store()
    warm_up()
    log.info(READY_MESSAGE, extra={"worker": f"{socket.gethostname()}:{os.getpid()}"})


class _Sweeper(threading.Thread):
    """Re-queues (and re-sends) jobs whose lease expired, every ``sweep_interval_s``."""

    def __init__(self, app: Celery, settings: Settings, store: Any) -> None:
        super().__init__(name="pba-sweeper", daemon=True)
        self.app, self.settings, self.store = app, settings, store
        self._halt = threading.Event()
        self.unsent: set[str] = set()

    def run(self) -> None:
        while not self._halt.wait(self.settings.sweep_interval_s):
            try:
                sweep(self.app, self.settings, self.store, self.unsent)
            except Exception:
                log.exception("lease sweep failed")

    def stop(self) -> None:
        self._halt.set()


def sweep(app: Celery, settings: Settings, store: Any, unsent: set[str] | None = None) -> list[Any]:
    """One pass of the lease sweeper; the jobs it changed. Jobs it re-queued but could not
    send (broker down) are added to ``unsent``, and those in ``unsent`` still accepted are
    sent again."""
    from service.store.leases import expire_leases

    unsent = unsent if unsent is not None else set()
    expired = expire_leases(
        store, settings.lease_s, settings.max_attempts, settings.job_time_limit_s
    )
    for e in expired:
        log.warning("lease of %s expired: job %s", e.holder, e.action, extra={"job_id": e.job_id})
        if e.action == "requeued":
            unsent.add(e.job_id)
    for job_id in sorted(unsent):
        rec = store.get_job(job_id)
        if rec is None or rec.status.value != "accepted":
            unsent.discard(job_id)
            continue
        try:
            publish(app, settings, job_id)
            unsent.discard(job_id)
        except Exception as exc:
            log.error(
                "could not send a re-queued job (%s); will retry", exc, extra={"job_id": job_id}
            )
    return expired


def open_main_store(url: str) -> Any:
    """A store for a worker's main process: migrated to head, and holding no connection
    between uses (the pool processes are forked from this process)."""
    from sqlalchemy import create_engine
    from sqlalchemy.pool import NullPool

    from service.store.sql import SqlStore

    store = SqlStore(url, create=True)
    if store.engine.dialect.name != "sqlite":  # SQLite engines use NullPool already
        store.engine.dispose()
        store.engine = create_engine(url, poolclass=NullPool)
    return store


def worker_main(
    settings: Settings, concurrency: int | None = None, node: str | None = None, small_lane: bool = False
) -> int:
    """``pba worker``: run a Celery worker (prefork pool) until SIGTERM/SIGINT; with
    ``small_lane`` it reads the small-job lane's queue and claims only small-lane jobs."""
    from service.logs import configure_logging

    configure_logging(settings.log_level, settings.log_format)
    concurrency = concurrency or settings.worker_concurrency or (os.cpu_count() or 1)
    RT.settings = settings
    RT.main_pid = os.getpid()
    RT.small_only = small_lane
    queue = settings.celery_small_queue if small_lane else settings.celery_queue
    RT.shutdown = mp.get_context("fork").Event()
    for attempt in range(30):  # the database may still be starting (docker compose up)
        try:
            store = open_main_store(settings.resolved_database_url)
            break
        except Exception as exc:
            if attempt == 29:
                raise
            log.warning("database not reachable yet (%s); retrying", type(exc).__name__)
            time.sleep(2)
    app = create_celery(settings)
    sweeper = _Sweeper(app, settings, store)

    def on_ready(**_: Any) -> None:
        sweeper.start()
        log.info(
            "pba worker ready: queue %s, %d pool processes", queue, concurrency
        )

    def on_shutdown(**_: Any) -> None:
        RT.shutdown.set()
        sweeper.stop()

    signals.worker_process_init.connect(_on_process_init, weak=False)
    signals.worker_ready.connect(on_ready, weak=False)
    signals.worker_shutting_down.connect(on_shutdown, weak=False)
    node = node or f"pba-{os.getpid()}@{socket.gethostname()}"
    argv = [
        "worker",
        "--pool=prefork",
        f"--concurrency={concurrency}",
        f"--queues={queue}",
        f"--hostname={node}",
        f"--loglevel={settings.log_level.upper()}",
        "--without-mingle",
        "--without-gossip",
    ]
    try:
        app.worker_main(argv)
    finally:
        sweeper.stop()
        store.close()
    return 0


def ping_local_workers(settings: Settings, timeout_s: float = 5.0) -> list[str]:
    """Celery nodes of this host that answer a ping through the broker (health check)."""
    app = create_celery(settings)
    try:
        replies = app.control.ping(timeout=timeout_s) or []
    finally:
        app.close()
    host = socket.gethostname()
    return sorted(n for reply in replies for n in reply if n.endswith(f"@{host}"))
