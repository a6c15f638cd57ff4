"""Measured attitude with a common error per attitude block and angle
(``options.attitude.bias_sigma_deg``): the whitened residuals against the covariance
``sigma_w^2 I + sigma_b^2 11^T`` built and inverted directly with numpy, their Jacobian against
central differences of the projection kernel's own angles, the independent model unchanged
without a bias, both evaluation paths agreeing, and data snooping of one sample."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from test_attitude_obs import _samples_from
from test_orbit_pass import _pass_job
from test_prior_jacobians import _assert_jacobian, _steps
from utils.differences import central_jacobian

from solver.adjust import prepare
from solver.api import run
from solver.kernels import _attitude_angles, _attitude_time
from solver.observations.attitude import attitude_terms, bias_shrink
from solver.observations.state_priors import StatePrior
from solver.schema.job import load_job

WHITE_DEG = (0.0005, 0.001, 0.002)
BIAS_DEG = (0.003, 0.0, 0.01)  # a zero bias (pitch): that angle's samples stay independent
COST_REL = 1e-10  # r^T r against r^T Sigma^-1 r (numpy's solve of a 3n x 3n covariance of condition ~1e3)
JSON_DEGREES_SIGMA = 1e-6  # whitened residuals from degrees written to and read from JSON


def _job(bias, model: str = "OA-J2") -> dict:
    job = _pass_job(model)
    for im in job["images"]:
        im["model"]["options"] = {"orders": {"omega": 2, "phi": 1, "kappa": 1}}
    _samples_from(prepare(load_job(job)), job, 1.0, 0.001, np.random.default_rng(3))
    job["options"] = {"attitude": {"sigma_deg": list(WHITE_DEG), **({"bias_sigma_deg": list(bias)} if bias is not None else {})}}
    return job


def _covariance(n: int, white=WHITE_DEG, bias=BIAS_DEG) -> np.ndarray:
    """Sigma of a block's 3n rows (sample by sample: roll, pitch, yaw), rad^2, written out."""
    cov = np.zeros((3 * n, 3 * n))
    for e in range(3):
        rows = 3 * np.arange(n) + e
        cov[np.ix_(rows, rows)] = math.radians(bias[e]) ** 2 + np.diag(np.full(n, math.radians(white[e]) ** 2))
    return cov


def test_bias_shrink_is_the_inverse_square_root() -> None:
    for n, sw, sb in [(1, 1.0, 1.0), (55, 1e-5, 1e-3), (10, 2.0, 0.5), (4, 1.0, 0.0)]:
        c = bias_shrink(n, sw, sb)
        t = (np.eye(n) - c / n) / sw
        sigma = sw**2 * np.eye(n) + sb**2
        np.testing.assert_allclose(t @ sigma @ t, np.eye(n), rtol=0, atol=1e-9)  # condition up to 5e5


@pytest.mark.parametrize("model", ["OA-J2", "PASS-J2"])
def test_whitened_cost_is_the_mahalanobis_norm(model) -> None:
    """r^T r of each block's whitened residuals equals (A p - b)^T Sigma^-1 (A p - b) with Sigma
    written out and solved with numpy (relative 1e-10), at arbitrary parameters; so does the
    normal matrix J^T J = A^T Sigma^-1 A."""
    problem = prepare(load_job(_job(BIAS_DEG, model)))
    rng = np.random.default_rng(7)
    terms = attitude_terms(problem)
    assert terms
    for term in terms:
        img = problem.images[term.image_index]
        p = img.params + rng.normal(0.0, 1e-4, img.nfree)
        r, jac = term.evaluate(p)
        raw = term.a @ p - term.b
        cov = _covariance(len(raw) // 3)
        expected = float(raw @ np.linalg.solve(cov, raw))
        assert abs(float(r @ r) - expected) <= COST_REL * expected
        normal = term.a.T @ np.linalg.solve(cov, term.a)
        np.testing.assert_allclose(jac.T @ jac, normal, rtol=COST_REL, atol=COST_REL * np.abs(normal).max())
        a, b = term.linear_form()  # the compiled path's constant form: the same residuals
        np.testing.assert_allclose(a @ p - b, r, rtol=0, atol=1e-9 * np.abs(r).max())
        np.testing.assert_array_equal(a, jac)


def test_jacobian_by_central_differences_of_the_kernels_angles() -> None:
    """The whitened residuals recomputed from the projection kernel's angle polynomials at each
    sample, whitened by Sigma^(-1/2) from numpy's eigen-decomposition: same values, and the term's
    Jacobian equals their central differences."""
    job = _job(BIAS_DEG)
    problem = prepare(load_job(job))
    rng = np.random.default_rng(4)
    for term in attitude_terms(problem):
        img = problem.images[term.image_index]
        doc = job["images"][term.image_index]
        vals, vecs = np.linalg.eigh(_covariance(len(doc["attitude"])))
        inv_sqrt = vecs @ np.diag(vals**-0.5) @ vecs.T

        def residual(p, img=img, doc=doc, inv_sqrt=inv_sqrt):
            coef = img.base.copy()
            coef[img.free_idx] = p
            out = []
            for sample in doc["attitude"]:
                ang, rate = np.empty(3), np.empty(3)
                _attitude_angles(coef, _attitude_time(img.kind, img.kc, sample["time_s"] - doc["first_line_time_s"]), ang, rate)
                out.append(ang - np.radians([sample["roll_deg"], sample["pitch_deg"], sample["yaw_deg"]]))
            return inv_sqrt @ np.concatenate(out)

        p = img.params + rng.normal(0.0, 1e-3, img.nfree)
        r, jac = term.evaluate(p)
        np.testing.assert_allclose(r, residual(p), rtol=0, atol=JSON_DEGREES_SIGMA * max(1.0, np.abs(r).max()))
        _assert_jacobian(jac, central_jacobian(residual, p, _steps(p)))


def test_without_a_bias_the_samples_are_independent_as_before() -> None:
    """bias_sigma_deg null: the residuals, Jacobian and linear form are bit for bit those of the
    independent model ``W (A p - b)``; a zero bias gives the same to rounding."""
    none = attitude_terms(prepare(load_job(_job(None))))
    zero = attitude_terms(prepare(load_job(_job((0.0, 0.0, 0.0)))))
    rng = np.random.default_rng(2)
    for t0, tz in zip(none, zero, strict=True):
        assert t0.shrink is None
        p = rng.normal(0.0, 1e-3, t0.a.shape[1])
        plain = StatePrior(t0.image_index, t0.a, t0.b, t0.w)
        for got, ref in zip(t0.evaluate(p) + t0.linear_form(), plain.evaluate(p) + plain.linear_form()):
            np.testing.assert_array_equal(got, ref)
        for got, ref in zip(tz.evaluate(p), t0.evaluate(p)):
            np.testing.assert_allclose(got, ref, rtol=1e-14, atol=0)


def _direct_job() -> dict:
    return json.loads((Path(__file__).resolve().parents[3] / "examples" / "prism-triplet-direct.json").read_text())


@pytest.mark.slow
@pytest.mark.parametrize("path", ["compiled", "python"])
def test_both_evaluation_paths_agree(monkeypatch, path) -> None:
    """The simulated triplet without control, its attitude with a common error: the report's
    sigma0, attitude residuals and parameters are the same on both evaluation paths (the
    compiled path's LinearCost takes the whitened linear form, the Python path evaluates it)."""
    job = _direct_job()
    job["options"]["attitude"]["bias_sigma_deg"] = [0.005, 0.005, 0.005]
    monkeypatch.setenv("PBA_EVALUATION", "compiled")
    ref = run(copy.deepcopy(job))
    monkeypatch.setenv("PBA_EVALUATION", path)
    rep = run(copy.deepcopy(job))
    assert rep["adjustment"]["converged"]
    assert rep["adjustment"]["sigma0_aposteriori"] == pytest.approx(ref["adjustment"]["sigma0_aposteriori"], rel=1e-6)
    for a, b in zip(rep["attitude"], ref["attitude"], strict=True):
        np.testing.assert_allclose(a["rms_residual_deg"], b["rms_residual_deg"], rtol=1e-6, atol=1e-9)
    for a, b in zip(rep["images"], ref["images"], strict=True):
        np.testing.assert_allclose([q["value"] for q in a["parameters"]], [q["value"] for q in b["parameters"]], rtol=1e-7, atol=1e-9)


ATTITUDE_ESTIMATE_DEG = 0.006  # three white sigmas (0.002 deg) of the sample over its redundancy


@pytest.mark.slow
def test_a_blunder_in_one_sample_is_found_at_that_sample() -> None:
    """Data snooping with a common error (the w-test of a sample on its three whitened rows: its
    departure from the block's common error): the simulated triplet's clean run rejects
    nothing; one sample's pitch moved 0.02 deg (10 white sigmas) is the one rejected, with an
    estimated error of the blunder less the part the block's mean carries (c/n of it, 0.14 here)."""
    job = _direct_job()
    job["options"]["attitude"]["bias_sigma_deg"] = [0.005, 0.005, 0.005]
    job["options"]["blunder_detection"] = {}
    clean = run(copy.deepcopy(job))
    assert clean["quality"]["rejected"] == [] and clean["quality"]["not_identifiable"] == []
    sample = job["images"][1]["attitude"][2]
    sample["pitch_deg"] += 0.02
    rep = run(job)
    (r,) = rep["quality"]["rejected"]
    assert (r["kind"], r["time_s"], r["removed"]) == ("attitude_sample", sample["time_s"], True)
    n = len(job["images"][1]["attitude"])
    seen = 0.02 * (1.0 - bias_shrink(n, 0.002, 0.005) / n)
    np.testing.assert_allclose(r["estimated_error"], [0.0, seen, 0.0], atol=ATTITUDE_ESTIMATE_DEG)
    assert sum(a["n_samples"] for a in rep["attitude"]) == sum(a["n_samples"] for a in clean["attitude"]) - 1
