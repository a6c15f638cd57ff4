"""The two evaluation paths of the residual blocks (solver/engine/backend.py): compiled C++ cost
functions calling numba C callbacks (solver/engine/native, solver/kernels/callbacks.py) and the
Python cost functions, which must give the same numbers.

- block by block, on scenes of every residual-block family (point blocks, fixed-point blocks,
  linear priors of states, attitude and interior orientation, pass states, RPC images, free
  interior orientation): residuals and Jacobians of the two paths agree, and the compiled
  Jacobians agree with central differences of the compiled residuals;
- whole adjustments: the same solution and report numbers on both paths, the compiled one on
  several threads (pass images cache their trajectory in per-thread tables);
- a parameter block held constant (Ceres then asks for no Jacobian of it);
- cancellation reaches a compiled solve within an iteration.

``make test`` builds the extension and sets PBA_REQUIRE_NATIVE=1: there the compiled path must
be available (a missing build fails instead of skipping).
"""

from __future__ import annotations

import copy
import json
import os
import re
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from utils.differences import central_jacobian
from utils.scenes import block_job

from solver.engine import backend, native
from solver.engine.backend import SolveControl, build_ceres_problem
from solver.errors import Cancelled
from solver.procedures.single import prepare
from solver.schema.job import load_job
from solver.schema.settings import JobSettings

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
SAME_PHYSICS_RTOL = 1e-10  # one kernel behind both paths: only summation order may differ
SAME_PHYSICS_ATOL = 1e-10  # whitened residuals / Jacobian entries (residuals are ~1)
FD_RESIDUAL_STEP = 0.1
FD_RTOL = 2e-4  # central differences of the compiled residuals vs its analytic Jacobian
SAME_CHECK_M = 1e-4  # check-point discrepancies of two solves of one problem (0.1 mm; GSD 2.5 m)
SAME_SOLUTION_SIGMAS = 1e-4  # two solves of one problem: parameters within this fraction of their sigmas

REQUIRED = os.environ.get("PBA_REQUIRE_NATIVE") == "1"


def test_the_compiled_path_is_available_where_required() -> None:
    state = native.status()
    if REQUIRED:
        assert state.path == "compiled", state.reason
    elif state.path != "compiled":
        pytest.skip(f"compiled cost functions not available here: {state.reason}")


requires_native = pytest.mark.skipif(
    not REQUIRED and native.status().path != "compiled", reason="compiled cost functions not built (make native)"
)


def _triplet_job(model: str, **options: Any) -> dict[str, Any]:
    from solver.simulate import presets
    from solver.simulate.scene import SceneSettings

    job = presets.prism_triplet(SceneSettings(preset="prism-triplet", seed=5), gcps=8, checks=3, tie_points=12).job()
    for image in job["images"]:
        image["model"] = {"name": model}
    job.setdefault("options", {}).update(options)
    return job


def _rpc_job() -> dict[str, Any]:
    from solver.simulate import presets
    from solver.simulate.rpc import RpcSettings
    from solver.simulate.scene import SceneSettings

    settings = SceneSettings(preset="prism-triplet", seed=5, rpc=RpcSettings("RPC-DRIFT", {"a0": 5.0, "b0": -3.0}, [2, 3]))
    return presets.prism_triplet(settings, gcps=8, checks=3, tie_points=12).job()


def _fixed_control_job() -> dict[str, Any]:
    """Control points without sigma: fixed ground points, evaluated in per-image fixed blocks."""
    job, _ = block_job("P2", n_triplets=1, n_tie=10, n_gcp=8, n_check=2, seed=4, state_sigma=(20.0, 0.05))
    return job


def _lines_job(line_model: str, fitted: bool) -> dict[str, Any]:
    """Straight-line control with points (tests/utils/line_scenes.py): the line terms' three forms."""
    from utils.line_scenes import lines_job

    job, _truth = lines_job("P1", n_lines=8, line_model=line_model, fitted=fitted, endpoint_sigma_m=0.3, seed=4)
    return job


EPHEMERIS = {"ephemeris": {"sigma_position_m": 10.0, "sigma_velocity_m_s": 0.05}}
SCENES = {
    "P2 fixed control, weighted states": _fixed_control_job,
    "K2 self-calibrating": lambda: _triplet_job("K2", self_calibration={"estimate": ["df", "a0", "b0"]}),
    "OA-J2 with ephemeris": lambda: _triplet_job("OA-J2", **EPHEMERIS),
    "PASS-J2 with ephemeris, self-calibrating": lambda: _triplet_job(
        "PASS-J2", **EPHEMERIS, self_calibration={"estimate": ["df", "a0", "b0"]}
    ),
    "RPC-DRIFT beside a rigorous image": _rpc_job,
    "P1 lines, rigorous, measured points": lambda: _lines_job("rigorous", False),
    "P1 lines, rigorous, fitted image lines": lambda: _lines_job("rigorous", True),
    "P1 lines, equivalent planes": lambda: _lines_job("equivalent_planes", False),
}


def _built(job: dict[str, Any], path: str, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv(native.EVALUATION_ENV, path)
    problem = prepare(load_job(copy.deepcopy(job)))
    options = JobSettings.from_options(problem.job.options).solve
    return problem, build_ceres_problem(problem, options, SolveControl(None, None, 10))


def _evaluate(cost: Any, params: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    res, jacs = cost.evaluate(*params)  # pyceres' CostFunction.evaluate: the block's own Evaluate
    assert res is not None, "evaluation failed"
    return np.asarray(res).ravel(), [np.asarray(j) for j in jacs]


def _parameter_arrays(problem) -> list[np.ndarray]:
    """Every parameter array of a problem, in a fixed order (images, cameras, passes, points)."""
    out = [im.params for im in problem.images] + [c.params for c in problem.cameras] + [q.params for q in problem.passes]
    return out + [p.xyz for p in problem.points if p.estimated]


def _normal_equations(built) -> tuple[float, np.ndarray, np.ndarray]:
    """(cost, J^T J, J^T r) of a built problem: independent of how the residuals are grouped
    into blocks (the compiled path has one block per observation, the Python one per point)."""
    crs = built.problem.evaluate_jacobian()  # before the residuals: see ../shared/PYCERES_NOTES.md
    rows, cols, vals = crs.to_tuple()
    jac = np.zeros((crs.num_rows, crs.num_cols))
    jac[rows, cols] = vals
    res = np.asarray(built.problem.evaluate_residuals())
    return 0.5 * float(res @ res), jac.T @ jac, jac.T @ res


@requires_native
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_both_paths_give_the_same_normal_equations(scene: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every residual block of the scene on both paths: the cost, J^T J and J^T r agree, at the
    start and at a point moved off it (a fresh pass state: the trajectory segments are rebuilt)."""
    job = SCENES[scene]()
    problem_c, compiled = _built(job, "compiled", monkeypatch)
    problem_p, python = _built(job, "python", monkeypatch)
    assert compiled.python_blocks == 0 < python.python_blocks  # nothing left in Python, straight lines included
    assert any(type(c).__name__ == "CallbackCost" for c, _ in compiled.blocks)
    rng = np.random.default_rng(1)
    for scale in (0.0, 1e-6):
        for pc, pp in zip(_parameter_arrays(problem_c), _parameter_arrays(problem_p)):
            step = scale * np.abs(pc).clip(1.0) * rng.standard_normal(pc.shape)
            pc += step
            pp += step
        cost_c, n_c, g_c = _normal_equations(compiled)
        cost_p, n_p, g_p = _normal_equations(python)
        assert cost_c == pytest.approx(cost_p, rel=SAME_PHYSICS_RTOL)
        scale_n = np.sqrt(np.outer(np.diag(n_p), np.diag(n_p))) + SAME_PHYSICS_ATOL
        assert np.all(np.abs(n_c - n_p) <= SAME_PHYSICS_RTOL * scale_n)
        np.testing.assert_allclose(g_c, g_p, rtol=SAME_PHYSICS_RTOL, atol=SAME_PHYSICS_RTOL * np.sqrt(np.diag(n_p) * 2 * cost_p).max())


def _central_difference(cost: Any, params: list[np.ndarray], i: int, steps: np.ndarray) -> np.ndarray:
    """The residuals' derivatives by parameter block ``i`` (rows x its parameters)."""
    return central_jacobian(lambda block: _evaluate(cost, params[:i] + [block] + params[i + 1:])[0], params[i], steps)


@requires_native
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_compiled_jacobians_match_central_differences(scene: str, monkeypatch: pytest.MonkeyPatch) -> None:
    _, compiled = _built(SCENES[scene](), "compiled", monkeypatch)
    checked = 0
    for cost, params in compiled.blocks[:: max(1, len(compiled.blocks) // 12)]:
        if type(cost).__name__ not in ("CallbackCost", "LinearCost"):
            continue
        res, jacs = _evaluate(cost, params)
        for i, p in enumerate(params):
            analytic = jacs[i].reshape(len(res), len(p))
            # each parameter stepped so that the residuals move by about FD_RESIDUAL_STEP sigma:
            # the projection's line search (stopped at 1e-8 lines) is then noise far below the
            # change, and the model is close to linear over it
            largest = np.abs(analytic).max(axis=0)
            steps = np.where(largest > 0, FD_RESIDUAL_STEP / np.maximum(largest, 1e-300), 1.0)
            numeric = _central_difference(cost, params, i, steps)
            scale = np.abs(analytic).max() + 1e-12
            np.testing.assert_allclose(analytic / scale, numeric / scale, atol=FD_RTOL, err_msg=f"block {type(cost).__name__}, parameter block {i}")
            checked += 1
    assert checked >= 6


def _solve(job: dict[str, Any], path: str, monkeypatch: pytest.MonkeyPatch, threads: int = 2) -> dict[str, Any]:
    from solver.api import run

    monkeypatch.setenv(native.EVALUATION_ENV, path)
    monkeypatch.setenv(native.THREADS_ENV, str(threads))
    monkeypatch.setattr(backend, "PARALLEL_MIN_RESIDUAL_BLOCKS", 0)  # these small blocks too on several threads
    return run(copy.deepcopy(job))


def _assert_same_solution(a: dict[str, Any], b: dict[str, Any]) -> None:
    assert a["adjustment"]["sigma0_aposteriori"] == pytest.approx(b["adjustment"]["sigma0_aposteriori"], rel=1e-6)
    for ia, ib in zip(a["images"], b["images"]):
        for pa, pb in zip(ia["parameters"], ib["parameters"]):
            sigma = pb.get("sigma") or 0.0
            assert abs(pa["value"] - pb["value"]) <= SAME_SOLUTION_SIGMAS * sigma + 1e-12 * abs(pb["value"]), (ia["id"], pa["name"])
    for ca, cb in zip(a["checkpoints"]["points"], b["checkpoints"]["points"]):
        for axis in ("e", "n", "u"):
            if ca["discrepancy_m"][axis] is not None:
                assert ca["discrepancy_m"][axis] == pytest.approx(cb["discrepancy_m"][axis], abs=SAME_CHECK_M), (ca["id"], axis)


@requires_native
@pytest.mark.parametrize("scene", ["PASS-J2 with ephemeris, self-calibrating", "RPC-DRIFT beside a rigorous image", "P2 fixed control, weighted states"])
def test_both_paths_reach_the_same_adjustment(scene: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The compiled path on two threads (pass images then cache their segments in per-thread
    tables), on one thread and the Python path reach one solution."""
    job = SCENES[scene]()
    compiled = _solve(job, "compiled", monkeypatch, threads=2)
    python = _solve(job, "python", monkeypatch)
    _assert_same_solution(compiled, python)
    one_thread = _solve(job, "compiled", monkeypatch, threads=1)
    _assert_same_solution(compiled, one_thread)


@requires_native
def test_the_example_reports_are_the_same_on_both_paths(monkeypatch: pytest.MonkeyPatch) -> None:
    job = json.loads((EXAMPLES / "prism-triplet.json").read_text())
    _assert_same_solution(_solve(job, "compiled", monkeypatch), _solve(job, "python", monkeypatch))


@requires_native
def test_a_constant_parameter_block_gets_no_jacobian_and_the_right_step(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ceres passes no Jacobian storage for a constant block: the compiled cost function then
    hands the kernel scratch. With every image and camera held constant, Ceres must move each
    point where a Gauss-Newton intersection of its own rays (numpy, from the blocks' residuals
    and point Jacobians) puts it. (pyceres' Python cost functions cannot take constant blocks:
    its trampoline wraps the null Jacobian pointers and crashes, so the reference is computed
    here instead.)"""
    import pyceres

    problem, built = _built(SCENES["K2 self-calibrating"](), "compiled", monkeypatch)
    for img in problem.images:
        built.problem.set_parameter_block_constant(img.params)
    for cam in problem.cameras:
        if cam.nfree:
            built.problem.set_parameter_block_constant(cam.params)
    ties = {id(q.xyz): q.xyz for q in problem.points if q.role == "tie"}  # no survey prior on them
    rays: dict[int, list[tuple[Any, list[np.ndarray]]]] = {}  # a tie point's blocks (one per observation)
    for c, ps in built.blocks:
        if type(c).__name__ == "CallbackCost" and id(ps[0]) in ties:
            rays.setdefault(id(ps[0]), []).append((c, ps))
    assert rays
    start = {k: ties[k].copy() + 5.0 for k in rays}  # off the solution: the points must move
    expected = {}
    for k, blocks in rays.items():
        x = start[k].copy()
        for _ in range(20):
            parts = [_evaluate(cost, [x] + params[1:]) for cost, params in blocks]
            res = np.concatenate([r for r, _ in parts])
            j = np.vstack([jacs[0].reshape(len(r), 3) for r, jacs in parts])
            x = x - np.linalg.solve(j.T @ j, j.T @ res)
        expected[k] = x
    for k in rays:
        ties[k][:] = start[k]
    options = pyceres.SolverOptions()
    options.linear_solver_type = pyceres.LinearSolverType.SPARSE_SCHUR
    options.function_tolerance = options.parameter_tolerance = 1e-14
    options.max_num_iterations = 50
    summary = pyceres.SolverSummary()
    pyceres.solve(options, built.problem, summary)
    assert summary.IsSolutionUsable()
    np.testing.assert_allclose(np.array([ties[k] for k in rays]), np.array([expected[k] for k in rays]), atol=1e-4)


@requires_native
def test_cancel_stops_a_compiled_solve_within_an_iteration(monkeypatch: pytest.MonkeyPatch) -> None:
    """No Python runs inside a compiled evaluation: the cancel hook is polled by a watcher thread,
    and the solve ends within an iteration or two of the request (not at its 50th)."""
    from solver.api import run

    monkeypatch.setenv(native.EVALUATION_ENV, "compiled")
    job, _ = block_job("P2", n_triplets=2, n_tie=3000, n_gcp=6, n_check=2, seed=2)  # no weighted states: LM creeps
    first_iteration = threading.Event()

    def progress(fraction: float, message: str, info: dict) -> None:
        if "iteration" in info:
            first_iteration.set()

    with pytest.raises(Cancelled) as info:
        run(job, progress=progress, cancel=first_iteration.is_set)
    iterations = int(re.search(r"after (\d+) iterations", str(info.value)).group(1))
    assert iterations <= 3, str(info.value)
