"""Large least-squares blocks split each point's observations into residual blocks of at most
three (solver.engine.backend.split_rays): the same sum of squares in smaller Jacobian cells.
Checked against the report's own linearisation (solver.engine.linalg, assembled independently
of the Ceres blocks), against the unsplit layout, and on the solve's outcome."""

from __future__ import annotations

import collections
import copy
from typing import Any

import numpy as np
import pytest
import scipy.sparse as sp
from utils.scenes import connected_strip_job

from solver.engine import backend
from solver.engine.backend import SolveControl, build_ceres_problem
from solver.engine.linalg import linearise
from solver.procedures.single import prepare, solve_problem
from solver.schema.job import load_job
from solver.schema.settings import JobSettings

SAME_RTOL = 1e-10  # the same kernels either way: only summation order may differ


@pytest.fixture(scope="module")
def strip() -> dict[str, Any]:
    """A connected strip with more estimated points than the split threshold, points in 3 to 6
    images, weighted control (survey priors on split points)."""
    job, _truth = connected_strip_job("P2", n_triplets=2, points_per_triplet=1150, n_gcp=20, n_check=2, seed=11)
    for point in job["points"]:
        if point["role"] == "gcp":
            point["sigma_m"] = [0.5, 0.5, 1.0]  # surveyed: estimated, with a prior
    return job


def _built(job: dict[str, Any]):
    problem = prepare(load_job(copy.deepcopy(job)))
    options = JobSettings.from_options(problem.job.options).solve
    return problem, build_ceres_problem(problem, options, SolveControl(None, None, 10))


def _normal_equations(built) -> tuple[float, sp.csr_matrix, np.ndarray]:
    """(cost, J^T J, J^T r) of a built problem: independent of how residuals are grouped in blocks."""
    crs = built.problem.evaluate_jacobian()  # before the residuals: see ../shared/PYCERES_NOTES.md
    rows, cols, vals = crs.to_tuple()
    jac = sp.csr_matrix((vals, (rows, cols)), shape=(crs.num_rows, crs.num_cols))
    res = np.asarray(built.problem.evaluate_residuals())
    return 0.5 * float(res @ res), (jac.T @ jac).tocsr(), jac.T @ res


def test_large_blocks_hold_at_most_three_rays_of_a_point_and_each_survey_once(strip) -> None:
    problem, built = _built(strip)
    assert backend.split_rays(problem, None) == backend.SPLIT_RAYS
    rays_of = np.bincount(problem.obs.pt[problem.adjusted_mask])
    rays = collections.Counter(rays_of.tolist())
    assert max(rays) == 6 and rays[6] > 100  # points in the overlaps: split in two
    point_blocks = [(cost, params) for cost, params in built.blocks if len(params) > 1]  # [point, image(s)]
    assert max(cost.num_residuals() for cost, _ in point_blocks) == 2 * backend.SPLIT_RAYS
    estimated = np.array([p.estimated for p in problem.points])
    assert sum(cost.num_residuals() for cost, _ in point_blocks) == 2 * int((problem.adjusted_mask & estimated[problem.obs.pt]).sum())
    priors = [params[0] for cost, params in built.blocks if len(params) == 1 and cost.num_residuals() == 3]  # survey priors
    weighted = [p for p in problem.points if p.estimated and p.role == "gcp" and p.sigma_m is not None]
    assert len(weighted) == 20 and len(priors) == len(weighted)
    assert max(rays_of[p.index] for p in weighted) > backend.SPLIT_RAYS  # surveyed points split too
    assert {id(a) for a in priors} == {id(p.xyz) for p in weighted}
    # the Ceres cost is the report's: 0.5 |r|^2 of the independent linearisation (priors included)
    lin = linearise(problem)
    assert _normal_equations(built)[0] == pytest.approx(0.5 * float(lin.residuals @ lin.residuals), rel=SAME_RTOL)


def test_the_split_layout_has_the_normal_equations_of_one_block_per_point(strip, monkeypatch) -> None:
    _problem_s, split = _built(strip)
    monkeypatch.setattr(backend, "split_rays", lambda problem, loss: None)
    _problem_w, whole = _built(strip)
    assert len(split.blocks) > len(whole.blocks)
    cost_s, n_s, g_s = _normal_equations(split)
    cost_w, n_w, g_w = _normal_equations(whole)
    assert cost_s == pytest.approx(cost_w, rel=SAME_RTOL)
    d = np.sqrt(n_w.diagonal())
    scaled = sp.diags(1.0 / d) @ (n_s - n_w) @ sp.diags(1.0 / d)
    assert abs(scaled).max() <= SAME_RTOL
    np.testing.assert_allclose(g_s, g_w, rtol=SAME_RTOL, atol=SAME_RTOL * np.abs(g_w).max())


def test_the_split_solve_reaches_the_same_solution(strip, monkeypatch) -> None:
    def solved() -> tuple[Any, np.ndarray]:
        problem = prepare(load_job(copy.deepcopy(strip)))
        outcome = solve_problem(problem, SolveControl(None, None, 50))
        return outcome, np.concatenate([im.params for im in problem.images] + [p.xyz for p in problem.points if p.estimated])

    split, x_split = solved()
    monkeypatch.setattr(backend, "split_rays", lambda problem, loss: None)
    whole, x_whole = solved()
    assert split.converged and whole.converged
    assert split.iterations == whole.iterations
    assert split.final_cost == pytest.approx(whole.final_cost, rel=1e-9)
    np.testing.assert_allclose(x_split, x_whole, rtol=1e-7, atol=1e-6)


def test_small_and_robust_blocks_keep_one_block_per_point(strip) -> None:
    problem = prepare(load_job(copy.deepcopy(strip)))
    assert backend.split_rays(problem, backend.pyceres.HuberLoss(1.0)) is None  # a loss acts on each block's own sum
    small, _truth = connected_strip_job("P2", n_triplets=2, points_per_triplet=150, n_gcp=4, n_check=1, seed=3)
    assert backend.split_rays(prepare(load_job(small)), None) is None
