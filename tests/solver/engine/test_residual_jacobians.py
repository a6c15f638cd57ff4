"""Every residual term against central finite differences, on scenes that hold every kind of term.

Two consumers evaluate the residuals: Ceres (the cost functions of :mod:`solver.engine.backend`:
the point blocks, the fixed-point blocks, the families' terms) and the covariance
(:func:`solver.engine.linalg.linearise`: the observation blocks, the weighted control points'
survey priors and the families' terms). Both are checked here, column by column, against central
differences of their own residuals, on five scenes that together contain every observation
family of the registry (state priors, RPC bias priors, measured attitude, straight lines, pass
ephemeris samples, interior-orientation priors, DEM heights), fixed and estimated points, chips with free
interior orientation, pass-propagated and RPC images. A family added to the registry without a
scene here fails :func:`test_the_scenes_hold_every_family_and_every_cost_function`.
"""

from __future__ import annotations

import copy
import os

import numpy as np
import pytest
from test_attitude_obs import _samples_from
from test_orbit_pass import _pass_job
from test_rpc_models import _triplet
from utils.differences import central_difference_in_place
from utils.line_scenes import lines_job
from utils.scenes import block_job

from solver.adjust import prepare
from solver.engine import backend, native
from solver.engine.linalg import linearise
from solver.engine.terms import family_terms
from solver.observations import registry
from solver.schema.job import load_job
from solver.schema.settings import JobSettings

# Steps move the most sensitive residual of a column by this many sigma: large enough that the
# kernels' iterative line search (stopped at ~1e-8 line) and the rounding of 7e6-m coordinates
# stay below 1e-6 of the derivative, small enough that the curvature of the projection does too.
STEP_SIGMA = 0.1
# Analytic vs central-difference column, relative to the column's largest entry: a wrong sign,
# scale, row or column is off by the whole entry; the differences agree to ~1e-7 at STEP_SIGMA.
FD_REL = 1e-4
FD_ABS = 1e-9  # columns that are zero (a parameter a residual block does not see) must stay zero
N_POINT_COLUMNS = 4  # estimated points whose columns are differenced (each point's rows are alike)


def _orbital_scene() -> dict:
    """Orbit-attitude triplet: weighted line-0 states, two chips with free and a-priori-weighted
    interior orientation, measured attitude, fixed and weighted (estimated) control points."""
    job = block_job("OA-J2", n_triplets=1, n_tie=6, n_gcp=6, n_check=2, seed=3, chips=2, state_sigma=(20.0, 0.05))[0]
    job = copy.deepcopy(job)
    gcps = [p for p in job["points"] if p["role"] == "gcp"]
    for p in gcps[: len(gcps) // 2]:
        p["sigma_m"] = [3.0, 3.0, 5.0]
    job["options"]["self_calibration"] = {"estimate": ["df", "a0", "b0"], "sigmas": {"df": 0.5, "a0": 0.02, "b0": 0.01}}
    for im in job["images"]:
        im["first_line_time_s"] = 0.0  # the samples' time scale
    _samples_from(prepare(load_job(job)), job, 1.0, 0.001, np.random.default_rng(3))
    job["options"]["attitude"] = {"sigma_deg": [0.01, 0.02, 0.03]}
    return job


def _lines_scene() -> dict:
    """One image with rigorous straight-line control and weighted states."""
    job = lines_job("K2", n_lines=4, points_per_line=4, n_gcp=3, n_check=2, seed=2, pitch_deg=-23.8)[0]
    return job


def _pass_scene() -> dict:
    """The pass-propagated triplet with ephemeris samples and measured attitude."""
    job = _pass_job("PASS-J2", ephemeris=True)
    _samples_from(prepare(load_job(job)), job, 2.0, 0.001, np.random.default_rng(4))
    job["options"]["attitude"] = {"sigma_deg": [0.01, 0.01, 0.01]}
    return job


def _rpc_scene() -> dict:
    """RPC images with an affine bias weighted a priori."""
    job = _triplet("RPC-AFFINE", gcps=4, checks=2, ties=8)
    for im in job["images"]:
        im["bias_prior"] = {"a0": {"value": 20.0, "sigma": 0.5}, "b0": {"value": -12.0, "sigma": 0.5}}
    return job


def _dem_scene() -> dict:
    """The pass-propagated triplet's tie points on a sloped, rough DEM (an ellipsoidal grid of
    1-arc-second cells around the points, 4 m noise): the DEM heights family's terms. A term is
    linear around the position it was sampled at, so here its rows, columns and whitening are
    checked; its gradient against the DEM itself is test_dem_heights' central differences."""
    from pyproj import CRS

    from solver.geometry.dem import Dem, grid_to_job
    from solver.geometry.geodesy import ecef_to_geodetic
    from solver.geometry.vertical import resolve

    job = _pass_job("PASS-J2", ephemeris=True)
    problem = prepare(load_job(job))
    ties = [p for p in problem.points if p.role == "tie"]
    lon0, lat0, _h = ecef_to_geodetic(problem.frame.to_ecef(np.array([p.xyz for p in ties]))).mean(axis=0)
    d, n = 1.0 / 3600, 1200  # 1", 20' across: the points and their moves stay inside
    cols, rows = np.meshgrid(np.arange(n), np.arange(n))
    values = 400.0 + 0.15 * cols * 30 - 0.08 * rows * 30 + np.random.default_rng(7).normal(0, 4.0, (n, n))
    dem = Dem(values, (d, 0.0, lon0 - n * d / 2, 0.0, -d, lat0 + n * d / 2), CRS.from_epsg(4326), resolve(None, "ellipsoid"))
    job["dem"] = {"grid": grid_to_job(dem), "sigma_m": 4.0}
    return job


SCENES = {"orbital": _orbital_scene, "lines": _lines_scene, "pass": _pass_scene, "rpc": _rpc_scene, "dem": _dem_scene}


@pytest.fixture(scope="module", params=sorted(SCENES))
def scene(request):
    """(name, prepared problem) with parameters moved off the initial values (non-zero
    higher-order terms exercise every coefficient)."""
    problem = prepare(load_job(SCENES[request.param]()))
    rng = np.random.default_rng(11)
    for params in _distinct(problem):
        params += rng.normal(0.0, 1e-6, params.shape) * np.maximum(np.abs(params), 1e-3)
    return request.param, problem


def _distinct(problem) -> list[np.ndarray]:
    """The parameter arrays of the images (shared blocks once), cameras and passes."""
    out, seen = [], set()
    for arr in [im.params for im in problem.images] + [c.params for c in problem.cameras] + [p.params for p in problem.passes]:
        if len(arr) and id(arr) not in seen:
            seen.add(id(arr))
            out.append(arr)
    return out


def _assert_columns(analytic: np.ndarray, residual, x: np.ndarray, where: str) -> None:
    """Columns of ``analytic`` (rows x len(x)) against central differences of ``residual`` at
    ``x`` (perturbed in place and restored)."""
    for k in range(len(x)):
        col = analytic[:, k]
        scale = np.max(np.abs(col))
        h = STEP_SIGMA / scale if scale > 0 else 1e-6 * max(abs(x[k]), 1.0)
        fd = central_difference_in_place(residual, x, k, h)
        err = np.max(np.abs(fd - col))
        assert err <= FD_REL * scale + FD_ABS, f"{where}, column {k}: |fd - analytic| = {err:.3g} of {scale:.3g}"


def test_linearisation_matches_finite_differences_in_every_column(scene):
    """The covariance's Jacobian (observations, survey priors, every family's terms) by columns of
    the images, cameras, passes and the first estimated points."""
    name, problem = scene
    lin = linearise(problem)
    jac = lin.sparse_jacobian().toarray()
    lay = lin.layout
    blocks = []
    seen: set[int] = set()
    for im in problem.images:
        if id(im.params) not in seen and im.nfree:
            seen.add(id(im.params))
            blocks.append((f"image {im.index}", int(lay.img_col[im.index]), im.params))
    blocks += [(f"camera {c.index}", int(lay.cam_col[c.index]), c.params) for c in problem.cameras if c.nfree]
    blocks += [(f"pass {p.index}", int(lay.pass_col[p.index]), p.params) for p in problem.passes]
    est = [p for p in problem.points if p.estimated][:N_POINT_COLUMNS]
    blocks += [(f"point {p.index}", int(lay.pt_col[p.index]), p.xyz) for p in est]
    assert blocks
    for where, c0, x in blocks:
        _assert_columns(jac[:, c0 : c0 + len(x)], lambda: linearise(problem).residuals, x, f"{name}: {where}")


class _Recorder:
    """Stands in for ``pyceres.Problem``: records the residual blocks the backend adds."""

    def __init__(self):
        self.blocks: list[tuple] = []

    def add_parameter_block(self, *args) -> None:
        pass

    def add_residual_block(self, cost, loss, params) -> None:
        self.blocks.append((cost, list(params)))


def _ceres_blocks(problem, monkeypatch, path: str = "python") -> list[tuple]:
    """The residual blocks the backend builds on evaluation ``path`` ("python" or "compiled")."""
    monkeypatch.setattr(backend.pyceres, "Problem", _Recorder)
    monkeypatch.setenv("PBA_EVALUATION", path)
    settings = JobSettings.from_options(problem.job.options).solve
    built = backend.build_ceres_problem(problem, settings, backend.SolveControl(None, None, 10))
    return [(c, p) for c, p in built.problem.blocks if isinstance(c, backend.pyceres.CostFunction) and not _is_ceres_own(c)]


def _is_ceres_own(cost) -> bool:
    """Ceres' NormalPrior (the survey prior of a weighted control point): Ceres' code, checked
    through the linearisation's prior rows."""
    return type(cost).__module__.startswith("pyceres")


def _evaluate(cost, params: list[np.ndarray], n: int, with_jacobians: bool):
    """(residuals, Jacobians or None) of a Python cost function (its ``Evaluate``) or a compiled
    one (pyceres' ``evaluate``, which calls the C++ ``Evaluate`` with every Jacobian asked for)."""
    if isinstance(cost, backend.pyceres.CostFunction) and hasattr(cost, "Evaluate"):
        res = np.zeros(n)
        jacs = [np.full(n * len(p), np.nan) for p in params] if with_jacobians else None
        assert cost.Evaluate(params, res, jacs), type(cost).__name__
        return res, jacs
    res, jacs = cost.evaluate(*params)
    assert res is not None, type(cost).__name__
    return np.asarray(res).ravel(), [np.asarray(j).ravel() for j in jacs] if with_jacobians else None


@pytest.mark.parametrize("path", ["python", "compiled"])
def test_every_ceres_residual_block_matches_finite_differences(scene, monkeypatch, path):
    """Each cost function the backend gives Ceres, on both evaluation paths, each of its
    parameter blocks, against central differences of its own residuals (copies of the blocks:
    the problem is not touched)."""
    if path == "compiled" and native.status().path != "compiled":
        assert os.environ.get("PBA_REQUIRE_NATIVE") != "1", native.status().reason
        pytest.skip(f"compiled cost functions not built here: {native.status().reason}")
    name, problem = scene
    blocks = _ceres_blocks(problem, monkeypatch, path)
    assert blocks
    for cost, params in blocks:
        params = [np.array(p, dtype=float) for p in params]
        n = cost.num_residuals()
        res, jacs = _evaluate(cost, params, n, True)

        def residual(cost=cost, params=params, n=n):
            return _evaluate(cost, params, n, False)[0]

        np.testing.assert_array_equal(residual(), res)  # the Jacobian call wrote the same residuals
        for b, (p, jac) in enumerate(zip(params, jacs)):
            _assert_columns(jac.reshape(n, len(p)), residual, p, f"{name}: {type(cost).__name__} block {b}")


def test_the_scenes_hold_every_family_and_every_cost_function(monkeypatch):
    """The scenes above are only evidence for the terms they contain: every registered family
    has terms in some scene, and every cost function class of the backend appears."""
    families: set[str] = set()
    costs: set[str] = set()
    compiled: set[str] = set()
    for make in SCENES.values():
        problem = prepare(load_job(make()))
        families |= {t.family.name for t in family_terms(problem)}
        costs |= {type(c).__name__ for c, _ in _ceres_blocks(problem, monkeypatch)}
        if native.status().path == "compiled":
            compiled |= {type(c).__name__ for c, _ in _ceres_blocks(problem, monkeypatch, "compiled")}
    assert families == {f.name for f in registry.FAMILIES}
    assert costs == {"PointCost", "ImageBatchCost", "ImageTermCost"}
    if native.status().path == "compiled":  # the lines' terms stay Python cost functions
        assert compiled == {"CallbackCost", "LinearCost", "ImageTermCost"}
