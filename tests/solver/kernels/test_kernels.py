"""Kernels against independent evidence: finite differences, hand-built matrices, orbit integration."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from tolerances import ROUND_TRIP_PX
from utils.differences import central_difference, central_jacobian
from utils.scenes import block_job, single_image_job

from solver.adjust import prepare
from solver.kernels import (
    gravity_and_gradient,
    project,
    ray,
    rotation_and_derivatives,
)
from solver.platforms import get_model, model_names
from solver.platforms.kepler import AE_M, GM_M3_S2, J2, OMEGA_RAD_S
from solver.schema.job import load_job

ELEMENTARY_ABS = 1e-15  # the closed-form rotation vs the product of three elementary rotations: an ulp
ORTHONORMAL_ABS = 1e-14  # M M^T = I for a kernel rotation: a few ulps
ROTATION_FD_ABS = 1e-9  # dM/dangle vs central differences with h = 1e-6 rad: truncation h^2 ~ 1e-12, rounding 1e-10
GRAVITY_FD_REL, GRAVITY_FD_ABS = 1e-6, 1e-15  # the gravity gradient vs central differences with 1-m steps on 7e6-m radii (m/s^2 per m)
POTENTIAL_FD_REL = 1e-7  # J2 acceleration vs the numeric gradient of its potential (0.5-m steps)
PACKED_RESIDUAL_ABS = 1e-9  # the packed block's whitened residual vs the plain kernel's: the same arithmetic
PACKED_JACOBIAN_REL = 1e-12  # the packed block's Jacobian rows vs the plain kernel's divided by sigma
ZERO_IOP_PX = 1e-7  # project_cam with every IOP zero vs project: the same ray, iterated separately
ZERO_IOP_REL, ZERO_IOP_ABS = 1e-6, 1e-9  # their derivatives wrt the point, same iterations

# the pass-propagated models need passes (several images, epochs) that the per-image synthetic
# scenes here do not have; tests/solver/platforms/test_orbit_pass.py covers their Jacobians and projections;
# the RPC bias models have no camera (tests/solver/platforms/test_rpc_models.py)
PER_IMAGE_MODELS = [m for m in model_names() if get_model(m).kind.position_from_image_state]

REL_TOL = 2e-5  # finite differences (central) vs analytic, relative to the column scale


def _elementary(axis: int, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    m = np.eye(3)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[i, i] = c
    m[j, j] = c
    m[i, j] = -s
    m[j, i] = s
    return m


def test_rotation_matches_product_of_elementary_rotations_and_fd():
    om, ph, ka = 0.3, -0.41, 2.2
    m, dmo, dmp, dmk = rotation_and_derivatives(om, ph, ka)
    expected = _elementary(0, om) @ _elementary(1, ph) @ _elementary(2, ka)
    np.testing.assert_allclose(m, expected, atol=ELEMENTARY_ABS)
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=ORTHONORMAL_ABS)
    h = 1e-6
    for k, dm in enumerate((dmo, dmp, dmk)):
        fd = central_difference(lambda a: rotation_and_derivatives(*a)[0], np.array([om, ph, ka]), k, h)
        np.testing.assert_allclose(dm, fd, atol=ROTATION_FD_ABS)


def test_backward_camera_has_negative_phi():
    """Seed 000 holds phi = -23.8 deg for the backward camera: our convention must agree."""
    # flight towards +x (kappa = 0): a backward camera looks towards -x
    m = rotation_and_derivatives(0.0, math.radians(-23.8), 0.0)[0]
    boresight_object = m.T @ np.array([0.0, 0.0, -1.0])
    assert boresight_object[0] < -0.3


@pytest.mark.parametrize("j2", [0.0, J2])
def test_gravity_gradient_fd(j2):
    r = np.array([4.1e6, -5.1e6, -2.6e6])
    g, gg = gravity_and_gradient(r, GM_M3_S2, j2, AE_M)
    h = 1.0
    for j in range(3):
        fd = central_difference(lambda x: gravity_and_gradient(x, GM_M3_S2, j2, AE_M)[0], r, j, h)
        np.testing.assert_allclose(gg[:, j], fd, rtol=GRAVITY_FD_REL, atol=GRAVITY_FD_ABS)


def test_j2_acceleration_is_gradient_of_potential():
    """g_J2 = grad V with V = -GM a^2 J2 / r^3 (3/2 z^2/r^2 - 1/2): independent numeric gradient."""

    def potential(r):
        rn = np.linalg.norm(r)
        return GM_M3_S2 / rn - GM_M3_S2 * AE_M**2 * J2 / rn**3 * (1.5 * r[2] ** 2 / rn**2 - 0.5)

    r = np.array([3.7e6, -4.6e6, -2.8e6])
    g, _ = gravity_and_gradient(r, GM_M3_S2, J2, AE_M)
    h = 0.5
    num = central_jacobian(potential, r, h)
    np.testing.assert_allclose(g, num, rtol=POTENTIAL_FD_REL)


def test_kepler_position_is_second_order_taylor_of_the_rotating_frame_orbit():
    """Integrate the Earth-fixed equations of motion (J2, Coriolis, centrifugal) for one PRISM
    scene (5.9 s) and compare with S0 + u t + 1/2 a t^2: the truncation (jerk) stays well below a
    metre, while the printed seed-000 variants (Coriolis sign, missing 1/2) are tens of metres off."""
    from solver.kernels import platform_state

    r0 = np.array([4096571.0, -5124225.0, -2629051.0])
    u0 = np.array([-2503.6, 1237.2, -6222.1])
    w = OMEGA_RAD_S

    def rhs(_t, y):
        g, _ = gravity_and_gradient(y[:3], GM_M3_S2, J2, AE_M)
        a = g + np.array([w * w * y[0] + 2 * w * y[4], w * w * y[1] - 2 * w * y[3], 0.0])
        return np.concatenate([y[3:], a])

    t_end = 16000 * 0.00037
    sol = solve_ivp(rhs, (0, t_end), np.concatenate([r0, u0]), rtol=1e-12, atol=1e-6, method="DOP853")
    truth = sol.y[:3, -1]
    coef = np.zeros(24)
    coef[[0, 4, 8]] = r0
    coef[[1, 5, 9]] = u0
    kc = np.zeros(16)
    kc[0:9] = np.eye(3).ravel()
    kc[12:16] = (GM_M3_S2, w, J2, AE_M)
    model = platform_state(1, coef, kc, t_end)[0]
    assert np.linalg.norm(model - truth) < 1.0
    g, _ = gravity_and_gradient(r0, GM_M3_S2, J2, AE_M)
    wrong_sign = g + np.array([w * w * r0[0] + 2 * w * u0[1], w * w * r0[1] + 2 * w * u0[0], 0.0])
    printed = r0 + u0 * t_end + 0.5 * wrong_sign * t_end**2
    assert np.linalg.norm(printed - truth) > 5.0  # 2 Omega u_x t^2 = 12.8 m here


def _fd_check(kind, coef, kc, p, oc, free):
    ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp = project(kind, coef, kc, p, oc, True)
    assert ok
    for j in free:
        # step moving the image point by ~0.3 px: truncation and rounding errors both negligible
        h = 0.3 / max(abs(dl_dc[j]), abs(dc_dc[j]), 1e-12)
        fdl, fdc = central_difference(lambda c: project(kind, c, kc, p, oc, False)[1:3], coef, j, h)
        # relative to the larger of the two derivatives of this column (they share the step)
        scale = max(abs(dl_dc[j]), abs(dc_dc[j]))
        assert abs(fdl - dl_dc[j]) <= REL_TOL * scale, (j, fdl, dl_dc[j])
        assert abs(fdc - dc_dc[j]) <= REL_TOL * scale, (j, fdc, dc_dc[j])
    for j in range(3):
        h = 0.3 / max(abs(dl_dp[j]), abs(dc_dp[j]), 1e-12)
        fdl, fdc = central_difference(lambda x: project(kind, coef, kc, x, oc, False)[1:3], p, j, h)
        scale = max(abs(dl_dp[j]), abs(dc_dp[j]))
        assert abs(fdl - dl_dp[j]) < REL_TOL * scale
        assert abs(fdc - dc_dp[j]) < REL_TOL * scale


@pytest.mark.parametrize("model", PER_IMAGE_MODELS)
@pytest.mark.parametrize("pitch", [0.0, -23.8])
def test_projection_jacobian_matches_finite_differences(model, pitch):
    opts = {"orders": {"X": 3, "Y": 2, "Z": 2, "omega": 1, "phi": 1, "kappa": 2}} if model == "GENERAL" else None
    job, _ = single_image_job(model, seed=5, pitch_deg=pitch, n_gcp=20, options=opts)
    problem = prepare(load_job(job))
    img = problem.images[0]
    coef = img.coef()
    # non-zero higher-order coefficients so that every term is exercised
    coef[img.free_idx] += np.where(np.abs(coef[img.free_idx]) > 0, 0, 1e-7)
    for k in range(0, len(problem.obs.img), 5):
        p = problem.points[problem.obs.pt[k]].xyz
        _fd_check(img.kind, coef, img.kc, p, problem.obs.oc[k], img.free_idx)


# A ray taken 700 km out and projected back, the search started at the ray's own pixel and lines
# away from it: the pixel must come back to rounding from any of these starts (Newton's last step
# on the line below 1e-8 line; measured worst over the per-image models: 3.0e-10 px)
NEWTON_START_PX = 1e-9


@pytest.mark.parametrize("model", PER_IMAGE_MODELS)
def test_ray_inverts_projection_from_starts_lines_away(model):
    job, _ = single_image_job(model, seed=7, pitch_deg=-23.8)
    problem = prepare(load_job(job))
    img = problem.images[0]
    coef = img.coef()
    worst = 0.0
    for k in range(len(problem.obs.img)):
        oc = problem.obs.oc[k].copy()
        s, d = ray(img.kind, coef, img.kc, oc)
        p = s + 700e3 * d
        for off in (0.0, 0.5, 3.0, -40.0):
            start = oc.copy()
            start[0] += off
            ok, line, col, *_ = project(img.kind, coef, img.kc, p, start, False)
            assert ok
            worst = max(worst, abs(line - oc[0]), abs(col - oc[1]))
    assert worst < min(NEWTON_START_PX, ROUND_TRIP_PX)


# Newton on the line may stop on its second-order error estimate instead of a step below 1e-8
# line: against the root of the along-track condition found by bracketing (brentq on
# platform_state and object_to_camera, which share no code with the Newton loop), the line and
# column must stay at the rounding of the camera vector (measured worst: 4.3e-10 line, 5.9e-10
# px for K2 on the 100k strip; the early stop's own estimate is held below 1e-11)
ROOT_PX = 2e-9


@pytest.mark.parametrize("model", ["K2", "OA-J2", "P2", "MT8"])
def test_projection_equals_a_bracketed_root_of_the_along_track_condition(model):
    """From the observed line and from starts 3, -40 and 500 lines away, with perturbed
    coefficients (curved orbit and attitude), the projection's (line, column) equal the bracketed
    root's, and the call with derivatives gives the very same (line, column) as the one without
    (Ceres compares costs from both)."""
    from scipy.optimize import brentq

    from solver.kernels import object_to_camera, platform_state

    job, _ = single_image_job(model, seed=11, pitch_deg=-23.8)
    problem = prepare(load_job(job))
    img = problem.images[0]
    coef = img.coef()
    coef[img.free_idx] += np.where(np.abs(coef[img.free_idx]) > 0, 0, 1e-7)
    worst = 0.0
    for k in range(0, len(problem.obs.img), 3):
        p = problem.points[problem.obs.pt[k]].xyz
        oc = problem.obs.oc[k].copy()
        f, px, xo, yo, cc, tpl = oc[3], oc[4], oc[5], oc[6], oc[7], oc[8]

        def camera_vector(line, p=p, tpl=tpl):
            tau = line * tpl
            return object_to_camera(img.kind, coef, img.kc, tau) @ (p - platform_state(img.kind, coef, img.kc, tau)[0])

        def along_track(line, f=f, xo=xo):
            d = camera_vector(line)
            return -f * d[0] / d[2] - xo

        ok, line, col, *_ = project(img.kind, coef, img.kc, p, oc, False)
        assert ok
        root = brentq(along_track, line - 50.0, line + 50.0, xtol=1e-12, rtol=1e-15)
        d = camera_vector(root)
        root_col = cc + (-f * d[1] / d[2] - yo) / px
        for off in (0.0, 3.0, -40.0, 500.0):
            start = oc.copy()
            start[0] += off
            plain = project(img.kind, coef, img.kc, p, start, False)
            with_jac = project(img.kind, coef, img.kc, p, start, True)
            assert plain[0] and with_jac[0]
            assert (plain[1], plain[2]) == (with_jac[1], with_jac[2])
            worst = max(worst, abs(plain[1] - root), abs(plain[2] - root_col))
    assert worst < ROOT_PX


def test_point_block_matches_single_projections_and_layout():
    """The packed point block used by Ceres gives the same numbers as the plain kernel, with the
    Jacobian of image i only on rows 2i, 2i+1 (Ceres' dense row-major layout)."""
    from solver.engine.backend import PointCost, SolveControl
    from solver.engine.packed_tables import camera_table, image_table
    from solver.engine.residual_blocks import point_blocks

    job, _ = block_job("K2", n_triplets=1, n_tie=5, n_gcp=6, n_check=2, seed=3)
    problem = prepare(load_job(job))
    control = SolveControl(None, None, 10)
    p = next(q for q in problem.points if q.role == "tie")
    blocks = point_blocks(problem)
    b = int(np.flatnonzero(blocks.owner == p.index)[0])
    rows = blocks.rows[blocks.start[b] : blocks.start[b + 1]]
    sizes = [len(a) for a in blocks.params[b]]
    cf = PointCost(blocks.records_of(b), sizes, control, (image_table(problem), camera_table(problem)))
    k = len(rows)
    imgs = [problem.images[problem.obs.img[r]] for r in rows]
    params = [p.xyz] + [im.params for im in imgs]
    res = np.zeros(2 * k)
    jacs = [np.full(2 * k * 3, np.nan)] + [np.full(2 * k * im.nfree, np.nan) for im in imgs]
    assert cf.Evaluate(params, res, jacs)
    for i, (r, im) in enumerate(zip(rows, imgs)):
        ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp = project(im.kind, im.coef(), im.kc, p.xyz, problem.obs.oc[r], True)
        sig = problem.obs.oc[r, 2]
        assert res[2 * i] == pytest.approx((problem.obs.oc[r, 0] - line) / sig, abs=PACKED_RESIDUAL_ABS)
        jp = jacs[0].reshape(2 * k, 3)
        np.testing.assert_allclose(jp[2 * i], -dl_dp / sig, rtol=PACKED_JACOBIAN_REL)
        ji = jacs[1 + i].reshape(2 * k, im.nfree)
        np.testing.assert_allclose(ji[2 * i + 1], -dc_dc[im.free_idx] / sig, rtol=PACKED_JACOBIAN_REL)
        other = np.delete(ji, [2 * i, 2 * i + 1], axis=0)
        assert np.all(other == 0.0)


@pytest.mark.parametrize("model", ["K2", "P2", "OA-J2"])
def test_projection_with_interior_orientation_jacobian_and_zero_limit(model):
    """project_cam: equals project when every IOP is zero; exact derivatives wrt coefficients,
    point and each IOP (nonzero values so that every term is exercised)."""
    from solver.kernels import IOP_CHIP, IOP_OPTICAL, N_IOP, project_cam

    job, _ = single_image_job(model, seed=5, pitch_deg=23.8)
    problem = prepare(load_job(job))
    img = problem.images[0]
    coef = img.coef()
    chip, chip_len = 1, 3624 * 0.0071
    for k in range(0, len(problem.obs.img), 6):
        p = problem.points[problem.obs.pt[k]].xyz
        oc = problem.obs.oc[k]
        a = project(img.kind, coef, img.kc, p, oc, True)
        b = project_cam(img.kind, coef, img.kc, p, oc, np.zeros(N_IOP), chip, chip_len, True)
        assert abs(a[1] - b[1]) < ZERO_IOP_PX and abs(a[2] - b[2]) < ZERO_IOP_PX
        np.testing.assert_allclose(b[5], a[5], rtol=ZERO_IOP_REL, atol=ZERO_IOP_ABS)
    iop = np.zeros(N_IOP)
    iop[: len(IOP_OPTICAL)] = [0.004, -0.003, 1.5, 2e-6, 3e-10, 1e-4]
    b0 = 6 + 5 * chip
    iop[b0 : b0 + len(IOP_CHIP)] = [0.02, -0.03, 2e-4, -1e-4, 1e-3]
    for k in range(0, len(problem.obs.img), 6):
        p = problem.points[problem.obs.pt[k]].xyz
        oc = problem.obs.oc[k]
        r = project_cam(img.kind, coef, img.kc, p, oc, iop, chip, chip_len, True)
        assert r[0]
        checks = [(3, 5, coef, j, "coef") for j in img.free_idx] + [(7, 8, iop, q, "iop") for q in list(range(6)) + list(range(b0, b0 + 5))]
        for il, ic, vec, j, what in checks:
            h = 0.05 / max(abs(r[il][j]), abs(r[ic][j]), 1e-12)  # distortion terms are strongly non-linear
            def image_point(v, what=what):
                return project_cam(img.kind, coef if what == "iop" else v, img.kc, p, oc, iop if what == "coef" else v, chip, chip_len, False)[1:3]

            fdl, fdc = central_difference(image_point, vec, j, h)
            scale = max(abs(r[il][j]), abs(r[ic][j]))
            assert abs(fdl - r[il][j]) <= REL_TOL * scale, (what, j)
            assert abs(fdc - r[ic][j]) <= REL_TOL * scale, (what, j)
        for j in range(3):
            h = 0.3 / max(abs(r[4][j]), abs(r[6][j]))
            fdl, fdc = central_difference(lambda x: project_cam(img.kind, coef, img.kc, x, oc, iop, chip, chip_len, False)[1:3], p, j, h)
            scale = max(abs(r[4][j]), abs(r[6][j]))
            assert abs(fdl - r[4][j]) <= REL_TOL * scale
            assert abs(fdc - r[6][j]) <= REL_TOL * scale


RAY_MISS_M = 1e-4  # Newton stops at 1e-8 line; one line of a 7 km/s platform is metres


@pytest.mark.parametrize("model", ["K2", "P2", "OA-J2"])
def test_ray_with_interior_orientation_passes_through_the_projected_point(model):
    """project_cam maps a ground point to (L, C); the ray of that pixel (ray_cam, same IOP) must
    pass through the point: its perpendicular distance is the error of the ray's line time,
    attitude or interior orientation."""
    from solver.kernels import IOP_CHIP, IOP_OPTICAL, N_IOP, project_cam, ray_cam

    job, _ = single_image_job(model, seed=5, pitch_deg=23.8)
    problem = prepare(load_job(job))
    img = problem.images[0]
    coef = img.coef()
    chip, chip_len = 1, 3624 * 0.0071
    iop = np.zeros(N_IOP)
    iop[: len(IOP_OPTICAL)] = [0.004, -0.003, 1.5, 2e-6, 3e-10, 1e-4]
    b0 = 6 + 5 * chip
    iop[b0 : b0 + len(IOP_CHIP)] = [0.02, -0.03, 2e-4, -1e-4, 1e-3]
    for k in range(0, len(problem.obs.img), 3):
        p = problem.points[problem.obs.pt[k]].xyz
        oc = problem.obs.oc[k].copy()
        ok, line, col, *_ = project_cam(img.kind, coef, img.kc, p, oc, iop, chip, chip_len, False)
        assert ok
        oc[0], oc[1] = line, col
        s, d = ray_cam(img.kind, coef, img.kc, oc, iop, chip, chip_len)
        assert np.linalg.norm(np.cross(p - s, d)) < RAY_MISS_M, (k, line)


SOLVE3_REL = 1e-12  # the written-out 3 x 3 LU vs LAPACK's (numpy): the same algorithm, condition numbers below 1e3


def test_solve3_matches_lapack_and_reports_singular_systems():
    """intersect_all's 3 x 3 solver (written out to keep numba's LAPACK bindings out of the
    kernel) against numpy's LAPACK solve and determinant, pivoting included (a zero leading
    entry), and a singular system's zero determinant."""
    from solver.kernels.projection import _solve3

    rng = np.random.default_rng(3)
    systems = [(np.array([[0.0, 2.0, 1.0], [1.0, 1.0, 0.0], [3.0, 0.0, 1.0]]), np.array([1.0, -2.0, 0.5]))]
    for _ in range(200):
        a = rng.normal(size=(3, 3)) + 3.0 * np.eye(3)
        systems.append((a * 10.0 ** rng.uniform(-3, 6), rng.normal(size=3) * 10.0 ** rng.uniform(-2, 6)))
    for a, b in systems:
        assert np.linalg.cond(a) < 1e3
        x = np.empty(3)
        det = _solve3(a, b, x)
        expected = np.linalg.solve(a, b)
        assert np.max(np.abs(x - expected)) <= SOLVE3_REL * np.max(np.abs(expected))
        assert det == pytest.approx(np.linalg.det(a), rel=SOLVE3_REL)
    singular = np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [1.0, 0.0, 1.0]])
    assert abs(_solve3(singular, np.ones(3), np.empty(3))) < 1e-15
