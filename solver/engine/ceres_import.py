"""pyceres imported without glog's failure signal handlers.

Importing pyceres (directly, or through the compiled cost functions, whose module imports it)
installs glog's handlers for SIGSEGV, SIGABRT, SIGBUS, SIGILL, SIGFPE and SIGTERM. On a crash
inside the C library's allocator (a corrupted heap found by ``free``), the handler's stack
trace calls ``backtrace``, which needs the allocator's lock the crashing thread holds: the
process then sleeps forever instead of dying, and a worker's job never ends (seen on a
5-million-observation block). A Python SIGTERM handler installed before the import (a worker's
warm shutdown) no longer ran either. :func:`import_pyceres` imports pyceres and puts back what
each signal did before: the default action (the process dies and its parent sees why), Python's
own handler where one was installed, and faulthandler's where it is enabled.
"""

from __future__ import annotations

import faulthandler
import signal
import sys
import threading
from types import ModuleType

GLOG_SIGNALS = (signal.SIGSEGV, signal.SIGABRT, signal.SIGBUS, signal.SIGILL, signal.SIGFPE, signal.SIGTERM)
"""The signals glog's failure handler takes over when pyceres is imported."""


def import_pyceres() -> ModuleType:
    """pyceres, imported with every signal of :data:`GLOG_SIGNALS` left as it was before. Off
    the main thread (where Python cannot set handlers) pyceres is imported as it is."""
    if "pyceres" in sys.modules:
        return sys.modules["pyceres"]
    on_main = threading.current_thread() is threading.main_thread()
    before = {s: signal.getsignal(s) for s in GLOG_SIGNALS} if on_main else {}
    import pyceres

    for s, handler in before.items():
        # None: a handler not installed from Python (faulthandler's, restored below)
        signal.signal(s, signal.SIG_DFL if handler is None else handler)
    if on_main and faulthandler.is_enabled():
        faulthandler.enable()
    return pyceres
