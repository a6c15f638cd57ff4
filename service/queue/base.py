"""The queue backend interface: how accepted jobs reach a solver.

The API writes every job to the store first (status ``accepted``) and then calls
:meth:`QueueBackend.submit`; the store is the source of truth, so a backend may lose a
notification without losing a job (local workers poll the store; a Celery backend re-sends
accepted jobs). Progress, results and cancellation go through the store as well, which is
what lets a distributed backend (issue 8) replace the local pool without API changes.
"""

from __future__ import annotations

from typing import Protocol


class QueueBackend(Protocol):
    """What the API needs from a queue."""

    name: str

    def start(self) -> None:
        """Start consuming (called once, at server start-up, after the store is ready)."""

    def stop(self) -> None:
        """Stop; a job being solved is handed back to the queue (called at shutdown)."""

    def submit(self, job_id: str) -> None:
        """A job was stored as accepted: get it solved."""

    def cancel(self, job_id: str) -> None:
        """The store's cancel flag of a running job was set: make the holder notice soon."""

    def ready(self) -> tuple[bool, str]:
        """(ready, explanation) for ``/readyz``."""

    def worker_count(self) -> int:
        """Workers currently able to take jobs (for metrics)."""
