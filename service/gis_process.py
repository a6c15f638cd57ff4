"""The process the GIS result endpoints compute in: RPC fits, GeoJSON and ground <-> image
transforms of finished jobs, outside the API process.

Those use cases (:mod:`service.gis_results`) rebuild a job's adjusted model and evaluate the
solver's compiled kernels: numba alone is about 125 MB of a process, an adjusted model and its
fitted RPCs tens of MB more. The API process must stay small and predictable whatever a user
asks (a hostile or merely large request may not grow it), so the endpoints hand the job's id and
the request's arguments to ``spawn``-started processes (started with ``pba serve``, or by
the first GIS request of an app run otherwise; stopped with the server) that open the same store,
load the job themselves and keep the caches of :mod:`service.gis_results` (adjusted models, one
fit per job, image and chip). A problem one raises (404, 409, 422) comes back as the same problem
document; a crash of one is a 503 and the next request starts a new one.

Requests are shared fairly (:class:`GisProcess`): small transforms have a process of their own,
and within each lane a free process goes to the user with the fewest requests running.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import os
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from service.errors import NoSuchJob, ServiceError
from service.fair_slots import FairSlots

log = logging.getLogger("pba.gis")

PROCESS_NAME = "pba-gis"
USE_CASES = ("rpc_document", "geojson", "ground_to_image", "image_to_ground")
ROW_USE_CASES = ("ground_to_image", "image_to_ground")  # whose cost is their rows


class GisUnavailable(ServiceError):
    status, code, title = 503, "gis-unavailable", "The GIS computation process stopped"


# ---- in the GIS process ------------------------------------------------------------------
_store: Any = None


def _open(database_url: str) -> None:
    """Initializer of the GIS process: its name (``ps`` shows ``pba-gis``), one BLAS thread, and
    the store it reads jobs from."""
    global _store
    from threadpoolctl import threadpool_limits

    from service.store import open_store
    from solver.raster_gate import lock_down_process

    # Small least-squares problems (RPC fits) on one BLAS thread: with OpenBLAS's threads competing
    # for the cores the workers' solves use, a 0.6 s fit took 17-25 s (measured on 2 cores).
    threadpool_limits(limits=1)
    lock_down_process()  # this process opens no raster; GDAL off the network (solver.raster_gate)
    try:
        with open("/proc/self/comm", "w") as comm:  # Linux; elsewhere the name stays python
            comm.write(PROCESS_NAME)
    except OSError:
        pass
    _store = open_store(database_url, create=False)
    _exit_with_parent(os.getppid())


PARENT_POLL_S = 1.0


def _exit_with_parent(parent: int) -> None:
    """End this process once the API process that started it is gone: a server killed outright
    (no ``stop()`` reached) would otherwise leave it running, holding its memory and the store."""

    def watch() -> None:
        while True:
            time.sleep(PARENT_POLL_S)
            if os.getppid() != parent:
                os._exit(0)

    threading.Thread(target=watch, name="pba-gis-parent", daemon=True).start()


def _problem_fields(exc: ServiceError) -> dict[str, Any]:
    return {k: getattr(exc, k) for k in ("status", "code", "title", "detail", "errors", "type_uri", "headers")}


def _run(use_case: str, job_id: str, args: tuple[Any, ...]) -> tuple[str, Any]:
    """One use case of :mod:`service.gis_results` on the stored job: ``("ok", result)`` or
    ``("problem", fields)`` (problems travel as plain fields: their classes need not pickle)."""
    from service import gis_results

    try:
        rec = _store.get_job(job_id)
        if rec is None:
            raise NoSuchJob(job_id)
        return "ok", getattr(gis_results, use_case)(rec, *args)
    except ServiceError as exc:
        return "problem", _problem_fields(exc)


def _warm() -> None:
    """Load what the use cases need (the kernels from their disk cache) before the first request."""
    import solver.gis.model  # noqa: F401
    import solver.gis.rpc_export  # noqa: F401
    import solver.kernels.blocks  # noqa: F401
    from service import gis_results  # noqa: F401


# ---- in the API process ------------------------------------------------------------------
def _rebuilt(fields: dict[str, Any]) -> ServiceError:
    """The problem raised in the GIS process, as a ServiceError of the same status and code."""
    exc = ServiceError(fields["detail"], fields["errors"], fields["type_uri"], fields["headers"])
    exc.status, exc.code, exc.title = fields["status"], fields["code"], fields["title"]
    return exc


@dataclass
class _Lane:
    """Processes of one kind of request: a pool of ``processes`` and as many fair slots."""

    name: str
    processes: int
    slots: FairSlots
    pool: ProcessPoolExecutor | None = None


class GisProcess:
    """The GIS computation processes of one server (started lazily, restarted after a crash).

    Two lanes, each a pool of processes with fair slots (:class:`service.fair_slots.FairSlots`):
    transforms of at most ``small_rows`` rows go to the small lane (one process), everything else
    (larger transforms, RPC fits, GeoJSON) to the general lane (``processes`` processes). A
    1-row transform therefore never waits behind another user's 10,000-row one, and within a
    lane users take turns (docs/server-limits.md "GIS requests")."""

    def __init__(self, database_url: str, processes: int = 1, small_rows: int = 100) -> None:
        self.database_url = database_url
        self.small_rows = small_rows
        self.lanes = {
            "general": _Lane("general", processes, FairSlots(processes)),
            "small": _Lane("small", 1, FairSlots(1)),
        }
        self._lock = threading.Lock()

    def lane_of(self, use_case: str, rows: int | None) -> _Lane:
        """The small lane for transforms of at most ``small_rows`` rows, else the general one."""
        small = use_case in ROW_USE_CASES and rows is not None and rows <= self.small_rows
        return self.lanes["small" if small else "general"]

    def _executor(self, lane: _Lane) -> ProcessPoolExecutor:
        with self._lock:
            if lane.pool is None:
                lane.pool = ProcessPoolExecutor(
                    max_workers=lane.processes, mp_context=mp.get_context("spawn"), initializer=_open, initargs=(self.database_url,)
                )
            return lane.pool

    def _discard(self, lane: _Lane, pool: ProcessPoolExecutor) -> None:
        with self._lock:
            if lane.pool is pool:
                lane.pool = None
        pool.shutdown(wait=False, cancel_futures=True)

    def start(self) -> None:
        """Start the processes now and load their libraries in the background (``pba serve``
        does, so that the first GIS request does not wait for them)."""
        def report(future: Future) -> None:
            if not future.cancelled() and future.exception() is not None:
                log.warning("a GIS process did not warm up: %s", future.exception())

        for lane in self.lanes.values():
            pool = self._executor(lane)
            for _ in range(lane.processes):
                pool.submit(_warm).add_done_callback(report)

    async def call(self, use_case: str, job_id: str, *args: Any, owner: str = "", rows: int | None = None) -> Any:
        """Run ``service.gis_results.<use_case>(job, *args)`` in a GIS process of the request's
        lane, when the fair order gives ``owner`` (the caller) a slot; ``rows``: a transform's
        row count."""
        if use_case not in USE_CASES:
            raise ValueError(f"unknown GIS use case {use_case!r}")
        lane = self.lane_of(use_case, rows)
        await lane.slots.acquire(owner)
        pool = self._executor(lane)
        try:
            computed = pool.submit(_run, use_case, job_id, args)
        except BaseException as exc:
            lane.slots.release(owner)
            if isinstance(exc, BrokenProcessPool):
                raise self._broken(lane, pool, use_case, job_id) from exc
            raise
        # The slot is held until the computation ends, not until the client stops waiting: a
        # request given up (client gone) leaves no extra work queued in the process.
        computed.add_done_callback(lambda _: lane.slots.release(owner))
        try:
            status, value = await asyncio.wrap_future(computed)
        except BrokenProcessPool as exc:
            raise self._broken(lane, pool, use_case, job_id) from exc
        if status == "problem":
            raise _rebuilt(value)
        return value

    def _broken(self, lane: _Lane, pool: ProcessPoolExecutor, use_case: str, job_id: str) -> GisUnavailable:
        log.error("the %s GIS process stopped during %s of job %s; the next request starts a new one", lane.name, use_case, job_id)
        self._discard(lane, pool)
        return GisUnavailable("the process computing RPCs and transforms stopped; retry the request")

    def stop(self) -> None:
        with self._lock:
            pools = [lane.pool for lane in self.lanes.values()]
            for lane in self.lanes.values():
                lane.pool = None
        for pool in pools:
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
