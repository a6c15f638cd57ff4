"""Compile the solver's numba kernels ahead of the first job (``pba warmup``).

The kernels are compiled on first use and cached on disk (``cache=True``) in a directory keyed
on a digest of the kernel sources (:mod:`solver.kernels.cache`: ``pba-kernels-<digest>`` under
the installation's ``solver/__pycache__``, which every process of the installation finds), so a
warm-up after an upgrade compiles the new kernels instead of loading the old ones. A cold
compile of every kernel takes one to three minutes of CPU on a small machine; a cached one loads
in a few seconds. Without a warm-up those minutes are paid by the first job a fresh installation
runs (its progress then says that kernels are compiling).

:func:`compile_kernels` adjusts a few tiny simulated jobs that between them reach every kernel
(every platform-model kind with its Jacobians, self-calibration, ephemeris observations, the
propagated pass state, straight lines with both line models, covariance and check points).
``make native`` (and so ``make serve`` and ``make test``) and the Docker build run it once per
installation.

Almost all of a cold warm-up is numba's compiler, which runs on one core. A large part of it is
the compiled path's C callbacks (:mod:`solver.kernels.callbacks`, all compiled first by
``callbacks.load_all``), which the Python path never uses; the rest are the kernels of the
Python cost functions and those both paths share (platform states, intersections, covariances).
With ``processes`` of 2 or more (``pba warmup --jobs``, by default 2 on a machine of two or more
cores) and the compiled path available, :func:`compile_kernels` therefore starts one child
process, ``python -m solver.warmup <this solver directory>`` with ``PBA_EVALUATION=python``
(which refuses to run on any other path or from another installation), that adjusts the same
jobs on the Python path while this process compiles the C callbacks and then adjusts the jobs
on the compiled path, by when most of the kernels it shares with the child are in the cache.
Both write into the same cache (numba renames each entry into place, so sharing it at once is
safe), the child's lines are relayed with the prefix ``[python path]``, a child that fails fails
the warm-up with the last lines it printed, and a warm-up that fails ends its child. A third
process would have nothing of its own to compile, so more than 2 work as 2; with 1, or where only
the Python path exists, everything runs in this process, one job after the other as before.
"""

from __future__ import annotations

import copy
import os
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any, Callable, Iterator

Say = Callable[[str], None]

SOLVER_DIR = Path(__file__).resolve().parent  # solver/ of this installation
CHILD_PREFIX = "[python path] "  # before each line the child prints, relayed by this process
TAIL_LINES = 20  # of the child's output, in the error when it fails


def _triplet() -> dict[str, Any]:
    """A PRISM triplet with 10 control, 2 check and 10 tie points (about 130 observations)."""
    from solver.simulate import presets
    from solver.simulate.scene import SceneSettings

    scene = presets.prism_triplet(SceneSettings(preset="prism-triplet", seed=7), gcps=10, checks=2, tie_points=10)
    return scene.job()


def _rpc_triplet() -> dict[str, Any]:
    """The triplet with images 2 and 3 as RPC-DRIFT images (RPC kernels beside a rigorous image)."""
    from solver.simulate import presets
    from solver.simulate.rpc import RpcSettings
    from solver.simulate.scene import SceneSettings

    settings = SceneSettings(preset="prism-triplet", seed=7, rpc=RpcSettings("RPC-DRIFT", {"a0": 5.0, "b0": -3.0}, [2, 3]))
    return presets.prism_triplet(settings, gcps=10, checks=2, tie_points=10).job()


def _lines() -> dict[str, Any]:
    """A CBERS-like scene with 10 ground lines, 6 control and 2 check points."""
    from solver.simulate.lines import cbers_lines
    from solver.simulate.scene import SceneSettings

    return cbers_lines(SceneSettings(preset="cbers-lines", seed=7), lines=10, gcps=6, checks=2).job()


def warmup_jobs() -> Iterator[tuple[str, dict[str, Any]]]:
    """(label, job document) of the warm-up adjustments."""
    triplet = _triplet()
    for model in ("P2", "K2", "OA-J2", "PASS-J2"):
        job = copy.deepcopy(triplet)
        for image in job["images"]:
            image["model"] = {"name": model}
        options = job.setdefault("options", {})
        if model in ("OA-J2", "PASS-J2"):  # the ephemeris is consistent with these models only
            options["ephemeris"] = {"sigma_position_m": 10.0, "sigma_velocity_m_s": 0.05}
        if model in ("K2", "PASS-J2"):  # one kernel self-calibrates every model kind
            options["self_calibration"] = {"estimate": ["df", "a0", "b0"]}
        yield model, job
    yield "RPC-DRIFT (mixed block)", _rpc_triplet()
    lines = _lines()
    for line_model in ("rigorous", "equivalent_planes"):
        job = copy.deepcopy(lines)
        job.setdefault("options", {})["line_model"] = line_model
        yield f"lines ({line_model})", job


class WarmupError(RuntimeError):
    """The warm-up's child process failed (its message ends with the child's last lines)."""


def default_processes() -> int:
    """``pba warmup``'s default ``--jobs``: 2 where this process may use two or more cores, else 1."""
    from solver.engine.native import available_cores

    return 2 if available_cores() >= 2 else 1


def python_path_command() -> list[str]:
    """The command of the child that warms the Python evaluation path: this module, run by this
    interpreter, told which ``solver`` package it must be (the tests replace it)."""
    return [sys.executable, "-m", "solver.warmup", str(SOLVER_DIR)]


def _adjust_jobs(say: Say | None, compiled: bool) -> None:
    """Adjust the warm-up jobs (first every C callback when ``compiled``), saying each one's time."""
    from solver.api import run
    from solver.kernels.cache import compile_notices

    with compile_notices(say or (lambda _message: None)):
        if compiled:  # every C callback, those no warm-up job reaches too
            from solver.kernels import callbacks

            callbacks.load_all()
        jobs = list(warmup_jobs())
        for k, (label, job) in enumerate(jobs, 1):
            t = time.perf_counter()
            report = run(job)
            if say is not None:
                say(f"{label}: {time.perf_counter() - t:.1f} s, sigma0 {report['adjustment']['sigma0_aposteriori']:.2f} (job {k} of {len(jobs)})")


def _serialised(say: Say | None) -> Say | None:
    """``say`` called under a lock: this process's lines and the relayed ones never mix."""
    if say is None:
        return None
    lock = threading.Lock()

    def locked(message: str) -> None:
        with lock:
            say(message)

    return locked


def _die_with_parent(parent: int) -> Callable[[], None] | None:
    """On Linux, what the child runs before its program: be sent SIGTERM when ``parent`` dies
    (killed, so that no ``finally`` of it runs); elsewhere nothing."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes
    import signal

    prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up here: nothing to import after the fork
    pr_set_pdeathsig = 1

    def arm() -> None:
        prctl(pr_set_pdeathsig, int(signal.SIGTERM))
        if os.getppid() != parent:  # the parent died before the line above
            os._exit(1)

    return arm


class _PythonPathChild:
    """The child process warming the Python evaluation path; a thread relays its output."""

    def __init__(self, say: Say | None) -> None:
        self.command = python_path_command()
        self.tail: deque[str] = deque(maxlen=TAIL_LINES)
        env = {**os.environ, "PBA_EVALUATION": "python", "PYTHONUNBUFFERED": "1"}
        self.process = subprocess.Popen(
            self.command,
            cwd=SOLVER_DIR.parent,  # `-m solver.warmup` finds this installation's solver first
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            errors="replace",
            preexec_fn=_die_with_parent(os.getpid()),
        )
        self.relay = threading.Thread(target=self._relay, args=(say,), name="pba-warmup-relay", daemon=True)
        self.relay.start()

    def _relay(self, say: Say | None) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            line = line.rstrip("\r\n")
            self.tail.append(line)
            if say is not None:
                say(CHILD_PREFIX + line)

    def wait(self) -> None:
        """Wait for the child to end; :class:`WarmupError` when it failed."""
        code = self.process.wait()
        self.relay.join()
        if code != 0:
            how = f"was killed by signal {-code}" if code < 0 else f"failed with exit status {code}"
            tail = "\n".join("  " + line for line in self.tail) or "  (no output)"
            raise WarmupError(f"the Python-path warm-up ({' '.join(self.command)}) {how}; its last lines:\n{tail}")

    def stop(self) -> None:
        """End the child if it still runs (this process failed or was interrupted)."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.relay.join(timeout=10)


def compile_kernels(say: Say | None = None, processes: int = 1) -> float:
    """Run the warm-up adjustments (compiling or loading every kernel); their total seconds.

    With ``processes`` of 2 or more and the compiled path available, a child process adjusts the
    same jobs on the Python path at the same time (module doc), its lines passed to ``say`` with
    :data:`CHILD_PREFIX`; :class:`WarmupError` when it fails. The child is ended when this
    process fails or is interrupted before it."""
    from solver.engine import native

    t0 = time.perf_counter()
    state = native.status()
    if say is not None:
        prefix = "" if state.path == "compiled" else "WARNING: "
        say(f"{prefix}residual evaluation: {state.path} ({state.reason})")
    if processes < 2 or state.path != "compiled":
        _adjust_jobs(say, compiled=state.path == "compiled")
        return time.perf_counter() - t0
    say = _serialised(say)
    child = _PythonPathChild(say)
    try:
        _adjust_jobs(say, compiled=True)
        child.wait()
    finally:
        child.stop()
    return time.perf_counter() - t0


def _python_path_main(argv: list[str]) -> int:
    """The child's program (``python -m solver.warmup <solver dir>``, ``PBA_EVALUATION=python``):
    the warm-up jobs on the Python evaluation path, refusing to run on any other path or from
    another installation's ``solver`` than the one given."""
    from solver.engine import native

    if argv and Path(argv[0]).resolve() != SOLVER_DIR:
        print(f"this is the solver package of {SOLVER_DIR}, not of {argv[0]}")
        return 2
    t0 = time.perf_counter()
    state = native.status()
    print(f"residual evaluation: {state.path} ({state.reason})")
    if state.path != "python" or native.module() is not None:
        print("expected the Python evaluation path (PBA_EVALUATION=python)")
        return 2
    _adjust_jobs(print, compiled=False)
    print(f"Python path warmed in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(_python_path_main(sys.argv[1:]))
