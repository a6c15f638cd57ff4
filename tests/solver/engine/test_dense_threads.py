"""The BLAS-thread rule of the dense algebra (solver/engine/dense_threads.py): one thread for
small matrices and whenever other threads are runnable, the solve's threads on idle cores, and
the limits restored after every block. (The speed that motivates it is measured by
bench/bench_dense_threads.py, not here.)"""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from solver.engine import dense_threads


def _blas_threads() -> set[int]:
    return {lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}


@pytest.fixture
def four_cores(monkeypatch):
    monkeypatch.setenv("PBA_SOLVER_THREADS", "4")


def test_small_matrices_take_one_thread(four_cores) -> None:
    assert dense_threads.threads_for(dense_threads.DENSE_PARALLEL_MIN - 1, others=lambda: 0) == 1


def test_large_matrices_take_the_idle_cores(four_cores) -> None:
    n = dense_threads.DENSE_PARALLEL_MIN
    assert dense_threads.threads_for(n, others=lambda: 0) == 4
    assert dense_threads.threads_for(n, others=lambda: 1) == 3
    assert dense_threads.threads_for(n, others=lambda: 7) == 1  # never fewer than one
    assert dense_threads.threads_for(n, others=lambda: None) == 4  # unreadable: the solve's threads


def test_very_large_matrices_take_one_thread(four_cores) -> None:
    """Above DENSE_PARALLEL_MAX OpenBLAS's threaded Cholesky crashes the process (measured:
    16,000 rows on two threads; bench/bench_openblas_large.py), idle cores or not."""
    assert dense_threads.DENSE_PARALLEL_MAX <= 15_000  # below the largest size measured to survive two threads
    assert dense_threads.threads_for(dense_threads.DENSE_PARALLEL_MAX - 1, others=lambda: 0) == 4
    assert dense_threads.threads_for(dense_threads.DENSE_PARALLEL_MAX, others=lambda: 0) == 1
    assert dense_threads.threads_for(21_200, others=lambda: None) == 1


def test_runnable_others_reads_the_kernel_count() -> None:
    others = dense_threads.runnable_others()
    assert others is None or others >= 0


def test_limits_apply_inside_and_are_restored(four_cores) -> None:
    """Every BLAS library of the process is limited, one loaded after the first limit too
    (OpenCV brings its own OpenBLAS: in the whole suite it is loaded by the matching tests)."""
    import scipy.linalg  # noqa: F401  (its BLAS loaded before the controller is made)

    with dense_threads.bounded():
        pass
    import cv2  # noqa: F401  (another OpenBLAS, loaded after the controller was made)

    before = _blas_threads()
    with dense_threads.bounded():
        assert _blas_threads() == {1}
        with dense_threads.limited(2):
            assert _blas_threads() == {2}
        assert _blas_threads() == {1}
    assert _blas_threads() == before


def test_an_adjustment_runs_bounded(monkeypatch) -> None:
    """solver.api.run enters the one-thread bound: a factorisation inside the adjustment sees
    one BLAS thread (observed from inside, at the reduced system's factor)."""
    import json
    from pathlib import Path

    from solver import api
    from solver.engine import linalg

    seen: list[set[int]] = []
    original = linalg.ReducedFactor.of.__func__

    def spy(cls, s: np.ndarray, overwrite: bool = False):
        seen.append(_blas_threads())
        return original(cls, s, overwrite)

    monkeypatch.setattr(linalg.ReducedFactor, "of", classmethod(spy))
    doc = json.loads((Path(__file__).resolve().parents[3] / "examples" / "prism-triplet.json").read_text())
    api.run(doc)
    assert seen and all(s == {1} for s in seen)
