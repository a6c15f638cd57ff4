"""Which queue lane a job takes, from what it will cost (:class:`service.processes.JobCost`).

The small-job lane (service.store.fair; docs/server-limits.md "Lanes by cost") is for jobs a
worker finishes in moments: adjustments (and pre-analyses) of at most
``PBA_SMALL_JOB_OBSERVATIONS`` observations. A matching's work grows with its rasters' pixels,
not with the job's observations (a composed job may have none), so a job costed in pixels never
takes the lane, however few observations it has. Whether the client waits for the answer
(synchronous execution) does not change the lane: a large synchronous job would otherwise hold
the workers kept for small ones.
"""

from __future__ import annotations

from service.processes import JobCost


def is_small(cost: JobCost, small_job_observations: int) -> bool:
    """True when a job of ``cost`` takes the small-job lane."""
    return cost.unit == "observations" and cost.amount <= small_job_observations
