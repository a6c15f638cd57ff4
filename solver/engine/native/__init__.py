"""The compiled Ceres cost functions (C++ extension ``callback_cost``, source beside this file).

``callback_cost`` defines ``ceres::CostFunction`` subclasses that pyceres accepts as its own:
``CallbackCost`` calls a numba C callback (:mod:`solver.kernels.callbacks`) through a function
pointer, ``LinearCost`` applies a constant whitened linear form ``A x - b`` (state, attitude and
interior-orientation priors); ``Evaluator`` holds what the cost functions of one solve share
(the image table, copied per evaluating thread, and the cancel flag). No Python runs inside
Ceres' evaluation, so the solve may use every core.

The extension is built by ``scripts/build_native.py`` (``make serve`` and ``make test`` run it:
g++, the Python headers, Debian's ``libceres-dev`` for ``ceres/cost_function.h`` and the
pybind11 release of the pyceres wheel). Without it, or with ``PBA_EVALUATION=python``, the
solver evaluates the same kernels through Python cost functions (one thread): the same numbers,
slower. :func:`status` says which path runs and why (``pba warmup``, the health endpoint).
"""

from __future__ import annotations

import importlib
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from types import ModuleType
from typing import Callable

import numpy as np

EVALUATION_ENV = "PBA_EVALUATION"  # auto (default) | compiled | python
THREADS_ENV = "PBA_SOLVER_THREADS"  # threads of a compiled solve (default: the machine's cores)
EVALUATION_CHOICES = ("auto", "compiled", "python")
ENVIRONMENT = {
    EVALUATION_ENV: (
        "auto",
        "how solves evaluate their residual blocks: `compiled` (C++ cost functions calling the numba kernels, "
        "every core; an error when not built), `python` (Python cost functions, one thread, the same numbers) "
        "or `auto` (compiled when built)",
    ),
    THREADS_ENV: ("the cores the process may use", "threads of a solve on the compiled path"),
}
"""The solver's environment variables (read by every process that solves: ``pba run``, the
server's workers): name -> (default, meaning)."""
ABI = 3  # the module's ``ABI`` attribute this Python side expects
SOURCE = Path(__file__).with_name("callback_cost.cpp")


@dataclass(frozen=True)
class NativeStatus:
    """Which evaluation path solves use: ``path`` "compiled" or "python", and why."""

    path: str
    available: bool
    reason: str

    def to_dict(self) -> dict[str, object]:
        return {"evaluation": self.path, "compiled_available": self.available, "reason": self.reason}


def requested() -> str:
    """The evaluation path asked for by ``PBA_EVALUATION`` (``auto`` when unset)."""
    value = os.environ.get(EVALUATION_ENV, "auto").strip().lower() or "auto"
    if value not in EVALUATION_CHOICES:
        raise ValueError(f"{EVALUATION_ENV}={value!r}: expected one of {', '.join(EVALUATION_CHOICES)}")
    return value


@lru_cache(maxsize=1)
def _load() -> tuple[ModuleType | None, str]:
    from solver.engine.ceres_import import import_pyceres

    import_pyceres()  # the extension imports pyceres: first without glog's signal handlers
    try:
        module = importlib.import_module("solver.engine.native.callback_cost")
    except ImportError as exc:
        return None, f"the compiled cost functions are not built ({exc}); run `make native` (scripts/build_native.py)"
    if getattr(module, "ABI", None) != ABI:
        return None, f"the compiled cost functions are out of date (ABI {getattr(module, 'ABI', None)}, expected {ABI}); run `make native`"
    return module, "compiled cost functions loaded"


def module() -> ModuleType | None:
    """The extension module when the compiled path is to be used, else None."""
    if requested() == "python":
        return None
    mod, reason = _load()
    if mod is None and requested() == "compiled":
        raise RuntimeError(f"{EVALUATION_ENV}=compiled but {reason}")
    return mod


def status() -> NativeStatus:
    """The path solves take in this process and the reason (never raises)."""
    try:
        want = requested()
    except ValueError as exc:
        return NativeStatus("python", False, str(exc))
    mod, reason = _load()
    if want == "python":
        return NativeStatus("python", mod is not None, f"{EVALUATION_ENV}=python")
    if mod is None:
        return NativeStatus("python", False, reason + ": solves use the slower Python cost functions")
    return NativeStatus("compiled", True, reason)


def built() -> tuple[bool, str]:
    """Whether the extension is built and current, judged from its files without importing it
    (importing it imports pyceres, which the server process must not load)."""
    import sysconfig

    target = SOURCE.with_name("callback_cost" + (sysconfig.get_config_var("EXT_SUFFIX") or ".so"))
    if requested_quietly() == "python":
        return False, f"{EVALUATION_ENV}=python: solves use the Python cost functions"
    if not target.is_file():
        return False, "the compiled cost functions are not built (make native): solves use the slower Python cost functions"
    if target.stat().st_mtime < SOURCE.stat().st_mtime:
        return False, "the compiled cost functions are older than their source (make native): solves may use the slower Python cost functions"
    return True, "compiled cost functions built"


def requested_quietly() -> str:
    """:func:`requested`, or "python" for a value it refuses (the solve will say why)."""
    try:
        return requested()
    except ValueError:
        return "python"


def available_cores() -> int:
    """The cores this process may use (its CPU affinity: a container's or ``taskset``'s share,
    not the machine's count), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def solver_threads() -> int:
    """Threads of a compiled solve: ``PBA_SOLVER_THREADS`` or the cores this process may use."""
    value = os.environ.get(THREADS_ENV, "").strip()
    if value:
        try:
            return max(1, int(value))
        except ValueError:
            raise ValueError(f"{THREADS_ENV}={value!r}: expected a positive integer") from None
    return available_cores()


PARALLEL_MIN_ROWS = 5_000
"""Fewer rows (observations, points) than this per thread are filled on one thread: starting a
thread costs more than it saves there."""


def thread_ranges(n: int) -> list[int]:
    """The bounds of the contiguous ranges :func:`in_threads` hands its threads over ``[0, n)``."""
    threads = max(1, min(solver_threads(), n // PARALLEL_MIN_ROWS))
    return np.linspace(0, n, threads + 1).astype(np.int64).tolist()


def in_threads(fill: Callable[[int, int], None], n: int) -> None:
    """Run ``fill(lo, hi)`` over contiguous ranges covering ``[0, n)``, one per thread of the
    solve (``PBA_SOLVER_THREADS``, at most one per :data:`PARALLEL_MIN_ROWS` rows), in threads of
    this process (the linearisation, covariance and intersections outside Ceres). ``fill`` calls a
    numba kernel that releases the GIL and writes only what its range owns (rows of an output, or
    its own copy that the caller adds in range order), so a result does not depend on which
    thread finishes first."""
    bounds = thread_ranges(n)
    threads = len(bounds) - 1
    if threads == 1:
        fill(0, n)
        return
    with ThreadPoolExecutor(threads, thread_name_prefix="pba-fill") as pool:
        for done in [pool.submit(fill, bounds[k], bounds[k + 1]) for k in range(threads)]:
            done.result()  # re-raises a thread's exception here
