"""Threads of the dense linear algebra (OpenBLAS under numpy and scipy).

OpenBLAS runs a factorisation on as many threads as there are cores, and its threads wait for
one another by spinning. On a machine whose cores are already busy (a shared server's other
workers, a second job, a test run) that turns a small factorisation into seconds: on 2 cores
with other processes running, the Cholesky factor and inverse of a 420-square matrix took
3.9 s on two threads and 0.015 s on one; a 5,400-square one 26.7 s against 5.2 s
(bench/bench_dense_threads.py). On an idle machine two threads gain only on large matrices.

So an adjustment runs its dense algebra on one thread (:func:`bounded`, entered by
:mod:`solver.api` around every job), and the few large factorisations of the reduced system
(the rank check's factor, the covariance, the eigen-analyses) take more threads only when
their matrix has at least :data:`DENSE_PARALLEL_MIN` rows (and fewer than
:data:`DENSE_PARALLEL_MAX`: OpenBLAS's threads corrupt memory above) and cores are idle at that moment
(:func:`for_matrix`): the threads the solve may use (``PBA_SOLVER_THREADS``) minus the runnable
threads of other processes (``/proc/loadavg`` less this process's own), at least one.
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from typing import Callable, Iterator

DENSE_PARALLEL_MIN = 1500
"""Rows of a dense matrix from which its factorisation may use more than one thread (below,
one thread is as fast on an idle machine: 0.10 s against 0.16 s at 1,200 rows)."""

DENSE_PARALLEL_MAX = 12_000
"""Rows from which a factorisation runs on one thread again, whatever the idle cores: OpenBLAS's
threaded Cholesky writes outside its per-thread buffer on large matrices
(https://github.com/OpenMathLib/OpenBLAS/issues/2562). Measured with the OpenBLAS that scipy
ships here (bench/bench_openblas_large.py): ``dpotrf`` of a 16,000-square matrix on two threads
kills the process with a segmentation fault, of a 15,000-square one it does not; one thread
factors a 21,200-square one (a 1,515-image block's reduced matrix) in 43 s. Where the write
lands short of a crash it corrupts the heap, and a later ``free`` aborts the process."""

_controller = None
_modules_seen = -1


def _blas():
    """threadpoolctl's controller of the BLAS libraries loaded (numpy's and scipy's OpenBLAS,
    and any another extension brought: OpenCV has its own), made again when modules were
    imported since (a library loaded later would otherwise keep its own threads)."""
    global _controller, _modules_seen
    if _controller is None or len(sys.modules) != _modules_seen:
        import scipy.linalg  # noqa: F401  (its OpenBLAS loaded, so the controller sees it)
        from threadpoolctl import ThreadpoolController

        _controller = ThreadpoolController()
        _modules_seen = len(sys.modules)
    return _controller


def _own_running() -> int:
    """Threads of this process the kernel has running or runnable now (state R in
    ``/proc/self/task/*/stat``; the caller's own thread among them): OpenBLAS's own threads
    still spin for a moment after a factorisation, and they are not another process's work."""
    running = 0
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return 1
    for tid in tasks:
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                state = f.read().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            continue
        running += state == "R"
    return max(running, 1)


def runnable_others() -> int | None:
    """Threads of other processes runnable on the machine now: the kernel's count of runnable
    threads (the fourth field of ``/proc/loadavg``, "running/total") less this process's own
    (:func:`_own_running`); None off Linux."""
    try:
        with open("/proc/loadavg") as f:
            running = int(f.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return None
    return max(running - _own_running(), 0)


def threads_for(rows: int, others: Callable[[], int | None] = runnable_others) -> int:
    """BLAS threads for a dense factorisation of a ``rows``-square matrix: one below
    :data:`DENSE_PARALLEL_MIN` and from :data:`DENSE_PARALLEL_MAX`; else the solve's threads
    less the other runnable threads (all of the solve's threads when that cannot be read), at
    least one."""
    from solver.engine.native import solver_threads

    if rows < DENSE_PARALLEL_MIN or rows >= DENSE_PARALLEL_MAX:
        return 1
    allowed = solver_threads()
    busy = others()
    return allowed if busy is None else max(1, min(allowed, allowed - busy))


@contextmanager
def limited(threads: int) -> Iterator[None]:
    """BLAS on ``threads`` threads inside the block; the previous limits restored after."""
    with _blas().limit(limits=threads, user_api="blas"):
        yield


@contextmanager
def bounded() -> Iterator[None]:
    """One BLAS thread for everything inside (an adjustment; see the module docstring)."""
    with limited(1):
        yield


@contextmanager
def for_matrix(rows: int) -> Iterator[None]:
    """The BLAS threads :func:`threads_for` gives a ``rows``-square factorisation, inside the block."""
    with limited(threads_for(rows)):
        yield

