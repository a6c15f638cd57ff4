"""Orbit ephemeris: Hermite interpolation to the first line, leave-one-out accuracy, and its use
as the image's approximate state and as a weighted observation (solver/observations/ephemeris.py)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from tolerances import RECOMPUTED_REL

from solver.api import run
from solver.engine.validate import validate_job
from solver.observations.ephemeris import Ephemeris, ephemeris_report, hermite, image_state
from solver.schema.job import Image, SolverOptions, load_job
from solver.simulate import presets
from solver.simulate.orbit import EarthModel, Orbit, circular_state_over, sun_synchronous_semi_major_axis
from solver.simulate.scene import SceneSettings

RMS_POSITION_M, RMS_VELOCITY_M_S = 2e-5, 3e-7  # RMS interpolation errors over the pass (measured below the max bounds)
ZERO_CORRECTION_M = 1e-6  # before the solve the Kepler state is the interpolated one

HERMITE_EXACT_ABS = 1e-9  # Hermite interpolation of a polynomial of its degree is exact: rounding of O(1) values
# interpolation at a sample's own epoch returns the sample: rounding of 7e6-m positions, 7e3-m/s velocities
AT_SAMPLE_M, AT_SAMPLE_M_S = 1e-6, 1e-9

STEP_S = 60.0  # ALOS ancillary sampling (seed 001 section 5)
ATOL_POSITION_M = 1e-4  # 0.1 mm: measured worst case 0.010 mm with 4 nodes
ATOL_VELOCITY_M_S = 1e-6  # 1 um/s: measured worst case 0.2 um/s with 4 nodes

EARTH = EarthModel()
_A = sun_synchronous_semi_major_axis(EARTH, 98.16)
# the simulator's independent J2-J4 integration (DOP853, rtol 1e-12) over +-11 minutes
ORBIT = Orbit(EARTH, circular_state_over(EARTH, -51.39, -22.12, _A, 98.16), -660.0, 660.0)
SAMPLE_T = np.arange(-600.0, 600.1, STEP_S)
SAMPLE_R, SAMPLE_V = ORBIT.state(SAMPLE_T)
EXACT = Ephemeris(SAMPLE_T, SAMPLE_R, SAMPLE_V)


def test_hermite_reproduces_a_polynomial_of_its_degree_and_its_derivative():
    rng = np.random.default_rng(1)
    for n in (1, 2, 3, 4, 5):
        coef = rng.normal(0, 1, 2 * n)  # degree 2n - 1
        poly = np.polynomial.Polynomial(coef)
        nodes = np.sort(rng.uniform(-2, 2, n)) + 0.5 * np.arange(n)
        t = np.linspace(nodes.min(), nodes.max(), 7)
        p, dp = hermite(nodes, poly(nodes), poly.deriv()(nodes), t)
        np.testing.assert_allclose(p[:, 0], poly(t), atol=HERMITE_EXACT_ABS)
        np.testing.assert_allclose(dp[:, 0], poly.deriv()(t), atol=HERMITE_EXACT_ABS)
    with pytest.raises(ValueError):
        hermite(np.array([0.0, 0.0]), np.zeros((2, 3)), np.zeros((2, 3)), 0.0)


def test_interpolation_of_a_60s_numerical_orbit_is_micrometre_accurate():
    """60-s samples of the simulator's integrated orbit, interpolated at 200 random epochs.

    Measured: 4 nodes (degree-7 Hermite, default) 0.003 mm RMS / 0.010 mm worst in position and
    0.06 um/s RMS in velocity, i.e. the accuracy of the reference integration itself; the
    two-node cubic Hermite is 0.21 m RMS / 12 mm/s and three nodes 0.05 mm / 4 um/s.
    """
    t = np.random.default_rng(2).uniform(-420.0, 420.0, 200)
    r_true, v_true = ORBIT.state(t)
    err = {}
    for nodes in (2, 4):
        got = [EXACT.interpolate(tk, nodes) for tk in t]
        dp = np.linalg.norm(np.array([g[0] for g in got]) - r_true, axis=1)
        dv = np.linalg.norm(np.array([g[1] for g in got]) - v_true, axis=1)
        err[nodes] = (float(np.sqrt(np.mean(dp**2))), dp.max(), float(np.sqrt(np.mean(dv**2))), dv.max())
    rms_p, max_p, rms_v, max_v = err[4]
    assert max_p < ATOL_POSITION_M and rms_p < RMS_POSITION_M
    assert max_v < ATOL_VELOCITY_M_S and rms_v < RMS_VELOCITY_M_S
    # the cubic (two nodes) is not good enough for a 60-s ephemeris: decimetres
    assert 0.05 < err[2][0] < 1.0


def test_leave_one_out_on_exact_samples_measures_the_interpolator():
    """Seed 001 reports 6 mm / 7 um/s (spline, real ALOS data); on exact samples of the
    simulated orbit the 4-node Hermite gives 0.003 mm / 0.03 um/s with each sample's neighbours
    120 s away."""
    loo = EXACT.leave_one_out()
    assert loo.n == len(SAMPLE_T) - 2
    assert loo.rms_position_mm < 0.05 and loo.rms_velocity_um_s < 0.5
    cubic = EXACT.leave_one_out(nodes=2)
    assert cubic.rms_position_mm > 100 * loo.rms_position_mm


def test_interpolation_is_exact_at_the_samples_and_ignores_their_order():
    doc = Image.model_validate(
        {
            "id": "a",
            "camera": "c",
            "model": {"name": "K2"},
            "first_line_time_s": float(SAMPLE_T[7]),
            "ephemeris": [
                {"time_s": float(t), "position_ecef_m": list(r), "velocity_ecef_m_s": list(v)}
                for t, r, v in reversed(list(zip(SAMPLE_T, SAMPLE_R, SAMPLE_V)))
            ],
        }
    )
    eph = Ephemeris.from_image(doc)
    assert np.all(np.diff(eph.time_s) > 0) and eph.step_s == STEP_S
    st = image_state(doc)
    np.testing.assert_allclose(st.position_ecef_m, SAMPLE_R[7], atol=AT_SAMPLE_M)
    np.testing.assert_allclose(st.velocity_ecef_m_s, SAMPLE_V[7], atol=AT_SAMPLE_M_S)
    assert st.sigma_position_m is None


@pytest.fixture(scope="module")
def triplet_job() -> dict:
    return presets.prism_triplet(SceneSettings(preset="prism-triplet", seed=5)).job()


def test_image_state_precedence(triplet_job):
    job = load_job(triplet_job)
    im = job.images[0]
    # default: the header state as written
    assert image_state(im, job.options) is im.approx_state
    # options.ephemeris: the interpolated ephemeris, with its sigmas, replaces it
    opts = SolverOptions.model_validate({"ephemeris": {"sigma_position_m": 10.0}})
    st = image_state(im, opts)
    r, _ = Ephemeris.from_image(im).interpolate(im.first_line_time_s)
    np.testing.assert_allclose(st.position_ecef_m, r)
    assert st.sigma_position_m == 10.0 and st.sigma_velocity_m_s is None
    # without approx_state, the ephemeris is the approximate state (unweighted)
    bare = im.model_copy(update={"approx_state": None})
    st = image_state(bare, job.options)
    np.testing.assert_allclose(st.position_ecef_m, r)
    assert st.sigma_position_m is None
    # nothing usable: None
    assert image_state(bare.model_copy(update={"first_line_time_s": None}), job.options) is None


def test_bad_ephemeris_is_reported_with_its_location(triplet_job):
    doc = copy.deepcopy(triplet_job)
    for im in doc["images"]:
        del im["approx_state"]
    doc["images"][0]["first_line_time_s"] = doc["images"][0]["ephemeris"][-1]["time_s"] + 30.0
    doc["images"][1]["ephemeris"][1]["time_s"] = doc["images"][1]["ephemeris"][0]["time_s"]
    del doc["images"][2]["first_line_time_s"]
    res = validate_job(load_job(doc))
    codes = {(p["code"], tuple(p["location"][:2])) for p in res["problems"]}
    assert ("ephemeris_does_not_cover_first_line", ("images", 0)) in codes
    assert ("ephemeris_duplicate_time", ("images", 1)) in codes
    assert ("ephemeris_without_first_line_time", ("images", 2)) in codes
    assert any(p["code"] == "no_initial_position" for p in res["problems"])
    with pytest.raises(ValueError):
        load_job(triplet_job | {"options": {"ephemeris": {"sigma_velocity_m_s": 1.0}}})


def test_a_job_with_only_ephemeris_runs_and_weights_it(triplet_job):
    doc = copy.deepcopy(triplet_job)
    for im in doc["images"]:
        del im["approx_state"]
    free = run(load_job(doc))
    assert free["adjustment"]["converged"]
    assert free["adjustment"]["sigma0_aposteriori"] < 1.3
    # the same job with the interpolated state written as approx_state gives the same solution
    same = copy.deepcopy(doc)
    for im_doc, im in zip(same["images"], load_job(doc).images):
        st = image_state(im)
        im_doc["approx_state"] = {"position_ecef_m": st.position_ecef_m, "velocity_ecef_m_s": st.velocity_ecef_m_s}
    again = run(load_job(same))
    assert again["adjustment"]["final_cost"] == pytest.approx(free["adjustment"]["final_cost"], rel=RECOMPUTED_REL)
    # weighted positions: three more observations per image, counted by validation too
    doc["options"] = {"ephemeris": {"sigma_position_m": 10.0}}
    job = load_job(doc)
    weighted = run(job)
    n_more = weighted["adjustment"]["n_observations"] - free["adjustment"]["n_observations"]
    assert n_more == 3 * len(doc["images"])
    assert validate_job(job)["n_observations"] == weighted["adjustment"]["n_observations"]
    assert weighted["adjustment"]["sigma0_aposteriori"] < 1.3


def test_ephemeris_report_gives_leave_one_out_and_the_adjusted_correction(triplet_job):
    from solver.adjust import prepare

    doc = copy.deepcopy(triplet_job) | {"options": {"ephemeris": {"sigma_position_m": 10.0}}}
    problem = prepare(load_job(doc))
    rep = ephemeris_report(problem)
    assert rep["nodes"] == 4 and len(rep["images"]) == 3
    for item in rep["images"]:
        assert item["used_as"] == "weighted_observation" and item["sigma_position_m"] == 10.0
        assert item["step_s"] == STEP_S and item["leave_one_out"]["n"] == item["n_samples"] - 2
        # the simulated ephemeris has 1 m / 1 mm/s white noise: leave-one-out sees the noise
        assert 0.3e3 < item["leave_one_out"]["rms_position_mm"] < 20e3
        # before the solve the Kepler state is the interpolated one: zero correction
        assert item["correction"]["position_m"] < ZERO_CORRECTION_M
