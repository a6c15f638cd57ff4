"""Running one claimed job inside a worker process (shared by every queue backend).

:func:`run_claimed_job` loads the stored inputs, calls ``solver.api.run`` (or ``compare``)
with a progress hook that writes throttled, only-increasing progress to the store and a cancel
hook that polls the store's cancel flag (throttled), the job's deadline and the worker's own
stop/orphan conditions. Every write names the worker, so a write from a run the server has
already given up on (re-queued or failed) changes nothing.

This module imports the solver; it must only be imported in worker processes.
"""

from __future__ import annotations

import logging
import math
import time
import traceback
from dataclasses import dataclass
from typing import Any, Callable

from service.problems import problem_entries, pydantic_errors
from service.processes import process
from service.states import FailureCode, JobStatus
from service.store import JobRecord, Store
from solver.report.json_text import report_json

log = logging.getLogger("pba.worker")

USER = "user"
TIME_LIMIT = "time_limit"
SHUTDOWN = "shutdown"


@dataclass(frozen=True)
class RunLimits:
    """Timing knobs of a run (from :class:`service.settings.Settings`)."""

    job_time_limit_s: float
    progress_interval_s: float = 0.5
    cancel_poll_interval_s: float = 0.2


class JobHooks:
    """The progress and cancel callables handed to the solver for one job."""

    def __init__(
        self,
        store: Store,
        job: JobRecord,
        worker: str,
        limits: RunLimits,
        stop_reason: Callable[[], str | None] = lambda: None,
    ) -> None:
        self.store = store
        self.job = job
        self.worker = worker
        self.limits = limits
        self.stop_reason = stop_reason
        self.deadline = time.monotonic() + limits.job_time_limit_s
        self.reason: str | None = None
        self._last_progress_write = 0.0
        self._last_percent = -1
        self._last_cancel_poll = 0.0

    def progress(self, fraction: float, message: str, info: dict[str, Any] | None = None) -> None:
        """Write progress (0-99 while solving) at most every ``progress_interval_s``."""
        if not isinstance(fraction, (int, float)) or not math.isfinite(fraction):
            return
        percent = int(max(0.0, min(0.99, float(fraction))) * 100)
        now = time.monotonic()
        if percent <= self._last_percent and now - self._last_progress_write < 5.0:
            return
        if now - self._last_progress_write < self.limits.progress_interval_s:
            return
        self._last_progress_write = now
        self._last_percent = max(self._last_percent, percent)
        try:
            self.store.set_progress(self.job.id, self.worker, percent, str(message)[:500])
        except Exception:  # progress is best effort; the solve goes on
            log.warning("could not write progress", extra={"job_id": self.job.id}, exc_info=True)

    def cancel(self) -> bool:
        """True when the solve must stop; sets :attr:`reason`."""
        if self.reason is not None:
            return True
        reason = self.stop_reason()
        if reason is None and time.monotonic() > self.deadline:
            reason = TIME_LIMIT
        now = time.monotonic()
        if reason is None and now - self._last_cancel_poll >= self.limits.cancel_poll_interval_s:
            self._last_cancel_poll = now
            try:
                reason = self.store.cancel_requested(self.job.id)
            except Exception:
                log.warning("could not read the cancel flag", extra={"job_id": self.job.id})
        self.reason = reason
        return reason is not None


def solve(document: dict[str, Any], process_id: str, hooks: JobHooks) -> dict[str, Any]:
    """Run the stored document as its process says (service.processes)."""
    return process(process_id).run(document, hooks.progress, hooks.cancel)


def run_claimed_job(
    store: Store,
    job: JobRecord,
    worker: str,
    limits: RunLimits,
    stop_reason: Callable[[], str | None] = lambda: None,
) -> JobStatus | None:
    """Run a job this worker has claimed and record the outcome.

    Returns the final status written, or None when the run was handed back (server stopping)
    or the store no longer lets this worker write (the job was re-queued or failed meanwhile).
    """
    from pydantic import ValidationError

    from solver.errors import Cancelled, JobError, UnusableSolution

    extra = {"job_id": job.id, "worker": worker}
    hooks = JobHooks(store, job, worker, limits, stop_reason)
    document = store.get_document(job.id)
    if document is None:
        ok = store.fail(job.id, "the job's inputs are missing from the store", worker=worker)
        return JobStatus.failed if ok else None
    t0, cpu0 = time.monotonic(), time.process_time()

    def usage() -> tuple[float, float]:
        """(CPU seconds of this process, all threads; wall seconds) since the solve began."""
        return time.process_time() - cpu0, time.monotonic() - t0

    log.info("solve started (attempt %d)", job.attempts, extra=extra)
    try:
        report = solve(document, job.process_id, hooks)
    except Cancelled:
        reason = hooks.reason or USER
        log.info("solve stopped: %s", reason, extra=extra)
        if reason == TIME_LIMIT:
            ok = store.fail(
                job.id,
                f"time limit of {limits.job_time_limit_s:g} s exceeded; the solve was stopped",
                {"code": FailureCode.time_limit},
                worker=worker,
                usage=usage(),
            )
            return JobStatus.failed if ok else None
        if reason == SHUTDOWN:
            store.requeue(job.id, worker, "re-queued: the server stopped during the solve", False)
            return None
        ok = store.finish_cancelled(job.id, worker, "cancelled by the user", usage())
        return JobStatus.dismissed if ok else None
    except JobError as exc:
        problems = exc.to_dict()["problems"]
        ok = store.fail(
            job.id,
            str(exc) if isinstance(exc, UnusableSolution) else f"invalid job: {exc}",
            {"code": exc.code, "errors": problem_entries(problems)},
            worker=worker,
            usage=usage(),
        )
        log.info("solve failed: %s", exc, extra=extra)
        return JobStatus.failed if ok else None
    except ValidationError as exc:
        ok = store.fail(
            job.id,
            "invalid job document",
            {
                "code": "invalid-input",
                "errors": pydantic_errors(exc.errors(), ("inputs", "job")),
            },
            worker=worker,
            usage=usage(),
        )
        return JobStatus.failed if ok else None
    except Exception as exc:  # a bug in the solver: fail the job, keep the worker
        log.error("solve crashed: %s\n%s", exc, traceback.format_exc(), extra=extra)
        ok = store.fail(
            job.id,
            f"internal solver error: {type(exc).__name__}: {exc}",
            {"code": FailureCode.internal},
            worker=worker,
            usage=usage(),
        )
        return JobStatus.failed if ok else None
    spent = usage()
    elapsed = spent[1]
    try:
        text = report_json(report)
    except Exception as exc:
        ok = store.fail(
            job.id,
            f"the report could not be serialized: {exc}",
            {"code": FailureCode.internal},
            worker=worker,
            usage=spent,
        )
        return JobStatus.failed if ok else None
    ok = store.complete(job.id, worker, text, f"finished in {elapsed:.2f} s", spent)
    log.info("solve finished in %.3f s", elapsed, extra=extra)
    return JobStatus.successful if ok else None
