"""Set-up shared by every test: the numba kernels compiled (or loaded from their disk cache)
once, before any test starts a server or worker process.

Without it, the first job of every spawned process on a fresh clone compiles the kernels itself
(one to two minutes on a 2-core machine), and tests that wait for a job to reach some iteration
would be timing the compiler instead of the service.
"""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session", autouse=True)
def _kernels_compiled() -> None:
    from solver.warmup import compile_kernels

    compile_kernels()
