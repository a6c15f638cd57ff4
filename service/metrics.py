"""Prometheus metrics, read from the store at scrape time so they hold for any queue backend.

* ``pba_jobs{status}``: jobs per status (gauge);
* ``pba_queue_depth``: accepted jobs waiting for a worker;
* ``pba_workers``: workers able to take jobs (this server's backend);
* ``pba_solve_duration_seconds{status}``: start-to-finish time of solves that finished since
  this server started (histogram fed from the store's finished jobs at each scrape).
"""

from __future__ import annotations

import threading
from datetime import datetime, timezone
from typing import Iterator

from prometheus_client import CollectorRegistry, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily, Metric

from service.queue import QueueBackend
from service.states import JobStatus
from service.store import Store

DURATION_BUCKETS = (0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300, 600, 1800, 3600)


class StoreCollector:
    """Gauges computed from the store at each scrape."""

    def __init__(self, store: Store, backend: QueueBackend) -> None:
        self.store = store
        self.backend = backend

    def collect(self) -> Iterator[Metric]:
        counts = self.store.counts_by_status()
        jobs = GaugeMetricFamily("pba_jobs", "Jobs by status", labels=["status"])
        for status in JobStatus:
            jobs.add_metric([status.value], counts.get(status, 0))
        yield jobs
        yield GaugeMetricFamily(
            "pba_queue_depth",
            "Accepted jobs waiting for a worker",
            value=counts.get(JobStatus.accepted, 0),
        )
        yield GaugeMetricFamily(
            "pba_workers", "Workers able to take jobs", value=self.backend.worker_count()
        )


class Metrics:
    """The registry of one app."""

    def __init__(self, store: Store, backend: QueueBackend) -> None:
        self.store = store
        self.registry = CollectorRegistry()
        self.registry.register(StoreCollector(store, backend))  # type: ignore[arg-type]
        self.durations = Histogram(
            "pba_solve_duration_seconds",
            "Start-to-finish time of solves",
            labelnames=["status"],
            buckets=DURATION_BUCKETS,
            registry=self.registry,
        )
        self._watermark = datetime.now(timezone.utc)
        self._seen: set[str] = set()
        self._lock = threading.Lock()

    def _feed_durations(self) -> None:
        with self._lock:
            runs = self.store.finished_since(self._watermark)
            for run in runs:
                if run.id in self._seen:
                    continue
                self._seen.add(run.id)
                seconds = max(0.0, (run.finished - run.started).total_seconds())
                self.durations.labels(status=run.status.value).observe(seconds)
            if runs:
                newest = max(r.finished for r in runs)
                # keep ids finished at the watermark itself so equal timestamps are not lost
                self._seen = {r.id for r in runs if r.finished == newest}
                self._watermark = newest

    def render(self) -> bytes:
        """The exposition text."""
        self._feed_durations()
        return generate_latest(self.registry)
