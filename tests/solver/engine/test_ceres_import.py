"""pyceres is loaded without glog's failure signal handlers (solver/engine/ceres_import.py): a
crash kills the process instead of hanging it in the handler's stack trace, and a worker's own
SIGTERM handler keeps running. Checked in fresh processes from the kernel's own record of the
signals a process catches (/proc/self/status, SigCgt), beside a plain ``import pyceres`` that
shows what glog does."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]

PROBE = textwrap.dedent(
    """
    import json, os, re, signal, sys, time
    def caught():
        mask = int(re.search(r"SigCgt:\\s*([0-9a-f]+)", open("/proc/self/status").read()).group(1), 16)
        return [s for s in range(1, 32) if mask >> (s - 1) & 1]
    ran = []
    signal.signal(signal.SIGTERM, lambda signum, frame: ran.append(signum))
    before = caught()
    {load}
    after = caught()
    os.kill(os.getpid(), signal.SIGTERM)  # a warm shutdown's signal: the Python handler must run
    time.sleep(0.2)
    print(json.dumps({{"before": before, "after": after, "term_handler_ran": bool(ran)}}))
    """
)


def _probe(load: str) -> tuple[int, dict | None]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", PROBE.format(load=load)], capture_output=True, text=True, env=env, cwd=ROOT,
                         timeout=300)
    lines = out.stdout.strip().splitlines()
    return out.returncode, (json.loads(lines[-1]) if lines else None)


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="needs /proc (Linux)")
def test_a_plain_import_of_pyceres_takes_the_crash_signals() -> None:
    """The control: glog's handler takes SIGTERM from the Python handler, so the process dies of
    it; and it catches SIGSEGV (11) and SIGABRT (6)."""
    code, got = _probe("import pyceres; print(json.dumps({'after': caught()}), flush=True)")
    assert code == -signal.SIGTERM
    assert got is not None and {6, 11} <= set(got["after"])


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="needs /proc (Linux)")
def test_the_solver_loads_pyceres_and_its_cost_functions_leaving_the_signals_as_they_were() -> None:
    code, got = _probe("import solver.engine.backend; from solver.engine import native; assert native.module() is not None")
    assert code == 0 and got is not None
    assert got["after"] == got["before"]
    assert got["term_handler_ran"]
