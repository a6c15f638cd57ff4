"""Which queue lane a job takes, from what it will cost (:class:`service.processes.JobCost`).

The small-job lane (service.store.fair; docs/server-limits.md "Lanes by cost") is for jobs a
worker finishes in moments: adjustments (and pre-analyses) of at most
``PBA_SMALL_JOB_OBSERVATIONS`` observations. A matching's work grows with its rasters' pixels,
not with the job's observations (a composed job may have none), so a job costed in pixels never
takes the lane, however few observations it has. Whether the client waits for the answer
(synchronous execution) does not change the lane: a large synchronous job would otherwise hold
the workers kept for small ones.

The same cost gives the job's ``share``: what it counts for in its user's fair share while it
runs (service.store.fair, the weighted share), in small jobs' worth: its observations over
``PBA_SMALL_JOB_OBSERVATIONS``, or its pixels over :data:`PIXELS_PER_OBSERVATION` times that,
and at least 1. A user running one matching of two 10,000 x 10,000 rasters counts as running
200 small jobs, so another user's jobs are not held back by it as by one job.
"""

from __future__ import annotations

from service.processes import JobCost

PIXELS_PER_OBSERVATION = 200
"""Pixels a matching works through in the time an adjustment takes per observation: an
adjustment costs about 40 microseconds per observation end to end (docs/benchmarks.md), a
matching 0.1 to 1 microsecond per pixel (docs/matching.md: a pair of 2 x 10^8 pixels in about
200 s with an eighth of a core). An order of magnitude, for the fair share only."""


def share_of(cost: JobCost, small_job_observations: int) -> float:
    """What a job of ``cost`` counts for in its user's share while it runs (at least 1)."""
    unit = max(1, small_job_observations)
    observations = cost.amount if cost.unit == "observations" else cost.amount / PIXELS_PER_OBSERVATION
    return max(1.0, observations / unit)


def is_small(cost: JobCost, small_job_observations: int) -> bool:
    """True when a job of ``cost`` takes the small-job lane."""
    return cost.unit == "observations" and cost.amount <= small_job_observations
