"""The process heap: handing freed memory back to the system (glibc's ``malloc_trim``).

glibc keeps memory a program frees in the heap it came from, and a thread other than the main
one allocates from a heap of its own: memory freed by the Ceres solver's threads or by
``pba match``'s detection thread stays in those heaps, where later allocations of the main
thread cannot reuse it, and the process's peak grows by it. :func:`release_freed_memory` hands
every heap's free pages back (a few milliseconds). Elsewhere than glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from typing import Callable


def _trim_function() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim`` (None on another C library)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


_TRIM = _trim_function()


def release_freed_memory() -> None:
    """Hand every heap's free memory back to the system (module docstring; nothing elsewhere
    than glibc)."""
    if _TRIM is not None:
        _TRIM(0)
