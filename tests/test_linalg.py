"""Covariance and leverages by Schur elimination against a direct dense inverse of J^T J."""

from __future__ import annotations

import numpy as np
import pytest
from tolerances import REDUNDANCY_SUM_ABS

from solver.adjust import prepare
from solver.engine.linalg import covariance, linearise, schur
from solver.schema.job import load_job
from solver.synthetic import block_job

# covariances on the correlation scale: position-pitch coupling makes N ill-conditioned
# (cond ~5e11), so any route loses about that many digits (cond * eps ~ 1e-4)
CORRELATION_ABS = 1e-4
LEVERAGE_ABS = 1e-3  # leverages without state priors: the same conditioning
LEVERAGE_PRIOR_ABS = 1e-5  # with weighted states the normal matrix is better conditioned


@pytest.mark.parametrize("model,state_sigma", [("P2", None), ("K2", (20.0, 0.05))])
def test_schur_covariance_equals_direct_inverse(model, state_sigma):
    job, _ = block_job(model, n_triplets=1, n_tie=12, n_gcp=8, n_check=3, seed=4, gcp_sigma_m=0.5, state_sigma=state_sigma)
    problem = prepare(load_job(job))
    lin = linearise(problem)
    parts = schur(lin, problem)
    cov = covariance(lin, parts, problem)
    jac = lin.sparse_jacobian().toarray()
    assert jac.shape[0] == len(lin.residuals)
    # reference: SVD of the column-scaled Jacobian (the most accurate route)
    d = np.sqrt((jac**2).sum(axis=0))
    _u, sv, vt = np.linalg.svd(jac / d, full_matrices=False)
    q = (vt.T / sv**2) @ vt / np.outer(d, d)
    n = lin.layout.n_img_params

    def same(a, b):
        s = np.sqrt(np.outer(np.diag(b), np.diag(b)))
        assert np.max(np.abs(a - b) / s) < CORRELATION_ABS

    same(cov.images, q[:n, :n])
    for pidx, c in cov.points.items():
        c0 = lin.layout.pt_col[pidx]
        same(c, q[c0 : c0 + 3, c0 : c0 + 3])
    h = np.einsum("ij,jk,ik->i", jac[: lin.n_obs_rows], q, jac[: lin.n_obs_rows])
    np.testing.assert_allclose(cov.leverage, h, atol=LEVERAGE_ABS if state_sigma is None else LEVERAGE_PRIOR_ABS)
    # redundancy numbers add up to the degrees of freedom (with the prior rows)
    h_all = np.einsum("ij,jk,ik->i", jac, q, jac)
    assert (1 - h_all).sum() == pytest.approx(jac.shape[0] - jac.shape[1], abs=REDUNDANCY_SUM_ABS)
