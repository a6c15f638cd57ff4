"""Retention: deleting finished jobs past ``PBA_JOB_RETENTION_DAYS`` and the per-user
storage quota (``PBA_USER_STORAGE_QUOTA_MB``); README "Retention".

* :func:`prune` deletes successful, failed and dismissed jobs that finished more than the
  given number of days ago, with their inputs and reports; accepted and running jobs are
  never deleted. The server runs it every ``PBA_RETENTION_INTERVAL_S`` (:class:`RetentionLoop`)
  and ``pba db prune`` runs it by hand.
* :func:`check_quota` refuses a submission (413 ``storage-quota-exceeded``) when the user's
  stored jobs plus this job's inputs would exceed the quota; nothing is deleted on the user's
  behalf (deleting a finished job, ``DELETE /jobs/{id}``, frees its space).
"""

from __future__ import annotations

import json
import logging
import threading
from datetime import datetime, timedelta, timezone
from typing import Any

from service.errors import StorageQuotaExceeded
from service.store import PrunedJob, Store, UserRecord
from service.store.payloads import pack

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


def check_quota(store: Store, user: UserRecord, document: dict[str, Any], quota_mb: float) -> None:
    """StorageQuotaExceeded when storing ``document`` would take ``user`` over ``quota_mb``
    (0: no quota). The measure is the compressed size the store keeps."""
    if quota_mb <= 0:
        return
    used = store.storage_used(user.id)
    need = len(pack(json.dumps(document)))
    if used + need > quota_mb * MB:
        raise StorageQuotaExceeded(
            f"your jobs store {used / MB:.1f} MB and this job's inputs {need / MB:.1f} MB; "
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
