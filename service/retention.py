"""Retention: deleting finished jobs past ``PBA_JOB_RETENTION_DAYS`` and the per-user
storage quota (``PBA_USER_STORAGE_QUOTA_MB``); docs/how-to/lab-server.md "Retention".

* :func:`prune` deletes successful, failed and dismissed jobs that finished more than the
  given number of days ago, with their inputs and reports; accepted and running jobs are
  never deleted. The server runs it every ``PBA_RETENTION_INTERVAL_S`` (:class:`RetentionLoop`)
  and ``pba db prune`` runs it by hand.
* the quota: the store refuses a job or camera version (:class:`service.store.QuotaExceeded`,
  checked in the inserting transaction, :func:`quota_bytes`) when the user's stored jobs and
  camera versions plus the new one would exceed it; :func:`quota_error` is the 413
  ``storage-quota-exceeded`` problem. Nothing is deleted on the user's behalf (deleting a
  finished job, ``DELETE /jobs/{id}``, frees its space).
"""

from __future__ import annotations

import logging
import threading
from datetime import datetime, timedelta, timezone

from service.errors import StorageQuotaExceeded
from service.store import PrunedJob, QuotaExceeded, Store

log = logging.getLogger("pba.service")

MB = 1_000_000  # bytes in the quota's megabyte


def prune(
    store: Store, older_than_days: float, dry_run: bool = False, now: datetime | None = None
) -> list[PrunedJob]:
    """Delete (or with ``dry_run`` only list) finished jobs that finished more than
    ``older_than_days`` days before ``now`` (default: the current UTC time)."""
    if older_than_days < 0:
        raise ValueError("older_than_days must be >= 0")
    cutoff = (now or datetime.now(timezone.utc)) - timedelta(days=older_than_days)
    return store.prune_jobs(cutoff, dry_run=dry_run)


def quota_bytes(quota_mb: float) -> int:
    """The quota in bytes for the store (0: no quota)."""
    return int(quota_mb * MB) if quota_mb > 0 else 0


def quota_error(exc: QuotaExceeded, quota_mb: float) -> StorageQuotaExceeded:
    """The 413 problem of a write the quota refused."""
    return StorageQuotaExceeded(
        f"your jobs and cameras store {exc.used / MB:.1f} MB and this one {exc.need / MB:.1f} MB; "
        f"the quota is {quota_mb:g} MB per user. Delete finished jobs you no longer need "
        "(DELETE /jobs/{jobId}) or ask an admin"
    )


class RetentionLoop:
    """A daemon thread of the API server that prunes every ``interval_s`` seconds (first
    right after start-up)."""

    def __init__(self, store: Store, retention_days: float, interval_s: float) -> None:
        self.store = store
        self.retention_days = retention_days
        self.interval_s = interval_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start the thread."""
        self._thread = threading.Thread(target=self._run, name="pba-retention", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread (waits for a prune in progress)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)

    def run_once(self) -> list[PrunedJob]:
        """One pruning pass, logged."""
        pruned = prune(self.store, self.retention_days)
        if pruned:
            log.info(
                "retention: deleted %d finished jobs older than %g days (%.1f MB)",
                len(pruned),
                self.retention_days,
                sum(p.stored_bytes for p in pruned) / MB,
            )
        return pruned

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.run_once()
            except Exception:  # a database hiccup must not end the loop
                log.exception("retention pass failed")
            self._stop.wait(self.interval_s)
