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


# ---- mirror_tests: helper folders on sys.path (begin) ----
def _helper_folders_on_sys_path() -> None:
    """Test helpers imported by their module name from any folder: pytest (prepend mode) puts
    only a test file's own folder on sys.path; their folders, from scripts/mirror_tests.py."""
    import sys
    from pathlib import Path

    for folder in ('service', 'service/routes', 'service/store', 'solver/importers', 'solver/matching', 'solver/observations', 'solver/platforms', 'solver/sensors'):
        path = str(Path(__file__).resolve().parent / folder)
        if path not in sys.path:
            sys.path.insert(0, path)


_helper_folders_on_sys_path()
# ---- mirror_tests: helper folders on sys.path (end) ----
