"""Numerical kernels (numba): rotation, platform evaluation and the pushbroom projection.

Everything that runs once per observation per solver evaluation lives here, compiled with numba
(``error_model="numpy"`` so a division by zero gives inf instead of raising inside Ceres).
The residual blocks in :mod:`solver.residuals` and the covariance/statistics code call only
these functions, so a compiled C++ kernel could replace this module behind the same interface.

Conventions (see docs/models.md):

* Rotation object -> camera: ``M(omega, phi, kappa) = Rx(omega) Ry(phi) Rz(kappa)`` with
  right-handed active elementary matrices. kappa turns about the object vertical (heading),
  phi about the camera's cross-track axis (pitch: a backward-looking camera has phi < 0),
  omega about the camera's along-track axis (roll).
* Camera frame: x_c along track (flight direction), z_c away from the scene, y_c = z_c x x_c.
  ``d = M (P - S)``; the image coordinates are ``x = -f d_x / d_z``, ``y = -f d_y / d_z`` (mm).
* Platform parameters of one image are a *full* coefficient vector ``coef[6, 4]`` (flattened to
  24) for the elements (X, Y, Z, omega, phi, kappa) and powers tau^0..tau^3 of the model's scaled
  time ``tau``. Polynomial models: every element is ``sum_k coef[e, k] tau^k`` in the LGS.
  Kepler models: coef[0:3, 0] is the ECEF position S0 at line 0, coef[0:3, 1] the ECEF velocity
  u, and the position is ``S0 + u tau + 1/2 a tau^2`` with the rotating-frame acceleration
  ``a = g(S0) + Omega^2 (X0, Y0, 0) + 2 Omega (u_y, -u_x, 0)`` (g: point mass, optionally J2);
  the result is rotated into the LGS. Angles are polynomials for every model.
* Kepler constants ``kc`` (16): R_ecef->lgs (9, row-major), LGS origin in ECEF (3), GM, Omega,
  J2 (0 disables), a_e.
* Observation constants ``oc`` (9): line, column, sigma_px, f_mm, pixel_mm, xo_mm, yo_mm,
  c_centre, tau_per_line, where the projection condition is ``-f d_x/d_z = xo`` (xo = chip dx -
  principal point x0) and ``column = c_centre + (-f d_y/d_z - yo) / pixel`` (yo = chip dy - y0).
"""

from __future__ import annotations

import numpy as np
from numba import njit

KIND_POLYNOMIAL = 0
KIND_KEPLER = 1
N_COEF = 24
N_OBS_CONST = 9
N_KEPLER_CONST = 16

_JIT = dict(cache=True, nogil=True, error_model="numpy", fastmath=False)


@njit(**_JIT)
def rotation_and_derivatives(om: float, ph: float, ka: float):
    """Return M, dM/domega, dM/dphi, dM/dkappa for M = Rx(om) Ry(ph) Rz(ka) (each 3x3)."""
    co, so = np.cos(om), np.sin(om)
    cp, sp = np.cos(ph), np.sin(ph)
    ck, sk = np.cos(ka), np.sin(ka)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, co, -so], [0.0, so, co]])
    drx = np.array([[0.0, 0.0, 0.0], [0.0, -so, -co], [0.0, co, -so]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    dry = np.array([[-sp, 0.0, cp], [0.0, 0.0, 0.0], [-cp, 0.0, -sp]])
    rz = np.array([[ck, -sk, 0.0], [sk, ck, 0.0], [0.0, 0.0, 1.0]])
    drz = np.array([[-sk, -ck, 0.0], [ck, -sk, 0.0], [0.0, 0.0, 0.0]])
    ryz = ry @ rz
    m = rx @ ryz
    dm_om = drx @ ryz
    dm_ph = rx @ (dry @ rz)
    dm_ka = rx @ (ry @ drz)
    return m, dm_om, dm_ph, dm_ka


@njit(**_JIT)
def gravity_and_gradient(r, gm: float, j2: float, ae: float):
    """Acceleration (m/s^2) of point mass + J2 at ECEF position r (m) and its 3x3 gradient."""
    x, y, z = r[0], r[1], r[2]
    r2 = x * x + y * y + z * z
    rn = np.sqrt(r2)
    r3 = r2 * rn
    r5 = r3 * r2
    g = np.empty(3)
    grad = np.empty((3, 3))
    for i in range(3):
        g[i] = -gm * r[i] / r3
        for j in range(3):
            grad[i, j] = -gm * ((1.0 if i == j else 0.0) / r3 - 3.0 * r[i] * r[j] / r5)
    if j2 != 0.0:
        k = 1.5 * j2 * gm * ae * ae
        r7 = r5 * r2
        r9 = r7 * r2
        z2 = z * z
        # g_i = -k * r_i * (c_i r^-5 - 5 z^2 r^-7), c = (1, 1, 3)
        c = np.array([1.0, 1.0, 3.0])
        for i in range(3):
            g[i] += -k * r[i] * (c[i] / r5 - 5.0 * z2 / r7)
            for j in range(3):
                # d/dr_j of [c_i r^-5 - 5 z^2 r^-7]
                dz2 = 2.0 * z if j == 2 else 0.0
                dbr = -5.0 * c[i] * r[j] / r7 - 5.0 * (dz2 / r7 - 7.0 * z2 * r[j] / r9)
                br = c[i] / r5 - 5.0 * z2 / r7
                grad[i, j] += -k * ((1.0 if i == j else 0.0) * br + r[i] * dbr)
    return g, grad


@njit(**_JIT)
def platform_state(kind: int, coef, kc, tau: float):
    """Perspective centre (LGS, m) and angles (rad) at scaled time tau, with derivatives.

    Returns (S[3], dS_dcoef[3,24], dS_dtau[3], ang[3], dang_dcoef[3,24], dang_dtau[3]).
    """
    s = np.zeros(3)
    ds_dc = np.zeros((3, N_COEF))
    ds_dt = np.zeros(3)
    ang = np.zeros(3)
    da_dc = np.zeros((3, N_COEF))
    da_dt = np.zeros(3)
    tp = np.ones(4)
    for k in range(1, 4):
        tp[k] = tp[k - 1] * tau
    # angles: polynomials for every model
    for e in range(3):
        for k in range(4):
            c = coef[(3 + e) * 4 + k]
            ang[e] += c * tp[k]
            da_dc[e, (3 + e) * 4 + k] = tp[k]
            if k >= 1:
                da_dt[e] += k * c * tp[k - 1]
    if kind == KIND_POLYNOMIAL:
        for e in range(3):
            for k in range(4):
                c = coef[e * 4 + k]
                s[e] += c * tp[k]
                ds_dc[e, e * 4 + k] = tp[k]
                if k >= 1:
                    ds_dt[e] += k * c * tp[k - 1]
        return s, ds_dc, ds_dt, ang, da_dc, da_dt
    # Kepler / J2 in the Earth-fixed frame
    r0 = np.array([coef[0], coef[4], coef[8]])
    u = np.array([coef[1], coef[5], coef[9]])
    om = kc[13]
    g, gg = gravity_and_gradient(r0, kc[12], kc[14], kc[15])
    a = g.copy()
    a[0] += om * om * r0[0] + 2.0 * om * u[1]
    a[1] += om * om * r0[1] - 2.0 * om * u[0]
    da_dr = gg.copy()
    da_dr[0, 0] += om * om
    da_dr[1, 1] += om * om
    da_du = np.zeros((3, 3))
    da_du[0, 1] = 2.0 * om
    da_du[1, 0] = -2.0 * om
    h = 0.5 * tau * tau
    se = r0 + u * tau + a * h
    sdt = u + a * tau
    dse = np.zeros((3, N_COEF))
    for i in range(3):
        for j in range(3):
            dse[i, j * 4] = (1.0 if i == j else 0.0) + h * da_dr[i, j]
            dse[i, j * 4 + 1] = (tau if i == j else 0.0) + h * da_du[i, j]
    rot = kc[0:9].reshape(3, 3)
    org = kc[9:12]
    s = rot @ (se - org)
    ds_dc = rot @ dse
    ds_dt = rot @ sdt
    return s, ds_dc, ds_dt, ang, da_dc, da_dt


@njit(**_JIT)
def _camera_vector(kind, coef, kc, tau, p):
    """d = M (P - S) and its derivatives wrt coef (3x24), tau (3) and P (3x3)."""
    s, ds_dc, ds_dt, ang, da_dc, da_dt = platform_state(kind, coef, kc, tau)
    m, dmo, dmp, dmk = rotation_and_derivatives(ang[0], ang[1], ang[2])
    v = p - s
    d = m @ v
    g0 = dmo @ v
    g1 = dmp @ v
    g2 = dmk @ v
    md = m @ ds_dc
    dd_dc = np.empty((3, N_COEF))
    for i in range(3):
        for j in range(N_COEF):
            dd_dc[i, j] = g0[i] * da_dc[0, j] + g1[i] * da_dc[1, j] + g2[i] * da_dc[2, j] - md[i, j]
    dd_dt = g0 * da_dt[0] + g1 * da_dt[1] + g2 * da_dt[2] - m @ ds_dt
    return d, dd_dc, dd_dt, m


@njit(**_JIT)
def project(kind, coef, kc, p, oc, want_jac: bool):
    """Exact pushbroom projection of ground point ``p`` (LGS, m) with its observation constants.

    Solves ``-f d_x(tau(L))/d_z = xo`` for the line L by Newton's method starting at the
    observed line, then evaluates the column. Returns (ok, line, column, dL_dcoef[24],
    dL_dp[3], dC_dcoef[24], dC_dp[3]); derivatives by the implicit function theorem.
    """
    f = oc[3]
    px = oc[4]
    xo = oc[5]
    yo = oc[6]
    cc = oc[7]
    tpl = oc[8]
    line = oc[0]
    ok = False
    for _ in range(30):
        tau = line * tpl
        d, dd_dc, dd_dt, m = _camera_vector(kind, coef, kc, tau, p)
        g = -f * d[0] / d[2] - xo
        dg_dt = -f * (dd_dt[0] * d[2] - d[0] * dd_dt[2]) / (d[2] * d[2])
        dg_dl = dg_dt * tpl
        if dg_dl == 0.0 or not np.isfinite(dg_dl):
            break
        step = g / dg_dl
        line -= step
        if abs(step) < 1e-8:
            ok = True
            break
    tau = line * tpl
    d, dd_dc, dd_dt, m = _camera_vector(kind, coef, kc, tau, p)
    y = -f * d[1] / d[2]
    col = cc + (y - yo) / px
    dl_dc = np.zeros(N_COEF)
    dl_dp = np.zeros(3)
    dc_dc = np.zeros(N_COEF)
    dc_dp = np.zeros(3)
    if want_jac:
        iz = 1.0 / d[2]
        # gradients of x and y (mm) wrt d
        gx = np.array([-f * iz, 0.0, f * d[0] * iz * iz])
        gy = np.array([0.0, -f * iz, f * d[1] * iz * iz])
        dx_dt = gx @ dd_dt
        dy_dt = gy @ dd_dt
        dx_dl = dx_dt * tpl
        dy_dl = dy_dt * tpl
        dx_dc = gx @ dd_dc
        dy_dc = gy @ dd_dc
        dx_dp = gx @ m
        dy_dp = gy @ m
        for j in range(N_COEF):
            dl_dc[j] = -dx_dc[j] / dx_dl
            dc_dc[j] = (dy_dc[j] + dy_dl * dl_dc[j]) / px
        for j in range(3):
            dl_dp[j] = -dx_dp[j] / dx_dl
            dc_dp[j] = (dy_dp[j] + dy_dl * dl_dp[j]) / px
    return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp


@njit(**_JIT)
def assemble(base, free_idx, p):
    """Full coefficient vector: ``base`` with the free entries replaced by ``p``."""
    coef = base.copy()
    for j in range(free_idx.shape[0]):
        coef[free_idx[j]] = p[j]
    return coef


@njit(**_JIT)
def residuals_image_batch(kind, base, p, kc, pts, ocs, free_idx, res, jac, want_jac: bool):
    """Residuals of many observations of one image of fixed ground points (resection block).

    ``pts`` (m, 3) LGS, ``ocs`` (m, 9); fills ``res`` (2m) with (observed - projected)/sigma
    for line then column, and ``jac`` (2m, nfree) wrt the free coefficients ``free_idx``.
    Returns False if a projection did not converge.
    """
    coef = assemble(base, free_idx, p)
    m = pts.shape[0]
    nf = free_idx.shape[0]
    all_ok = True
    for i in range(m):
        ok, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp = project(kind, coef, kc, pts[i], ocs[i], want_jac)
        all_ok = all_ok and ok
        w = 1.0 / ocs[i, 2]
        res[2 * i] = (ocs[i, 0] - ln) * w
        res[2 * i + 1] = (ocs[i, 1] - cl) * w
        if want_jac:
            for j in range(nf):
                jac[2 * i, j] = -dl_dc[free_idx[j]] * w
                jac[2 * i + 1, j] = -dc_dc[free_idx[j]] * w
    return all_ok


@njit(**_JIT)
def residuals_point_multi(p, kinds, bases, pimg, kcs, ocs, free_idx, nfree, res, jac_p, jac_img, want_jac: bool):
    """Residuals of one ground point (parameter) seen in k images (tie or weighted control).

    ``bases`` (k, 24) held coefficients, ``pimg`` (k, 24) the images' free parameters (first
    nfree[i] entries), ``kcs`` (k, 16), ``ocs`` (k, 9), ``free_idx`` (k, 24) padded, ``nfree``
    (k). Fills ``res`` (2k), ``jac_p`` (2k, 3) and ``jac_img`` (k, 2, 24) (first nfree[i] columns
    wrt the free coefficients of image i). Returns False if a projection did not converge.
    """
    k = kinds.shape[0]
    all_ok = True
    for i in range(k):
        coef = bases[i].copy()
        for j in range(nfree[i]):
            coef[free_idx[i, j]] = pimg[i, j]
        ok, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp = project(kinds[i], coef, kcs[i], p, ocs[i], want_jac)
        all_ok = all_ok and ok
        w = 1.0 / ocs[i, 2]
        res[2 * i] = (ocs[i, 0] - ln) * w
        res[2 * i + 1] = (ocs[i, 1] - cl) * w
        if want_jac:
            for j in range(3):
                jac_p[2 * i, j] = -dl_dp[j] * w
                jac_p[2 * i + 1, j] = -dc_dp[j] * w
            for j in range(nfree[i]):
                jac_img[i, 0, j] = -dl_dc[free_idx[i, j]] * w
                jac_img[i, 1, j] = -dc_dc[free_idx[i, j]] * w
    return all_ok


@njit(**_JIT)
def ray(kind, coef, kc, oc):
    """Perspective centre S (LGS) and unit viewing direction (LGS) of an observation's pixel."""
    tau = oc[0] * oc[8]
    s, ds_dc, ds_dt, ang, da_dc, da_dt = platform_state(kind, coef, kc, tau)
    m, dmo, dmp, dmk = rotation_and_derivatives(ang[0], ang[1], ang[2])
    f = oc[3]
    y = (oc[1] - oc[7]) * oc[4] + oc[6]
    cam = np.array([oc[5], y, -f])
    dvec = m.T @ cam
    dvec /= np.sqrt(dvec @ dvec)
    return s, dvec


@njit(**_JIT)
def observation_rows(kinds, coefs, kcs, free_idx, nfree, img_col, pts, pt_col, obs_img, obs_pt, ocs, want_jac: bool):
    """Whitened residuals and sparse Jacobian rows of every observation, in one call.

    ``coefs`` (nimg, 24) current full coefficients, ``free_idx`` (nimg, 24) padded with
    ``nfree`` (nimg), ``img_col`` (nimg) first column of each image's parameters, ``pts``
    (npt, 3) LGS coordinates, ``pt_col`` (npt) first column of the point's parameters or -1 if
    the point is held fixed, ``obs_img``/``obs_pt`` (n) indices, ``ocs`` (n, 9).

    Returns (res[2n], rows, cols, vals, ok[n]) in COO form; residual = (observed - projected)/sigma.
    """
    n = obs_img.shape[0]
    res = np.empty(2 * n)
    ok = np.empty(n, dtype=np.bool_)
    cap = 0
    if want_jac:
        for i in range(n):
            cap += 2 * (nfree[obs_img[i]] + (3 if pt_col[obs_pt[i]] >= 0 else 0))
    rows = np.empty(cap, dtype=np.int64)
    cols = np.empty(cap, dtype=np.int64)
    vals = np.empty(cap)
    q = 0
    for i in range(n):
        im = obs_img[i]
        pt = obs_pt[i]
        good, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp = project(kinds[im], coefs[im], kcs[im], pts[pt], ocs[i], want_jac)
        ok[i] = good
        w = 1.0 / ocs[i, 2]
        res[2 * i] = (ocs[i, 0] - ln) * w
        res[2 * i + 1] = (ocs[i, 1] - cl) * w
        if want_jac:
            for j in range(nfree[im]):
                c = img_col[im] + j
                rows[q] = 2 * i
                cols[q] = c
                vals[q] = -dl_dc[free_idx[im, j]] * w
                q += 1
                rows[q] = 2 * i + 1
                cols[q] = c
                vals[q] = -dc_dc[free_idx[im, j]] * w
                q += 1
            if pt_col[pt] >= 0:
                for j in range(3):
                    rows[q] = 2 * i
                    cols[q] = pt_col[pt] + j
                    vals[q] = -dl_dp[j] * w
                    q += 1
                    rows[q] = 2 * i + 1
                    cols[q] = pt_col[pt] + j
                    vals[q] = -dc_dp[j] * w
                    q += 1
    return res, rows, cols, vals, ok
