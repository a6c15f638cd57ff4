"""Straight-line observations (solver/observations/lines.py): Jacobians, recovery, combined adjustment, errors."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
from utils.differences import central_difference
from utils.line_scenes import lines_job
from utils.scenes import single_image_job, truth_parameters

from solver.adjust import prepare
from solver.api import run, validate
from solver.engine.terms import family_terms
from solver.errors import JobError
from solver.kernels import project
from solver.kernels.layout import FORM_X, FORM_Y
from solver.kernels.lines import line_distances, planes_model, pushbroom_line, two_point_line
from solver.observations.lines import LineTerm
from solver.platforms import get_model, model_names
from solver.schema.job import load_job

LINE_FIT_PX = 1e-9  # a fitted line's points lie on it: one multiplication and addition
CURVED_LINE_PX = 2e-3  # distances to a curved image line 40 px long: ~1e-3 px of curvature
DISTANCE_ABS = 1e-9  # the same distances whatever earlier evaluations left: rounding
SEARCH_PARAMETER = 1e-6  # where the search along the ground line stops (a parameter of the segment, 0..1)
LGS_ORIGIN_M = 1e-3  # the LGS origin at the control lines' centroid, recomputed from ECEF points

# the pass-propagated models need passes (several images, epochs) that the per-image synthetic
# scenes here do not have; tests/solver/platforms/test_orbit_pass.py covers their Jacobians and projections;
# the RPC bias models have no camera (tests/solver/platforms/test_rpc_models.py)
PER_IMAGE_MODELS = [m for m in model_names() if get_model(m).kind.position_from_image_state]

REL_TOL = 2e-5  # central differences vs analytic, relative to the largest derivative of the column
# plus the differences' own rounding, eps |f| / h, in units of it (f carries a few ulps of its
# computation): where the step is capped (an insensitive parameter) and the residuals are large,
# as at an initial orientation kilometres off, rounding alone reaches REL_TOL (measured: 2.1e-5 of
# a column at its capped step of 1e-3, 2.3e-6 at a step 1e5 times longer)
ROUNDING_ULPS = 4.0
PIXELS = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 1.0])


def _problem(model: str, **kw):
    """Prepared problem with its line state started at the initial orientation."""
    from solver.observations.lines import start

    job, truth = lines_job(model, **kw)
    problem = prepare(load_job(job))
    start(problem)
    return problem, job, truth


def _perturbed_coef(img) -> np.ndarray:
    """Current coefficients with non-zero higher-order terms, so that every term is exercised."""
    coef = img.coef()
    coef[img.free_idx] += np.where(np.abs(coef[img.free_idx]) > 0, 0, 1e-7)
    return coef


def _check_columns(f, x0: np.ndarray, analytic: np.ndarray, cols, target_change: float | None = None, step: float | None = None) -> None:
    """Central differences of vector function f at x0 along ``cols`` against analytic[:, col].

    The step moves f by about ``target_change`` (coefficients: rounding and truncation errors both
    small), or is ``step`` (object coordinates, metres); the tolerance is relative to the largest
    derivative of the column, or with ``step`` of all the columns checked (a point moved along its
    own line changes the distances only at second order).
    """
    whole = float(np.max(np.abs(analytic[:, list(cols)])))
    for j in cols:
        scale = float(np.max(np.abs(analytic[:, j])))
        if scale == 0.0 and step is None:
            continue
        # (a step that moves f by target_change, but at most 0.1 % of the parameter: an insensitive
        # parameter, such as the height in the equivalent planes model, would otherwise get a huge one)
        h = step if step is not None else min(target_change / scale, 1e-3 * max(1.0, abs(float(x0[j]))))
        fd = central_difference(f, x0, j, h)
        rounding = ROUNDING_ULPS * np.finfo(float).eps * float(np.max(np.abs(f(x0)))) / h
        tol = REL_TOL * (whole if step is not None else scale) + rounding
        np.testing.assert_allclose(fd, analytic[:, j], rtol=0, atol=tol, err_msg=f"column {j}")


def test_two_point_line_matches_equations_5_6_and_its_jacobian():
    x1, y1, x2, y2 = 0.3, -1.2, 4.1, 0.7
    a, b, j = two_point_line(FORM_Y, x1, y1, x2, y2)
    assert a == pytest.approx((y2 - y1) / (x2 - x1)) and b == pytest.approx((y1 * x2 - x1 * y2) / (x2 - x1))
    a2, b2, j2 = two_point_line(FORM_X, x1, y1, x2, y2)
    assert a2 == pytest.approx((x2 - x1) / (y2 - y1)) and b2 == pytest.approx(-(y1 * x2 - x1 * y2) / (y2 - y1))
    for form, jac in ((FORM_Y, j), (FORM_X, j2)):
        def f(v, form=form):
            a_, b_, _ = two_point_line(form, *v)
            return np.array([a_, b_])

        _check_columns(f, np.array([x1, y1, x2, y2]), jac, range(4), 1e-4)


@pytest.mark.parametrize("model", PER_IMAGE_MODELS)
@pytest.mark.parametrize("pitch", [0.0, -23.8])
def test_equivalent_planes_jacobian_matches_finite_differences(model, pitch):
    opts_model = "P2" if model == "GENERAL" else model  # GENERAL needs options; P2 has the same form
    problem, _job, _truth = _problem(opts_model, n_lines=8, pitch_deg=pitch, line_model="equivalent_planes", seed=5)
    img = problem.images[0]
    coef = _perturbed_coef(img)
    f_mm = img.camera.focal_mm
    for li in problem.lines.active():
        gl = problem.lines.lines[li.line]
        tau = li.ref_line * img.tau_per_line
        ab, jc, jp = planes_model(img.kind, coef, img.kc, gl.p1, gl.p2, tau, f_mm, li.form, True)
        np.testing.assert_allclose(planes_model(img.kind, coef, img.kc, gl.p1, gl.p2, tau, f_mm, li.form, False)[0], ab)
        _check_columns(
            lambda c: planes_model(img.kind, c, img.kc, gl.p1, gl.p2, tau, f_mm, li.form, False)[0], coef, jc, img.free_idx, 1e-5
        )
        ends = np.concatenate([gl.p1, gl.p2])
        _check_columns(
            lambda e: planes_model(img.kind, coef, img.kc, e[:3].copy(), e[3:].copy(), tau, f_mm, li.form, False)[0], ends, jp, range(6), step=1.0
        )


def test_equivalent_planes_is_the_frame_projection_of_the_line():
    """Eqs 3-4 give the image line through the frame-camera projections of any two object points."""
    from solver.kernels.lines import frame_xy

    problem, _job, _truth = _problem("K2", n_lines=8, line_model="equivalent_planes", seed=2)
    img = problem.images[0]
    coef = img.coef()
    for li in problem.lines.active():
        gl = problem.lines.lines[li.line]
        tau = li.ref_line * img.tau_per_line
        ab = planes_model(img.kind, coef, img.kc, gl.p1, gl.p2, tau, img.camera.focal_mm, li.form, False)[0]
        for t in (-0.3, 0.4, 1.7):
            x, y = frame_xy(img.kind, coef, img.kc, tau, gl.p1 + t * (gl.p2 - gl.p1), img.camera.focal_mm)
            if li.form == FORM_Y:
                assert y == pytest.approx(ab[0] * x + ab[1], abs=LINE_FIT_PX)
            else:
                assert x == pytest.approx(ab[0] * y + ab[1], abs=LINE_FIT_PX)


@pytest.mark.parametrize("model", PER_IMAGE_MODELS)
@pytest.mark.parametrize("pitch", [0.0, -23.8])
def test_rigorous_distance_jacobian_matches_finite_differences(model, pitch):
    opts_model = "P2" if model == "GENERAL" else model
    problem, _job, _truth = _problem(opts_model, n_lines=5, pitch_deg=pitch, seed=6)
    img = problem.images[0]
    coef = _perturbed_coef(img)
    for li in problem.lines.active():
        gl = problem.lines.lines[li.line]
        s = li.s.copy()
        ok, d, jc, jp = line_distances(img.kind, coef, img.kc, gl.p1, gl.p2, li.ocs, s, True)
        assert ok

        def dist(c, e=None):
            e = np.concatenate([gl.p1, gl.p2]) if e is None else e
            return line_distances(img.kind, c, img.kc, e[:3].copy(), e[3:].copy(), li.ocs, s.copy(), False)[1]

        _check_columns(dist, coef, jc, img.free_idx, 0.3)
        _check_columns(lambda e: dist(coef, e), np.concatenate([gl.p1, gl.p2]), jp, range(6), step=1.0)


def test_rigorous_distance_is_zero_on_the_projected_line_and_perpendicular():
    """Image points of the exact projection have distance 0; a point moved by delta along the
    normal of the projected line has distance delta (and moving along the line changes nothing)."""
    problem, _job, _truth = _problem("K2", n_lines=3, noise_px=0.0, seed=1)
    img = problem.images[0]
    coef = img.coef()
    li = problem.lines.active()[0]
    gl = problem.lines.lines[li.line]
    q = gl.p1 + 0.37 * (gl.p2 - gl.p1)
    ok, line, col, _, dl_dp, _, dc_dp = project(img.kind, coef, img.kc, q, li.ocs[0], True)
    t = np.array([dl_dp @ (gl.p2 - gl.p1), dc_dp @ (gl.p2 - gl.p1)])
    n = np.array([-t[1], t[0]]) / np.linalg.norm(t)
    ocs = np.repeat(li.ocs[:1], 3, axis=0)
    for k, (dl, dc) in enumerate([(0.0, 0.0), tuple(2.5 * n), tuple(2.5 * n + 40 * t / np.linalg.norm(t))]):
        ocs[k, 0], ocs[k, 1] = line + dl, col + dc
    s = np.full(3, 0.3)
    ok, d, _jc, _jp = line_distances(img.kind, coef, img.kc, gl.p1, gl.p2, ocs, s, False)
    assert ok
    np.testing.assert_allclose(d, [0.0, 2.5, 2.5], atol=CURVED_LINE_PX)
    assert s[0] == pytest.approx(0.37, abs=SEARCH_PARAMETER)


def test_distances_do_not_depend_on_where_earlier_evaluations_left_the_search():
    """A wild trial step of the solver (phi off by 1.5 rad) makes closest-point searches fail
    or converge far away. The next evaluation at a sane orientation must still succeed and give
    the same distances, whatever the stored search starts hold. (They were overwritten once by
    failed searches, every later evaluation failed, and a 10-line CBERS scene with 6 control
    points stopped at its initial values.)"""
    problem, _job, _truth = _problem("K2", n_lines=3, seed=1)
    img = problem.images[0]
    coef = img.coef()
    li = problem.lines.active()[0]
    gl = problem.lines.lines[li.line]
    s = li.s.copy()
    ok, d0, _jc, _jp = line_distances(img.kind, coef, img.kc, gl.p1, gl.p2, li.ocs, s, False)
    assert ok
    wild = coef.copy()
    wild[16] -= 1.5  # phi0 (rad)
    before = s.copy()
    ok, d_wild, _jc, _jp = line_distances(img.kind, wild, img.kc, gl.p1, gl.p2, li.ocs, s, False)
    # the wild step's searches failed, or converged far away (the stored starts moved by hundreds
    # of line lengths; the distances are 1e5 px): either leaves starts the next evaluation must not trust
    assert not ok or (np.all(np.abs(s - before) > 100.0) and np.all(np.abs(d_wild) > 1e4))
    for starts in (s, np.full_like(s, 40.0), np.full_like(s, np.nan)):
        ok, d1, _jc, _jp = line_distances(img.kind, coef, img.kc, gl.p1, gl.p2, li.ocs, starts, False)
        assert ok
        np.testing.assert_allclose(d1, d0, atol=DISTANCE_ABS)


@pytest.mark.parametrize("model", ["K2", "ON2", "MT8", "P1"])
def test_pushbroom_line_jacobian_matches_finite_differences(model):
    problem, _job, _truth = _problem(model, n_lines=8, line_model="equivalent_planes", seed=8)
    img = problem.images[0]
    coef = _perturbed_coef(img)
    for li in problem.lines.active():
        gl = problem.lines.lines[li.line]
        k = problem.lines.k_mm[li.image]
        pseudo = [np.array([oc[5], li.ref_line, k, oc[6], oc[7], img.camera.pixel_mm]) for oc in li.end_ocs]
        for mp1, mp2 in ((PIXELS, PIXELS), tuple(pseudo)):
            for form in (li.form,):  # the form suited to the line's direction (else b explodes)
                ok, ab, jc, jp = pushbroom_line(img.kind, coef, img.kc, gl.p1, gl.p2, li.end_ocs[0], li.end_ocs[1], mp1, mp2, form, True)
                assert ok

                def f(c, e=None, mp1=mp1, mp2=mp2, form=form):
                    e = np.concatenate([gl.p1, gl.p2]) if e is None else e
                    return pushbroom_line(img.kind, c, img.kc, e[:3].copy(), e[3:].copy(), li.end_ocs[0], li.end_ocs[1], mp1, mp2, form, False)[1]

                _check_columns(f, coef, jc, img.free_idx, 5e-4 if mp1 is PIXELS else 1e-4)
                _check_columns(lambda e: f(coef, e), np.concatenate([gl.p1, gl.p2]), jp, range(6), step=1.0)


@pytest.mark.parametrize(
    "line_model,fitted,sigma",
    [("rigorous", False, None), ("rigorous", True, 0.5), ("equivalent_planes", False, 0.5), ("equivalent_planes", True, None)],
)
def test_line_term_jacobian_matches_finite_differences(line_model, fitted, sigma):
    """The whitened terms handed to Ceres and the covariance (all three residual kinds)."""
    problem, _job, _truth = _problem("P1", n_lines=8, line_model=line_model, fitted=fitted, endpoint_sigma_m=sigma, seed=4)
    img = problem.images[0]
    terms = [t.term for t in family_terms(problem) if isinstance(t.term, LineTerm)]
    assert len(terms) == 8
    p0 = img.params.copy()
    for term in terms:
        res, jac = term.evaluate(p0)
        assert res.shape == (term.n_residuals,) and jac.shape == (term.n_residuals, img.nfree)
        _check_columns(lambda p: term.evaluate(p)[0], p0, jac, range(img.nfree), 0.03)


# ---- adjustment -------------------------------------------------------------------------------


def _z_scores(report: dict, truth: dict) -> dict[str, float]:
    tp = truth_parameters(truth["model"], truth["coef"], truth["options"])
    return {p["name"]: (p["value"] - tp[p["name"]]) / p["sigma"] for p in report["images"][0]["parameters"] if p["estimated"]}


@pytest.mark.parametrize(
    "model,line_model,fitted,pitch",
    [
        ("MT8", "rigorous", False, 0.0),
        ("ON2", "rigorous", False, 0.0),
        ("K2", "rigorous", False, -23.8),
        ("P2", "rigorous", False, 0.0),
        ("J2-1", "rigorous", True, 0.0),
        ("MT8", "equivalent_planes", False, 0.0),
        ("ON2", "equivalent_planes", False, 0.0),
        ("ON1", "equivalent_planes", True, 0.0),
    ],
)
def test_lines_alone_recover_the_truth_within_3_sigma(model, line_model, fitted, pitch):
    job, truth = lines_job(model, n_lines=20, line_model=line_model, fitted=fitted, pitch_deg=pitch, seed=11, endpoint_sigma_m=0.3)
    assert not any(p["role"] == "gcp" for p in job["points"])
    report = run(job)
    a = report["adjustment"]
    assert a["converged"]
    z = _z_scores(report, truth)
    assert max(abs(v) for v in z.values()) < 3.0, z
    assert report["lines"]["model"] == line_model
    assert not report["lines"]["warnings"]
    # the LGS is at the centroid of the control lines' points (no control points)
    assert np.allclose(report["frames"]["lgs"]["origin_ecef_m"], truth["frame_origin_ecef"], atol=LGS_ORIGIN_M)


@pytest.mark.parametrize("model", PER_IMAGE_MODELS)
def test_points_and_lines_combined_for_every_platform_model(model):
    """Control points and control lines in one adjustment: both kinds of residual are reported,
    the observation count adds up, check points are still by mono, statistics keep their shape,
    and the combination recovers the truth."""
    job, truth = lines_job(model, n_lines=6, n_gcp=8, n_check=5, seed=3, endpoint_sigma_m=0.2)
    counts = validate(job)
    assert counts["valid"], counts["problems"]
    report = run(job)
    a = report["adjustment"]
    assert a["converged"]
    assert a["n_observations"] == counts["n_observations"] == 2 * 8 + 6 * 8
    assert report["checkpoints"]["method"] == "mono" and report["checkpoints"]["n"] == 5
    assert set(report["checkpoints"]) >= {"rmse_m", "t_test", "shapiro_wilk", "mean_gsd"}
    items = report["lines"]["items"]
    assert len(items) == 6 and all(len(it["images"][0]["residuals"]) == 8 for it in items)
    assert report["images"][0]["n_observations"] == 8
    assert report["lines"]["rmse_px"]["control"] < 1.0
    if model != "GENERAL":  # 18 parameters, all quadratic: too weak for a 3-sigma promise here
        assert max(abs(v) for v in _z_scores(report, truth).values()) < 3.0


def test_lines_in_a_block_with_tie_and_weighted_points():
    """A check line in a multi-image job with tie points and weighted control (Schur path)."""
    from utils.scenes import block_job

    job, _truth = block_job("K2", n_triplets=1, n_tie=5, n_gcp=6, n_check=2, seed=3, gcp_sigma_m=0.3)
    nadir = next(im["id"] for im in job["images"] if im["camera"] == "nadir")
    chk = [p for p in job["points"] if p["role"] == "check"][:2]
    obs = {o["point"]: o for o in job["observations"] if o["image"] == nadir and o["point"] in {c["id"] for c in chk}}
    assert len(obs) == 2
    job["lines"] = [
        {
            "id": "X1",
            "role": "check",
            "endpoints": [chk[0]["coordinates"], chk[1]["coordinates"]],
            "observations": [
                {"image": nadir, "points": [{"line": obs[c["id"]]["line"], "column": obs[c["id"]]["column"]} for c in chk]}
            ],
        }
    ]
    report = run(job)
    assert report["adjustment"]["converged"]
    (item,) = report["lines"]["items"]
    assert item["role"] == "check" and item["images"][0]["residuals"] is None
    # the check line passes through the two check points: its distances are their image errors
    assert all(abs(d) < 3.0 for d in item["images"][0]["distances_px"])
    assert report["lines"]["rmse_px"]["check"] is not None and report["lines"]["rmse_px"]["control"] is None


def test_report_lines_section():
    job, _truth = lines_job("ON2", n_lines=13, line_model="equivalent_planes", seed=3, n_check=3)
    job["lines"][12]["role"] = "check"
    report = run(job)
    sec = report["lines"]
    assert sec["model"] == "equivalent_planes" and sec["correction"] == "iterated"
    assert sec["resolves"] >= 1 and sec["refresh_changes"][-1] <= 0.01
    control = [it for it in sec["items"] if it["role"] == "control"]
    check = [it for it in sec["items"] if it["role"] == "check"]
    assert len(control) == 12 and len(check) == 1
    im = control[0]["images"][0]
    assert im["form"] in ("y=ax+b", "x=a'y+b'") and len(im["residuals"]) == 2 and len(im["correction"]) == 2
    assert len(im["standardized"]) == 2 and im["residual_units"] == ["1", "mm"]
    assert len(im["distances_px"]) == im["n_points"] == 8
    ck = check[0]["images"][0]
    assert ck["residuals"] is None and ck["rmse_px"] < 2.0
    assert sec["rmse_px"]["control"] < 1.0
    # the adjustment counts only control lines: 12 x 2 equations
    assert report["adjustment"]["n_observations"] == 24
    json.dumps(report)


def test_uncorrected_equivalent_planes_fits_worse_than_corrected():
    """On model-consistent data with a 0.1 deg crab angle the frame approximation alone leaves
    systematic residuals; the iterated correction removes them."""
    job, _ = lines_job("ON2", n_lines=15, line_model="equivalent_planes", seed=9)
    s0 = {}
    for corr in ("none", "iterated"):
        job["options"]["line_correction"] = corr
        s0[corr] = run(job)["adjustment"]["sigma0_aposteriori"]
    assert s0["iterated"] < 1.5 < 3.0 < s0["none"]


def test_equivalent_planes_with_estimated_phi_warns():
    job, _ = lines_job("P1", n_lines=20, line_model="equivalent_planes", seed=1)
    report = run(job)
    assert any("omega/phi estimated" in w for w in report["warnings"])


def test_jobs_without_lines_report_an_empty_section():
    job, _ = single_image_job("K2", n_gcp=8, n_check=3, seed=1)
    report = run(job)
    assert report["lines"]["items"] == [] and report["lines"]["rmse_px"] == {"control": None, "check": None}


# ---- bad input --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def good_job() -> dict:
    job, _ = lines_job("MT8", n_lines=6, seed=7)
    return job


def _codes(job: dict) -> dict[str, list]:
    out = validate(job)
    return {p["code"]: p["location"] for p in out["problems"]}


def test_valid_line_job_counts(good_job):
    out = validate(good_job)
    assert out["valid"] and out["n_observations"] == 6 * 8 and out["n_unknowns"] == 8


def test_coincident_endpoints(good_job):
    job = copy.deepcopy(good_job)
    job["lines"][2]["endpoints"][1] = list(job["lines"][2]["endpoints"][0])
    assert _codes(job)["line_endpoints_coincide"] == ["lines", 2, "endpoints"]
    with pytest.raises(JobError) as exc:
        run(job)
    assert exc.value.code == "line_endpoints_coincide"


def test_line_seen_edge_on(good_job):
    """A vertical line under a nadir camera is parallel to the viewing direction."""
    job = copy.deepcopy(good_job)
    lon, lat, h = job["lines"][1]["endpoints"][0]
    job["lines"][1]["endpoints"] = [[lon, lat, h], [lon, lat, h + 20.0]]
    codes = _codes(job)
    assert codes["line_edge_on"] == ["lines", 1, "observations", 0]
    msg = next(p["message"] for p in validate(job)["problems"] if p["code"] == "line_edge_on")
    assert "edge-on" in msg and "viewing direction" in msg


def test_single_image_point(good_job):
    job = copy.deepcopy(good_job)
    job["lines"][0]["observations"][0]["points"] = job["lines"][0]["observations"][0]["points"][:1]
    assert _codes(job)["line_single_point"] == ["lines", 0, "observations", 0, "points"]


def test_unknown_image_reference(good_job):
    job = copy.deepcopy(good_job)
    job["lines"][3]["observations"][0]["image"] = "no-such-image"
    assert _codes(job)["unknown_image"] == ["lines", 3, "observations", 0, "image"]


@pytest.mark.parametrize(
    "change,code",
    [
        (lambda o: o.update(points=[]), "line_observation_empty"),
        (lambda o: o.update(fitted={"form": "y=ax+b", "a": 0.1, "b": 3.0, "sigma_a": 1e-4, "sigma_b": 0.3}), "line_observation_ambiguous"),
        (lambda o: o.update(points=[dict(p, line=o["points"][0]["line"], column=o["points"][0]["column"]) for p in o["points"]]), "line_image_points_coincide"),
        (lambda o: o["points"][2].update(column=-50.0), "outside_image"),
    ],
)
def test_bad_line_observations(good_job, change, code):
    job = copy.deepcopy(good_job)
    change(job["lines"][4]["observations"][0])
    codes = _codes(job)
    assert code in codes and codes[code][:4] == ["lines", 4, "observations", 0]


def test_duplicates_and_no_control(good_job):
    job = copy.deepcopy(good_job)
    job["lines"][1]["id"] = job["lines"][0]["id"]
    job["lines"][2]["observations"].append(copy.deepcopy(job["lines"][2]["observations"][0]))
    codes = _codes(job)
    assert codes["duplicate_id"] == ["lines", 1, "id"]
    assert codes["duplicate_line_observation"] == ["lines", 2, "observations", 1]
    job = copy.deepcopy(good_job)
    for gl in job["lines"]:
        gl["role"] = "check"
    assert "no_control" in _codes(job)


def test_schema_rejects_malformed_lines(good_job):
    from pydantic import ValidationError

    for bad in (
        {"role": "gcp"},
        {"sigma_m": [0.1, -1.0, 0.1]},
        {"endpoints": [[1.0, 2.0, 3.0]]},
    ):
        job = copy.deepcopy(good_job)
        job["lines"][0].update(bad)
        with pytest.raises(ValidationError):
            load_job(job)
    job = copy.deepcopy(good_job)
    job["lines"][0]["observations"][0] = {"image": "img-1", "fitted": {"form": "y=ax+b", "a": 1.0, "b": 0.0, "sigma_a": 0.1, "sigma_b": 0.1, "correlation": 1.0}}
    with pytest.raises(ValidationError):
        load_job(job)


def test_pba_run_on_a_job_with_lines(tmp_path, good_job, capsys):
    from solver.cli import main

    path = tmp_path / "lines.json"
    path.write_text(json.dumps(good_job))
    out = tmp_path / "report.json"
    assert main(["run", str(path), "-o", str(out), "-q"]) == 0
    report = json.loads(out.read_text())
    assert len(report["lines"]["items"]) == 6
    assert "lines (6 control, 0 check; rigorous)" in capsys.readouterr().out
    assert math.isfinite(report["adjustment"]["sigma0_aposteriori"])
