"""Prometheus metrics, computed from the store at scrape time so they hold for any queue
backend and agree between API processes and across restarts.

* ``pba_jobs{status}``: jobs per status (gauge);
* ``pba_queue_depth``: accepted jobs waiting for a worker;
* ``pba_workers``: workers able to take jobs (this server's backend);
* ``pba_solve_duration_seconds{status}``: start-to-finish time (seconds) of every finished
  solve the store holds (histogram built from the store's finished jobs at each scrape; it
  shrinks when jobs are deleted from the store, which Prometheus reads as a counter reset);
* ``pba_user_jobs_total{user,status}``, ``pba_user_cpu_seconds_total{user}``,
  ``pba_user_solve_seconds_total{user}``: the per-user accounting of finished runs
  (``user_usage``, kept when jobs are pruned; docs/how-to/lab-server.md "Fair sharing");
* ``pba_user_active_jobs{user,status}``: each user's accepted and running jobs now.
"""

from __future__ import annotations

import bisect
from datetime import datetime, timezone
from typing import Iterator

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    Metric,
)

from service.queue import QueueBackend
from service.states import JobStatus
from service.store import FinishedRun, Store

DURATION_BUCKETS = (0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300, 600, 1800, 3600)
EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)


def duration_histogram(runs: list[FinishedRun]) -> HistogramMetricFamily:
    """The solve-duration histogram of ``runs``, one series per final status (cumulative
    buckets in seconds, ``+Inf`` last, as the exposition format wants)."""
    family = HistogramMetricFamily(
        "pba_solve_duration_seconds", "Start-to-finish time of solves", labels=["status"]
    )
    by_status: dict[str, list[float]] = {}
    for run in runs:
        seconds = max(0.0, (run.finished - run.started).total_seconds())
        by_status.setdefault(run.status.value, []).append(seconds)
    for status, durations in sorted(by_status.items()):
        durations.sort()
        buckets = [
            (f"{bound:g}", bisect.bisect_right(durations, bound)) for bound in DURATION_BUCKETS
        ]
        buckets.append(("+Inf", len(durations)))
        family.add_metric([status], buckets, sum_value=sum(durations))
    return family


class StoreCollector:
    """Every metric, computed from the store at each scrape."""

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
        yield duration_histogram(self.store.finished_since(EPOCH))
        yield from user_metrics(self.store)


def user_metrics(store: Store) -> Iterator[Metric]:
    """The per-user accounting and load (see module docstring)."""
    names = {u.id: u.name for u in store.list_users()}
    jobs = CounterMetricFamily(
        "pba_user_jobs", "Finished runs per user and outcome", labels=["user", "status"]
    )
    cpu = CounterMetricFamily(
        "pba_user_cpu_seconds", "CPU seconds of the solving processes per user", labels=["user"]
    )
    solve = CounterMetricFamily(
        "pba_user_solve_seconds", "Wall seconds of solves per user", labels=["user"]
    )
    for u in store.usage():
        jobs.add_metric([u.name, JobStatus.successful.value], u.jobs_successful)
        jobs.add_metric([u.name, JobStatus.failed.value], u.jobs_failed)
        jobs.add_metric([u.name, JobStatus.dismissed.value], u.jobs_dismissed)
        cpu.add_metric([u.name], u.cpu_s)
        solve.add_metric([u.name], u.solve_s)
    active = GaugeMetricFamily(
        "pba_user_active_jobs", "Accepted and running jobs per user now", labels=["user", "status"]
    )
    for owner, (waiting, running) in sorted(store.active_by_owner().items()):
        name = names.get(owner, owner)
        active.add_metric([name, JobStatus.accepted.value], waiting)
        active.add_metric([name, JobStatus.running.value], running)
    yield from (jobs, cpu, solve, active)


class Metrics:
    """The registry of one app."""

    def __init__(self, store: Store, backend: QueueBackend) -> None:
        self.store = store
        self.registry = CollectorRegistry()
        self.registry.register(StoreCollector(store, backend))  # type: ignore[arg-type]

    def render(self) -> bytes:
        """The exposition text."""
        return generate_latest(self.registry)
