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
"""

from __future__ import annotations

import copy
import time
from typing import Any, Callable, Iterator

Say = Callable[[str], None]


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


def compile_kernels(say: Say | None = None) -> float:
    """Run the warm-up adjustments (compiling or loading every kernel); their total seconds."""
    from solver.api import run
    from solver.engine import native
    from solver.kernels.cache import compile_notices

    t0 = time.perf_counter()
    state = native.status()
    if say is not None:
        prefix = "" if state.path == "compiled" else "WARNING: "
        say(f"{prefix}residual evaluation: {state.path} ({state.reason})")
    with compile_notices(say or (lambda _message: None)):
        if state.path == "compiled":  # every C callback, those no warm-up job reaches too
            from solver.kernels import callbacks

            callbacks.load_all()
        jobs = list(warmup_jobs())
        for k, (label, job) in enumerate(jobs, 1):
            t = time.perf_counter()
            report = run(job)
            if say is not None:
                say(f"{label}: {time.perf_counter() - t:.1f} s, sigma0 {report['adjustment']['sigma0_aposteriori']:.2f} "
                    f"(job {k} of {len(jobs)})")
    return time.perf_counter() - t0
