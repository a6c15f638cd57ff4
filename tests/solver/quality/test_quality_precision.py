"""Predicted precision of check points and leave-one-out of control points (issue 15, items 3-4).

Independent evidence:

* leave-one-out comes from downdating the solution (solver/quality/leave_one_out.py); it is
  compared with re-adjustments from scratch in which the control point is turned into a check
  point (its prior and its rays out of the adjustment, then intersected as a check point);
* the predicted sigmas are compared with the scatter of the discrepancies over noise draws on a
  scene simulated by the model itself (simulated truth): the RMS of discrepancy / predicted sigma
  must be 1 (the issue accepts 0.8-1.25).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from tolerances import RECOMPUTED_REL, SAME_NUMBER_REL
from utils.scenes import block_job

from solver.adjust import adjust_job
from solver.geometry.geodesy import LocalFrame
from solver.schema.job import load_job

ELLIPSE_BOUND_REL = 1e-9  # the ellipse's semi-axes bound the east/north sigmas: eigenvalues of a 2 x 2 matrix
AZIMUTH_DEG = 1e-9  # a hand-built ellipse's azimuth: arctan2 of eigenvector components; an east/north swap reports 90 - az

# leave-one-out is the linearised (one Gauss-Newton step) solution without the point; the
# re-adjustment iterates to convergence. Measured: the two differ by 1-1.5% of the point's
# shift (2-4 m when it is withheld, K2 triplet), the curvature of the K2 model's weak
# along-track direction. 5% of the shift + 5 mm holds that and still fails a wrong sign or a
# missing term, which move the point by its whole shift (asserted to exceed 1 m).
RTOL_SHIFT = 0.05
ATOL_POSITION_M = 5e-3
MIN_SHIFT_M = 1.0
# predicted sigmas: the same formulas at slightly different linearisation points
RTOL_SIGMA = 0.02


def _job(control: str, seed: int = 21, noise_seed: int = 5) -> dict:
    gcp_sigma = 0.5 if control == "weighted" else None
    job = block_job("K2", n_triplets=1, n_tie=20, n_gcp=8, n_check=4, seed=seed, noise_seed=noise_seed,
                    gcp_sigma_m=gcp_sigma, state_sigma=(20.0, 0.05))[0]
    job["options"]["control"] = control
    return job


def _ecef(report: dict, lgs: list[float]) -> np.ndarray:
    frame = LocalFrame.at(np.array(report["frames"]["lgs"]["origin_ecef_m"]))
    return frame.to_ecef(np.array(lgs))


@pytest.mark.parametrize("control", ["weighted", "fixed"])
def test_leave_one_out_equals_readjustment_without_the_point(control):
    job = _job(control)
    rep = adjust_job(load_job(job))
    loo = {p["id"]: p for p in rep["quality"]["leave_one_out"]["points"]}
    gcps = [p["id"] for p in job["points"] if p["role"] == "gcp"]
    assert set(loo) == set(gcps)
    for pid in gcps[:3]:
        j = copy.deepcopy(job)
        for p in j["points"]:
            if p["id"] == pid:
                p["role"] = "check"
                p.pop("sigma_m", None)
        again = adjust_job(load_job(j))
        check = next(p for p in again["checkpoints"]["points"] if p["id"] == pid)
        got = loo[pid]
        assert got["determined"]
        # the LGS origin is the centroid of the control points: one fewer moves it; compare in ECEF
        a, b = _ecef(rep, got["estimated_lgs_m"]), _ecef(again, check["estimated_lgs_m"])
        adjusted = next((p["lgs_m"] for p in rep["control_points"] if p["id"] == pid), got["known_lgs_m"])
        shift = np.linalg.norm(b - _ecef(rep, adjusted))
        assert shift > MIN_SHIFT_M, (pid, shift)
        assert np.linalg.norm(a - b) < RTOL_SHIFT * shift + ATOL_POSITION_M, (pid, a - b, shift)
        # the check point of the re-adjustment has no survey sigma; the withheld control point
        # keeps its own: compare the parts that come from the adjustment
        survey = 0.5**2 if control == "weighted" else 0.0
        for a in "enu":
            want = check["sigma_m"][a]
            # var_factor differs slightly (one control point fewer): compare scaled to sigma0
            s0_full = rep["adjustment"]["sigma0_aposteriori"]
            s0_less = again["adjustment"]["sigma0_aposteriori"]
            got_adj = np.sqrt(got["sigma_m"][a] ** 2 - survey) / s0_full
            assert got_adj == pytest.approx(want / s0_less, rel=RTOL_SIGMA), (pid, a)


def test_checkpoint_fields_are_consistent():
    rep = adjust_job(load_job(_job("weighted")))
    cp = rep["checkpoints"]
    for p in cp["points"]:
        d = p["discrepancy_m"]
        s = p["sigma_m"]
        z = p["normalised_discrepancy"]
        for a in "enu":
            assert z[a] == pytest.approx(d[a] / s[a], rel=SAME_NUMBER_REL)
        ell = p["error_ellipse"]
        # the ellipse's axes bound the axis sigmas: minor <= sigma_e, sigma_n <= major
        assert ell["semi_minor_m"] <= min(s["e"], s["n"]) * (1 + ELLIPSE_BOUND_REL)
        assert max(s["e"], s["n"]) <= ell["semi_major_m"] * (1 + ELLIPSE_BOUND_REL)
        assert ell["semi_major_m"] ** 2 + ell["semi_minor_m"] ** 2 == pytest.approx(s["e"] ** 2 + s["n"] ** 2, rel=RECOMPUTED_REL)
    emp = np.sqrt(np.mean([p["discrepancy_m"]["u"] ** 2 for p in cp["points"]]))
    pred = np.sqrt(np.mean([p["sigma_m"]["u"] ** 2 for p in cp["points"]]))
    assert cp["rmse_ratio"]["u"] == pytest.approx(emp / pred, rel=RECOMPUTED_REL)
    three = np.sqrt(np.mean([sum(p["discrepancy_m"][a] ** 2 for a in "enu") for p in cp["points"]]))
    assert cp["rmse_m"]["3d"] == pytest.approx(three, rel=RECOMPUTED_REL)


@pytest.mark.slow
def test_monte_carlo_predicted_sigmas_match_the_scatter():
    """40 noise draws (image 0.5 px, survey 0.5 m, header states 20 m / 0.05 m/s) on one K2
    triplet with 8 control, 8 check and 20 tie points: the RMS of discrepancy / predicted sigma,
    per axis, of the check points and of the withheld control points lies in 0.8-1.25 (the
    issue's acceptance). 40 x 8 points x 3 axes give each RMS to about +-4% (1 sd) with the
    points of a draw sharing the orientation error; measured 0.87-1.04."""
    check, loo = [], []
    for k in range(40):
        job = block_job("K2", n_triplets=1, n_tie=20, n_gcp=8, n_check=8, seed=21, noise_seed=9000 + k,
                        gcp_sigma_m=0.5, state_sigma=(20.0, 0.05))[0]
        rep = adjust_job(load_job(job))
        check += [[p["normalised_discrepancy"][a] for a in "enu"] for p in rep["checkpoints"]["points"]]
        loo += [[p["normalised_discrepancy"][a] for a in "enu"] for p in rep["quality"]["leave_one_out"]["points"]]
    for z in (np.array(check), np.array(loo)):
        rms = np.sqrt(np.mean(z**2, axis=0))
        assert np.all((rms > 0.8) & (rms < 1.25)), rms


@pytest.mark.parametrize("azimuth_deg", [0.0, 30.0, 75.0, 120.0, 165.0])
def test_error_ellipse_of_a_hand_built_covariance(azimuth_deg):
    """A covariance built from its ellipse: major axis 3 m along the azimuth (clockwise from
    north, so the unit vector is (east, north) = (sin az, cos az)), minor axis 1 m across it.
    An east/north swap reports 90 - az; 1e-9 deg and 1e-12 m are rounding."""
    from solver.quality.precision import error_ellipse

    a = np.radians(azimuth_deg)
    major = np.array([np.sin(a), np.cos(a)])
    minor = np.array([np.cos(a), -np.sin(a)])
    cov = 9.0 * np.outer(major, major) + 1.0 * np.outer(minor, minor)
    ell = error_ellipse(cov)
    assert ell["semi_major_m"] == pytest.approx(3.0, abs=SAME_NUMBER_REL)
    assert ell["semi_minor_m"] == pytest.approx(1.0, abs=SAME_NUMBER_REL)
    assert ell["azimuth_deg"] == pytest.approx(azimuth_deg, abs=AZIMUTH_DEG)


def _ellipse_covariance(ell: dict) -> np.ndarray:
    """The (east, north) covariance an error ellipse describes."""
    a = np.radians(ell["azimuth_deg"])
    major = np.array([np.sin(a), np.cos(a)])
    minor = np.array([np.cos(a), -np.sin(a)])
    return ell["semi_major_m"] ** 2 * np.outer(major, major) + ell["semi_minor_m"] ** 2 * np.outer(minor, minor)


def test_mono_check_point_discrepancy_test_is_chi_square_with_two_dof():
    """Check points seen in one image (mono: the ray meets the known height) have a horizontal
    discrepancy only: its test is chi-square with 2 dof, whose 1 - alpha quantile is -2 ln alpha
    (no quantile function needed), on T = d_en^T C^-1 d_en with C the covariance the point's
    error ellipse describes (which must also give its east and north sigmas)."""
    from utils.scenes import single_image_job

    job, _ = single_image_job("K2", seed=6, n_check=9)
    rep = adjust_job(load_job(job))
    alpha = rep["checkpoints"]["points"][0]["discrepancy_test"]["alpha"]
    mono = [p for p in rep["checkpoints"]["points"] if p["method"] == "mono"]
    assert len(mono) == 9
    for p in mono:
        t = p["discrepancy_test"]
        c = _ellipse_covariance(p["error_ellipse"])
        assert np.sqrt(np.diag(c)) == pytest.approx([p["sigma_m"]["e"], p["sigma_m"]["n"]], rel=RECOMPUTED_REL)
        d = np.array([p["discrepancy_m"]["e"], p["discrepancy_m"]["n"]])
        statistic = float(d @ np.linalg.solve(c, d))
        assert t["dof"] == 2
        assert t["critical"] == pytest.approx(-2.0 * np.log(alpha), rel=SAME_NUMBER_REL)
        assert t["statistic"] == pytest.approx(statistic, rel=RECOMPUTED_REL)
        assert t["passed"] is bool(statistic <= -2.0 * np.log(alpha))
