"""Jacobians of the prior terms (state priors, measured attitude, IOP priors) against central
differences of residuals recomputed from what they observe.

Each term states ``r = W (A p - b)`` with its own A. The residuals here are recomputed without
A: from the platform kernel (the line-0 position and velocity, the angle polynomials at a
sample's epoch) or from the camera's parameter vector by name; their central differences must
equal the term's Jacobian, and their values the term's residuals.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from test_attitude_obs import _samples_from
from test_orbit_pass import _pass_job
from utils.differences import central_jacobian
from utils.scenes import block_job

from solver.adjust import prepare
from solver.kernels import _attitude_angles, _attitude_time, platform_state
from solver.observations.attitude import attitude_terms
from solver.observations.ephemeris import image_state
from solver.observations.interior import camera_priors
from solver.observations.state_priors import all_state_priors
from solver.schema.job import load_job

JSON_DEGREES_SIGMA = 1e-6  # whitened attitude residuals from degrees written to and read from JSON

# the residuals are linear in p up to the kernel's own rounding: central differences with steps
# of 1e-3 of a parameter's scale agree to ~1e-9 of the largest entry; a wrong row, scale or sign
# is off by the whole entry
FD_REL = 1e-6
VALUE_ABS = 1e-9  # whitened residuals recomputed two ways


def _steps(p: np.ndarray) -> np.ndarray:
    return 1e-3 * np.maximum(np.abs(p), 1.0)


def _assert_jacobian(jac: np.ndarray, fd: np.ndarray) -> None:
    assert jac.shape == fd.shape
    assert np.max(np.abs(jac - fd)) <= FD_REL * max(np.max(np.abs(jac)), 1e-12)


@pytest.mark.parametrize("model", ["P2", "K2", "OA-J2"])
def test_state_prior_is_the_line0_state_of_the_kernel(model):
    job, _ = block_job(model, n_triplets=1, n_tie=5, n_gcp=6, n_check=2, seed=3, state_sigma=(20.0, 0.05))
    problem = prepare(load_job(job))
    terms = all_state_priors(problem)
    assert len(terms) == 3
    frame = problem.frame
    rng = np.random.default_rng(1)
    for term in terms:
        img = problem.images[term.image_index]
        doc = image_state(problem.job.images[img.index], problem.job.options)
        dt_dtau = img.camera.line_time_s / img.tau_per_line
        ecef = img.model.kind.ecef_state  # the prior's frame: the model's coefficients'

        def residual(p, img=img, doc=doc, dt_dtau=dt_dtau, ecef=ecef):
            coef = img.base.copy()
            coef[img.free_idx] = p
            s, _ds, ds_dtau = platform_state(img.kind, coef, img.kc, 0.0)[:3]
            v = np.asarray(ds_dtau) / dt_dtau
            if ecef:
                pos, vel = frame.to_ecef(np.asarray(s)[None])[0], frame.vector_to_ecef(v)
                b_pos, b_vel = np.array(doc.position_ecef_m), np.array(doc.velocity_ecef_m_s)
            else:
                pos, vel = np.asarray(s), v
                b_pos = frame.to_lgs(np.array(doc.position_ecef_m))
                b_vel = frame.vector_to_lgs(np.array(doc.velocity_ecef_m_s))
            return np.concatenate([(pos - b_pos) / doc.sigma_position_m, (vel - b_vel) / doc.sigma_velocity_m_s])

        p = img.params + rng.normal(0.0, 1e-4, img.nfree) * np.maximum(np.abs(img.params), 1.0)
        r, jac = term.evaluate(p)
        assert len(r) == 6
        np.testing.assert_allclose(r, residual(p), rtol=0, atol=VALUE_ABS * max(1.0, np.max(np.abs(r))))
        _assert_jacobian(jac, central_jacobian(residual, p, _steps(p)))


def test_measured_attitude_is_the_kernels_angles_at_each_sample():
    job = _pass_job("OA-J2")
    for im in job["images"]:
        im["model"]["options"] = {"orders": {"omega": 2, "phi": 1, "kappa": 1}}
    _samples_from(prepare(load_job(job)), job, 1.0, 0.0, np.random.default_rng(3))
    job["options"] = {"attitude": {"sigma_deg": [0.01, 0.02, 0.03]}}
    problem = prepare(load_job(job))
    terms = attitude_terms(problem)
    assert terms
    rng = np.random.default_rng(4)
    for term in terms:
        img = problem.images[term.image_index]
        doc = job["images"][term.image_index]
        w = 1.0 / np.radians([0.01, 0.02, 0.03])

        def residual(p, img=img, doc=doc, w=w):
            coef = img.base.copy()
            coef[img.free_idx] = p
            out = []
            for sample in doc["attitude"]:
                ang, rate = np.empty(3), np.empty(3)
                _attitude_angles(coef, _attitude_time(img.kind, img.kc, sample["time_s"] - doc["first_line_time_s"]), ang, rate)
                measured = np.radians([sample["roll_deg"], sample["pitch_deg"], sample["yaw_deg"]])
                out.append(w * (ang - measured))
            return np.concatenate(out)

        p = img.params + rng.normal(0.0, 1e-3, img.nfree)
        r, jac = term.evaluate(p)
        np.testing.assert_allclose(r, residual(p), rtol=0, atol=JSON_DEGREES_SIGMA)
        _assert_jacobian(jac, central_jacobian(residual, p, _steps(p)))


def test_iop_priors_observe_the_named_parameters():
    job = block_job("K2", n_triplets=1, n_tie=10, n_gcp=8, n_check=2, seed=3, chips=4, state_sigma=(20.0, 0.05))[0]
    sigmas = {"df": 0.5, "a0": 0.02, "b0": 0.01}
    job = copy.deepcopy(job)
    job["options"]["self_calibration"] = {"estimate": ["df", "a0", "b0"], "sigmas": sigmas}
    problem = prepare(load_job(job))
    priors = camera_priors(problem.cameras)
    assert len(priors) == len(problem.cameras)
    for prior in priors:
        st = problem.cameras[prior.camera_index]
        names = [st.names[i] for i in st.free_idx]
        mean = st.base[st.free_idx].copy()  # the camera's given values (zero: none given)
        sig = np.array([sigmas[n.split("@")[0]] for n in names])

        def residual(p, mean=mean, sig=sig):
            return (p - mean) / sig

        p = mean + np.random.default_rng(5).normal(0.0, 1e-3, st.nfree)
        r, jac = prior.evaluate(p)
        np.testing.assert_allclose(r, residual(p), rtol=0, atol=VALUE_ABS)
        _assert_jacobian(jac, central_jacobian(residual, p, _steps(p)))
