"""Monte Carlo: the reported sigmas match the empirical scatter of the estimates.

One geometry, many independent draws of the measurement noise (image coordinates, survey
coordinates of weighted control, header states given as weighted observations). For every
estimated parameter, ratio = empirical std / RMS of the reported sigmas.

Weakly determined directions: for a single image with a Kepler model (K2, no state
observations) the position and pitch (X0, Z0, phi) scatter only 0.72-0.8 of the linear
prediction. Pitch and along-track position are nearly interchangeable (condition ~1e11), the
estimates spread along a curved valley of the cost, and the linear (tangent) covariance
overstates their spread in the individual coordinates. With the header state as a weighted
observation (seed 001 practice) the valley is closed and the ratios return to 1.
"""

from __future__ import annotations

import numpy as np
import pytest
from utils.scenes import block_job, single_image_job

from solver.adjust import adjust_job
from solver.schema.job import load_job

pytestmark = pytest.mark.slow


def _collect(jobs):
    vals, sigs, s0, tie_v, tie_s = [], [], [], [], []
    for job in jobs:
        rep = adjust_job(load_job(job))
        ps = [p for im in rep["images"] for p in im["parameters"] if p["estimated"]]
        vals.append([p["value"] for p in ps])
        sigs.append([p["sigma"] for p in ps])
        s0.append(rep["adjustment"]["sigma0_aposteriori"])
        tie_v.append([x for t in rep["tie_points"] for x in t["lgs_m"]])
        tie_s.append([x for t in rep["tie_points"] for x in t["sigma_m"]])
    names = [p["name"] for p in ps]

    def ratio(v, s):
        v, s = np.array(v), np.array(s)
        return v.std(axis=0, ddof=1) / np.sqrt(np.mean(s**2, axis=0))

    tie = ratio(tie_v, tie_s) if tie_v and tie_v[0] else np.array([])
    return names, ratio(vals, sigs), tie, np.array(s0)


def test_single_tilted_image_polynomial_model():
    """Backward camera (-23.8 deg), P2, 14 fixed control points, 0.5 px, 200 draws."""
    jobs = (single_image_job("P2", seed=11, noise_seed=1000 + k, pitch_deg=-23.8, control="fixed")[0] for k in range(200))
    names, ratio, _tie, s0 = _collect(jobs)
    assert abs(np.median(ratio) - 1.0) < 0.15, dict(zip(names, ratio.round(3)))
    assert abs(np.mean(s0) - 1.0) < 0.05
    assert np.all((ratio > 0.7) & (ratio < 1.3)), dict(zip(names, ratio.round(3)))


def test_single_image_kepler_model_weak_directions():
    """Nadir K2: median within 15%; the weak position/pitch directions scatter less (see top)."""
    jobs = (single_image_job("K2", seed=11, noise_seed=2000 + k, control="fixed")[0] for k in range(200))
    names, ratio, _tie, s0 = _collect(jobs)
    r = dict(zip(names, ratio))
    assert abs(np.median(ratio) - 1.0) < 0.15, r
    assert abs(np.mean(s0) - 1.0) < 0.05
    for well in ("ux", "uy", "uz", "omega", "kappa"):
        assert 0.8 < r[well] < 1.2, r
    # the weak directions (top: 0.72-0.8 measured); 200 draws give a ratio +-0.05 (1 sd), so
    # 0.55-0.97 holds the documented range with three sd either side and still catches a
    # calibrated (1.0) or a doubled sigma
    for weak in ("X0", "Z0", "phi"):
        assert 0.55 < r[weak] < 0.97, r
    for other in set(names) - {"ux", "uy", "uz", "omega", "kappa", "X0", "Z0", "phi"}:
        assert 0.7 < r[other] < 1.3, r


def test_triplet_with_tie_points_and_weighted_states():
    """K2 triplet, 20 tie points, weighted control (0.5 m) and header states (20 m, 0.05 m/s)."""
    jobs = (
        block_job("K2", n_triplets=1, n_tie=20, n_gcp=10, n_check=5, seed=21, noise_seed=5000 + k,
                  state_sigma=(20.0, 0.05), gcp_sigma_m=0.5)[0]
        for k in range(100)
    )
    names, ratio, tie, s0 = _collect(jobs)
    assert abs(np.median(ratio) - 1.0) < 0.15
    assert abs(np.median(tie) - 1.0) < 0.15
    assert abs(np.mean(s0) - 1.0) < 0.05
    # every parameter and tie coordinate: the weighted states close the weak valley (top), so
    # each ratio is 1 within sampling (100 draws: +-0.07 per ratio, 1 sd); 0.7-1.3 is > 4 sd
    assert np.all((ratio > 0.7) & (ratio < 1.3)), dict(zip(names, ratio.round(3)))
    assert np.all((tie > 0.7) & (tie < 1.3)), tie.round(3)
