"""Raster header checks of the API process, run outside its request threads with a time limit.

A ``match`` submission reads each raster's header (service.rasters, through the raster gate):
little work, but work on a file a client chose, in GDAL. A slow file system, a header GDAL
takes long over or a crash in GDAL must not stall or take down the API. So the API hands each
check to a small pool of processes of its own (``pba-raster`` in ``ps``):

- **a time limit**: a check that has not answered within ``PBA_RASTER_CHECK_TIMEOUT_S``
  seconds is abandoned, its process killed and replaced; the request gets a 422 pointing at the
  raster (``timeout``);
- **a share per user**: a user has at most ``PBA_RASTER_CHECKS_PER_USER`` checks running at
  once; a request beyond that is answered at once with 503 (``Retry-After``) instead of taking
  a request thread or a process, so one user's held requests leave the API and every other
  user's requests answering;
- **a bounded pool**: ``PBA_RASTER_CHECK_PROCESSES`` processes; a check waits for a free one at
  most the time limit (then 503);
- **a crash is a refusal**: a process that dies during a check (GDAL crashing on a hostile
  file) is replaced and the request gets a 422 pointing at the raster.

The processes import GDAL (rasterio), so the API process itself never does; they start with
the first check and end with the server (or by themselves when it is killed: their pipe
closes).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import queue
import threading
from dataclasses import dataclass
from typing import Any

from service.errors import InvalidInput, ServiceError

log = logging.getLogger("pba.raster_checks")

PROCESS_NAME = "pba-raster"
"""The check processes' name in ``ps`` (Linux: at most 15 characters)."""


class ChecksBusy(ServiceError):
    """503: the user's share of the raster checks (or the whole pool) is busy."""

    status, code, title = 503, "raster-checks-busy", "Raster checks busy"


def _serve(conn: Any) -> None:
    """A check process: answer ``(function name, args)`` requests until the pipe closes."""
    import os
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the server, which stops us
    try:
        with open("/proc/self/comm", "w") as comm:  # Linux; elsewhere the name stays python
            comm.write(PROCESS_NAME)
    except OSError:
        pass
    from service import rasters
    from solver.raster_gate import lock_down_process

    lock_down_process()
    while True:
        try:
            name, args = conn.recv()
        except (EOFError, OSError):
            os._exit(0)
        try:
            header = getattr(rasters, name)(*args)
            answer: tuple[Any, ...] = ("ok", header)
        except InvalidInput as exc:
            answer = ("invalid", exc.detail, exc.errors)
        except Exception as exc:  # noqa: BLE001 - any other failure is the raster's, said as such
            answer = ("failed", f"{type(exc).__name__}: {exc}")
        try:
            conn.send(answer)
        except (BrokenPipeError, OSError):
            os._exit(0)


class _Slot:
    """One check process and its pipe (started on first use, replaced after a timeout)."""

    def __init__(self, ctx: Any, index: int) -> None:
        self.ctx, self.index = ctx, index
        self.process: Any = None
        self.conn: Any = None

    def ensure(self) -> None:
        if self.process is not None and self.process.is_alive():
            return
        self.discard()
        parent, child = self.ctx.Pipe()
        p = self.ctx.Process(target=_serve, args=(child,), name=f"{PROCESS_NAME}-{self.index}", daemon=True)
        p.start()
        child.close()
        self.process, self.conn = p, parent

    def discard(self) -> None:
        if self.process is not None:
            if self.process.is_alive():
                self.process.kill()
            self.process.join(timeout=5)
        if self.conn is not None:
            self.conn.close()
        self.process = self.conn = None


@dataclass(frozen=True)
class Refusal:
    """Where a failed or timed-out check points: the request's field and what to say."""

    pointer: str
    shown: str


class RasterCheckPool:
    """The pool (module docstring). ``run(user, pointer, shown, name, *args)`` calls
    ``service.rasters.<name>(*args)`` in a check process and returns its result."""

    def __init__(self, processes: int, timeout_s: float, per_user: int) -> None:
        self.timeout_s = timeout_s
        self.per_user = per_user
        self._ctx = mp.get_context("spawn")
        self._slots = [_Slot(self._ctx, i) for i in range(processes)]
        self._free: queue.Queue[_Slot] = queue.Queue()
        for s in self._slots:
            self._free.put(s)
        self._running: dict[str, int] = {}
        self._lock = threading.Lock()

    def pids(self) -> list[int]:
        """PIDs of the check processes alive now."""
        return [s.process.pid for s in self._slots if s.process is not None and s.process.is_alive()]

    def _enter(self, user: str) -> None:
        with self._lock:
            if self._running.get(user, 0) >= self.per_user:
                raise ChecksBusy(
                    f"you have {self.per_user} raster check(s) running already (PBA_RASTER_CHECKS_PER_USER); retry when they end",
                    headers={"Retry-After": str(max(1, round(self.timeout_s)))},
                )
            self._running[user] = self._running.get(user, 0) + 1

    def _leave(self, user: str) -> None:
        with self._lock:
            left = self._running.get(user, 1) - 1
            if left > 0:
                self._running[user] = left
            else:
                self._running.pop(user, None)

    def run(self, user: str, where: Refusal, name: str, *args: Any) -> Any:
        self._enter(user)
        try:
            try:
                slot = self._free.get(timeout=self.timeout_s)
            except queue.Empty:
                raise ChecksBusy("every raster check process is busy; retry in a moment",
                                 headers={"Retry-After": str(max(1, round(self.timeout_s)))}) from None
            try:
                return self._ask(slot, where, name, args)
            finally:
                self._free.put(slot)
        finally:
            self._leave(user)

    def _ask(self, slot: _Slot, where: Refusal, name: str, args: tuple[Any, ...]) -> Any:
        def refuse(code: str, message: str) -> InvalidInput:
            return InvalidInput(message, [{"pointer": where.pointer, "code": code, "message": message}])

        slot.ensure()
        try:
            slot.conn.send((name, args))
            answered = slot.conn.poll(self.timeout_s)
            answer = slot.conn.recv() if answered else None
        except (EOFError, OSError, BrokenPipeError):
            slot.discard()
            log.warning("a raster check process died during a check", extra={"pointer": where.pointer})
            raise refuse("unreadable", f"{where.shown}: reading its header failed (the reader stopped); not a raster the server reads") from None
        if answer is None:
            slot.discard()
            log.warning("a raster check timed out; its process was replaced", extra={"pointer": where.pointer})
            raise refuse("timeout", f"{where.shown}: its header could not be read within {self.timeout_s:g} s "
                         "(PBA_RASTER_CHECK_TIMEOUT_S)")
        kind = answer[0]
        if kind == "ok":
            return answer[1]
        if kind == "invalid":
            raise InvalidInput(answer[1], answer[2])
        raise refuse("unreadable", f"{where.shown}: its header could not be read ({answer[1][:300]})")

    def stop(self) -> None:
        for s in self._slots:
            s.discard()


_pool: RasterCheckPool | None = None
_pool_lock = threading.Lock()


def pool(processes: int, timeout_s: float, per_user: int) -> RasterCheckPool:
    """This process's pool (created at the first check with these settings)."""
    global _pool
    with _pool_lock:
        if _pool is None or (len(_pool._slots), _pool.timeout_s, _pool.per_user) != (processes, timeout_s, per_user):
            if _pool is not None:
                _pool.stop()
            _pool = RasterCheckPool(processes, timeout_s, per_user)
        return _pool


def stop_pool() -> None:
    """End the check processes (the server's shutdown)."""
    global _pool
    with _pool_lock:
        if _pool is not None:
            _pool.stop()
            _pool = None

