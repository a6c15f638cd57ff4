"""The attitude base (``images[].attitude_base``): the delivered attitude, interpolated linearly
between its samples, to which the orbit-attitude and pass models add their angle polynomials.

Evidence: a base that is itself a polynomial (a constant, a straight line) must give exactly the
projections of the job without a base whose polynomial carries those terms (so the base is
added to the angles, on the polynomials' own time axis, shared pass attitude included); the
adjustment's Jacobian with an oscillating base against central differences of its residuals
(the line's Newton and the implicit-function derivatives use the base's rate); bad bases refused
by name. Jobs without a base are pinned by tests/test_report_fixtures.py."""

from __future__ import annotations

import copy
import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from utils.differences import central_difference_in_place

from solver.adjust import prepare
from solver.engine.linalg import linearise
from solver.errors import JobError
from solver.kernels import KC_ATT_BASE, project
from solver.platforms import coef_index
from solver.schema.job import load_job

_spec = importlib.util.spec_from_file_location("exp", Path(__file__).parents[3] / "scripts" / "experiments_orbit_models.py")
exp = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(exp)

SAME_PX = 1e-7  # a polynomial base vs the same polynomial as coefficients: rounding of the Newton's stop (1e-8 line)
COLUMN_FD_REL, COLUMN_FD_ABS = 1e-4, 1e-9  # Jacobian columns vs central differences (as tests/solver/platforms/test_orbit_pass.py)
ANGLES = ("omega", "phi", "kappa")


def _job(model: str) -> dict:
    job, _truth = exp.simulate(1)
    j = copy.deepcopy(job)
    for im in j["images"]:
        im["model"] = {"name": model, "options": {}}
    return exp.with_ephemeris(j)


def _base(im: dict, line_time_s: float, lines: int, law, step_s: float = 0.125) -> list[dict]:
    """Samples of ``law(t)`` (t: s since the image's first line; roll, pitch, yaw in degrees)
    every ``step_s`` over the image's lines and a little beyond."""
    t = np.arange(-0.3, lines * line_time_s + 0.3, step_s)
    return [{"time_s": float(im["first_line_time_s"] + x), **dict(zip(("roll_deg", "pitch_deg", "yaw_deg"), map(float, law(x))))}
            for x in t]


def _projections(problem, points) -> np.ndarray:
    """Every observation's projection with ``points``' coordinates (LGS; the same for both jobs:
    the tie points' intersections start from each job's own attitude)."""
    out = []
    for k in range(len(problem.obs.img)):
        img = problem.images[problem.obs.img[k]]
        ok, line, col = project(img.kind, img.coef(), img.kc, points[problem.obs.pt[k]].xyz, problem.obs.oc[k], False)[:3]
        assert ok
        out.append((line, col))
    return np.array(out)


@pytest.mark.parametrize("model", ["OA-J2", "PASS-J2"])
def test_a_straight_line_base_is_the_same_polynomial(model) -> None:
    """A base linear in time (roll, pitch, yaw with their own offsets and rates) projects every
    observation where the job without a base does with those offsets and rates as the constant
    and linear coefficients of its angle polynomials, at the angles' own time (PASS-J2: since
    the pass reference epoch, attitude shared per camera)."""
    job = _job(model)
    rates = np.array([2e-4, -3e-4, 1e-4])  # deg/s
    offsets = np.array([1e-3, -2e-3, 5e-4])  # deg at each image's first line
    based = copy.deepcopy(job)
    cams = {c["id"]: c for c in job["cameras"]}
    for im in based["images"]:
        cam = cams[im["camera"]]
        im["attitude_base"] = _base(im, cam["line_time_s"], cam["lines"], lambda t: offsets + rates * t, step_s=1.7)
    with_base = prepare(load_job(based))
    without = prepare(load_job(job))
    for a, b in zip(with_base.images, without.images):
        assert a.kc[KC_ATT_BASE] > 0 and without.images[0].kc[KC_ATT_BASE] == 0
        b.base[:] = a.coef()
        ta0 = a.model.kind.attitude_time_offset(a.kc)  # the angles' time at the image's first line
        for e, name in enumerate(ANGLES):
            b.base[coef_index(name, 0)] += math.radians(offsets[e] - rates[e] * ta0)
            b.base[coef_index(name, 1)] += math.radians(rates[e])
        b.params[:] = b.base[b.free_idx]
    d = _projections(with_base, without.points) - _projections(without, without.points)
    assert np.abs(d).max() < SAME_PX, np.abs(d).max()


def test_the_jacobian_with_an_oscillating_base_matches_central_differences() -> None:
    """The adjustment's Jacobian columns (the pass state and the attitude corrections) with a base
    whose pitch oscillates by 10 microradians over 4.5 s (a SPOT 3 scene's), against central
    differences of the whitened residuals."""
    job = _job("PASS-J2")
    cams = {c["id"]: c for c in job["cameras"]}
    amp = math.degrees(1e-5)
    for im in job["images"]:
        cam = cams[im["camera"]]
        im["attitude_base"] = _base(im, cam["line_time_s"], cam["lines"],
                                    lambda t: np.array([3e-4 * t, amp * math.cos(2 * math.pi * t / 4.5), -2e-4]))
    problem = prepare(load_job(job))
    lin = linearise(problem)
    jac = lin.sparse_jacobian().toarray()
    n_obs = lin.n_obs_rows
    blocks = [(problem.passes[0].params, int(lin.layout.pass_col[0]), [20.0] * 3 + [0.02] * 3)]
    blocks += [(img.params, int(lin.layout.img_col[img.index]), [1e-7] * img.nfree) for img in problem.images[:2]]
    for params, col0, steps in blocks:
        for k, h in enumerate(steps):
            fd = central_difference_in_place(lambda: linearise(problem).res_obs.ravel(), params, k, h)
            an = jac[:n_obs, col0 + k]
            assert np.max(np.abs(fd - an)) < COLUMN_FD_REL * np.max(np.abs(an)) + COLUMN_FD_ABS, (col0, k)


NORMAL_REL = 1e-9  # the reduced rows' normal equations vs the samples' own (QR rounding)


def test_samples_of_a_base_observe_the_correction_through_its_free_terms() -> None:
    """With a base the samples enter as :func:`solver.observations.attitude.reduced_term`: as
    many rows as the correction has free terms (validation counts the same), and the same normal
    equations as the samples' own whitened rows (numpy on the full rows, common bias included)."""
    from solver.observations.attitude import FAMILY, attitude_terms, n_attitude_observations

    job = _job("PASS-J2")
    job["options"] = {**job.get("options", {}), "attitude": {"sigma_deg": [2e-3] * 3, "bias_sigma_deg": [1e-3] * 3}}
    cams = {c["id"]: c for c in job["cameras"]}
    for im in job["images"]:
        im["attitude_base"] = _base(im, cams[im["camera"]]["line_time_s"], cams[im["camera"]]["lines"],
                                    lambda t: np.array([1e-3, 2e-3 * math.sin(t), -1e-3]))
    problem = prepare(load_job(job))
    full = attitude_terms(problem)
    reduced = [lab.term for lab in FAMILY.terms(problem)]
    assert len(full) == len(reduced) == 3
    for f, r in zip(full, reduced):
        img = problem.images[f.image_index]
        angle_terms = sum(int(k) in {coef_index(e, q) for e in ANGLES for q in range(4)} for k in img.free_idx)
        assert f.n_residuals > r.n_residuals == angle_terms
        wa, wb = f.whiten(f.a), f.whiten(f.b)
        ra, rb = r.linear_form()
        scale = np.abs(wa.T @ wa).max()
        assert np.abs(ra.T @ ra - wa.T @ wa).max() < NORMAL_REL * scale
        assert np.abs(ra.T @ rb - wa.T @ wb).max() <= NORMAL_REL * max(np.abs(wa.T @ wb).max(), 1.0)
    assert n_attitude_observations(load_job(job)) == sum(r.n_residuals for r in reduced)


def _refused(job: dict) -> list[tuple[str, str]]:
    with pytest.raises(JobError) as exc:
        prepare(load_job(job))
    return [(p.code, "/".join(map(str, p.location))) for p in exc.value.problems]


def test_bad_bases_are_refused_by_name() -> None:
    job = _job("OA-J2")
    im = job["images"][0]
    two = [{"time_s": im["first_line_time_s"] + t, "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 0.0} for t in (0.0, 1.0)]
    bad = copy.deepcopy(job)
    bad["images"][0]["attitude_base"] = two[:1]
    assert ("attitude_base_too_short", "images/0/attitude_base") in _refused(bad)
    bad["images"][0]["attitude_base"] = [two[1], two[0]]
    assert ("attitude_base_not_increasing", "images/0/attitude_base/1/time_s") in _refused(bad)
    bad = copy.deepcopy(job)
    bad["images"][1]["model"] = {"name": "K2"}
    bad["images"][1]["attitude_base"] = two
    assert ("attitude_needs_orbital_frame", "images/1/attitude_base") in _refused(bad)
