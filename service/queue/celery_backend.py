"""The distributed queue backend (``PBA_QUEUE=celery``): the API server's side.

The server only publishes job ids to the broker (Redis); ``pba worker`` processes on any
machine that reaches the broker and the database run them (:mod:`service.queue.celery_app`, where
delivery, leases and crash handling are described). This side:

* ``submit`` sends the job's message; a message that cannot be sent (broker down) is kept and
  sent again by the monitor thread - the job is already safe in the store;
* at start-up, re-sends every accepted job (a message lost with a Redis that kept nothing on
  disk, or a server that stopped between storing and sending); a duplicate is harmless, the
  store's claim takes each job once. Unlike the local pool it never re-queues running jobs at
  start-up: they belong to workers that may well be alive; their leases decide;
* a monitor thread sweeps expired leases (as every worker does) and counts the workers'
  pool processes (Celery's ``inspect stats``) for ``/readyz`` and ``pba_workers``;
* ``cancel`` needs nothing: the holder polls the store's cancel flag.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from service.settings import Settings
from service.store import Store

log = logging.getLogger("pba.queue")

MONITOR_INTERVAL_S = 3.0
INSPECT_TIMEOUT_S = 1.0


class CeleryBackend:
    """Publishes jobs to Celery workers (see module docstring)."""

    name = "celery"

    def __init__(self, settings: Settings, store: Store) -> None:
        from service.queue.celery_app import create_celery

        self.settings = settings
        self.store = store
        self.app = create_celery(settings)
        self._workers = 0
        self._nodes: list[str] = []
        self._broker_ok: bool | None = None
        self._broker_error = ""
        self._unsent: set[str] = set()
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._last_sweep = 0.0

    # -- QueueBackend ----------------------------------------------------------------------
    def start(self) -> None:
        """Re-send accepted jobs, then start the monitor thread."""
        from service.store.leases import accepted_job_ids

        pending = accepted_job_ids(self.store)  # type: ignore[arg-type]
        for job_id in pending:
            self.submit(job_id)
        if pending:
            log.info("re-sent %d accepted jobs to the broker", len(pending))
        self._thread = threading.Thread(
            target=self._monitor, name="pba-celery-monitor", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        """Stop the monitor (running jobs stay with their workers)."""
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(timeout=INSPECT_TIMEOUT_S + 5)
        try:
            self.app.close()
        except Exception:
            pass

    def submit(self, job_id: str) -> None:
        """Publish the job's message (kept for a later try when the broker is unreachable)."""
        from service.queue.celery_app import publish

        rec = self.store.get_job(job_id)
        try:
            publish(self.app, self.settings, job_id, small=bool(rec and rec.small))
        except Exception as exc:
            with self._lock:
                self._unsent.add(job_id)
            self._broker_ok, self._broker_error = False, type(exc).__name__
            log.error(
                "could not send the job to the broker (%s); will retry",
                exc,
                extra={"job_id": job_id},
            )

    def cancel(self, job_id: str) -> None:
        """Nothing to do: the worker holding the job polls the store's cancel flag."""

    def ready(self) -> tuple[bool, str]:
        """Ready when the broker answers (workers may come and go; jobs wait in the queue)."""
        if self._broker_ok is None:
            return False, "checking the broker"
        if not self._broker_ok:
            return False, f"broker unreachable ({self._broker_error})"
        return True, (
            f"celery: broker ok, {self._workers} worker processes on {len(self._nodes)} workers"
        )

    def worker_count(self) -> int:
        """Pool processes of the workers that answered the last inspection."""
        return self._workers

    # -- monitor ---------------------------------------------------------------------------
    def _check(self) -> None:
        """Ask the workers for their statistics (also proves the broker answers)."""
        try:
            stats = self.app.control.inspect(timeout=INSPECT_TIMEOUT_S).stats() or {}
        except Exception as exc:
            self._broker_ok, self._broker_error = False, type(exc).__name__
            self._workers, self._nodes = 0, []
            return
        self._broker_ok, self._broker_error = True, ""
        self._nodes = sorted(stats)
        self._workers = sum(
            int((s.get("pool") or {}).get("max-concurrency") or 0) for s in stats.values()
        )

    def _monitor(self) -> None:
        from service.queue.celery_app import sweep

        while not self._stopping.is_set():
            self._check()
            with self._lock:
                unsent, self._unsent = self._unsent, set()
            for job_id in sorted(unsent):
                rec = self.store.get_job(job_id)
                if rec is not None and rec.status.value == "accepted":
                    self.submit(job_id)
            now = time.monotonic()
            if self._broker_ok and now - self._last_sweep >= self.settings.sweep_interval_s:
                self._last_sweep = now
                with self._lock:
                    unsent, self._unsent = self._unsent, set()
                try:
                    sweep(self.app, self.settings, self.store, unsent)
                except Exception:
                    log.exception("lease sweep failed")
                finally:
                    with self._lock:
                        self._unsent |= unsent
            self._stopping.wait(MONITOR_INTERVAL_S)

    def describe(self) -> dict[str, Any]:
        """For diagnostics: broker state, workers, unsent messages."""
        return {
            "broker_ok": self._broker_ok,
            "workers": self._workers,
            "nodes": list(self._nodes),
            "unsent": len(self._unsent),
        }
