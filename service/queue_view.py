"""Where an accepted job stands: its position among the waiting jobs in the fair-share order
(service.store.fair.queue_order) and an estimated start time.

The estimate assumes every solve takes the mean duration of the last
:data:`RECENT_RUNS` finished solves (started to finished, cancelled ones included): each running job is expected to
end at its start plus that mean (now at the earliest), each free worker takes the next job in
the order. Without any finished solve, or without a worker, there is no estimate.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

from service.store import Store
from service.store.fair import queue_order

RECENT_RUNS = 50


@dataclass(frozen=True)
class Placement:
    """``position``: 1 for the job the next free worker takes; ``estimated_start``: UTC."""

    position: int
    estimated_start: datetime | None


def mean_solve_s(store: Store) -> float | None:
    """Mean start-to-finish seconds of the last :data:`RECENT_RUNS` solves."""
    runs = store.recent_runs(RECENT_RUNS)
    if not runs:
        return None
    return sum(max(0.0, (r.finished - r.started).total_seconds()) for r in runs) / len(runs)


def placement(
    store: Store, job_id: str, workers: int, max_running_per_user: int = 0
) -> Placement | None:
    """The placement of an accepted job, or None when it is not waiting."""
    waiting, loads, running = store.queue_snapshot(max_running_per_user)
    order = queue_order(waiting, loads)
    if job_id not in order:
        return None
    position = order.index(job_id) + 1
    mean = mean_solve_s(store)
    if mean is None or workers <= 0:
        return Placement(position, None)
    now = datetime.now(timezone.utc)
    free = sorted(max(now, (j.started or now) + timedelta(seconds=mean)) for j in running)
    free = free[:workers] + [now] * max(0, workers - len(free))
    heapq.heapify(free)
    start = now
    for _ in range(position):
        start = heapq.heappop(free)
        heapq.heappush(free, start + timedelta(seconds=mean))
    return Placement(position, start)
