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
* Kepler constants ``kc`` (17): R_ecef->lgs (9, row-major), LGS origin in ECEF (3), GM, Omega,
  J2 (0 disables), a_e, camera mounting pitch (rad, orbit-attitude models).
* Observation constants ``oc`` (9): line, column, sigma_px, f_mm, pixel_mm, xo_mm, yo_mm,
  c_centre, tau_per_line, where the projection condition is ``-f d_x/d_z = xo`` (xo = chip dx -
  principal point x0) and ``column = c_centre + (-f d_y/d_z - yo) / pixel`` (yo = chip dy - y0).
"""

from __future__ import annotations

import numpy as np
from numba import njit

KIND_POLYNOMIAL = 0
KIND_KEPLER = 1
KIND_ORBIT_ATTITUDE = 2  # Kepler/J2 position, attitude relative to the orbital frame
N_COEF = 24
N_OBS_CONST = 9
N_KEPLER_CONST = 17

_JIT = dict(cache=True, nogil=True, error_model="numpy", fastmath=False)


@njit(**_JIT)
def rotation_and_derivatives(om: float, ph: float, ka: float):
    """Return M, dM/domega, dM/dphi, dM/dkappa for M = Rx(om) Ry(ph) Rz(ka) (each 3x3)."""
    out = np.empty((4, 3, 3))
    _rotation_into(om, ph, ka, out)
    return out[0], out[1], out[2], out[3]


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
    a, da_dr = _kepler_terms(coef, kc)
    da_du = np.zeros((3, 3))
    da_du[0, 1] = 2.0 * kc[13]
    da_du[1, 0] = -2.0 * kc[13]
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
def _rotation_into(om: float, ph: float, ka: float, out):
    """Fill out[0] = M, out[1..3] = dM/d(omega, phi, kappa) for M = Rx(om) Ry(ph) Rz(ka)."""
    co, so = np.cos(om), np.sin(om)
    cp, sp = np.cos(ph), np.sin(ph)
    ck, sk = np.cos(ka), np.sin(ka)
    # M = Rx Ry Rz written out; rows: see docs/models.md
    out[0, 0, 0] = cp * ck
    out[0, 0, 1] = -cp * sk
    out[0, 0, 2] = sp
    out[0, 1, 0] = co * sk + so * sp * ck
    out[0, 1, 1] = co * ck - so * sp * sk
    out[0, 1, 2] = -so * cp
    out[0, 2, 0] = so * sk - co * sp * ck
    out[0, 2, 1] = so * ck + co * sp * sk
    out[0, 2, 2] = co * cp
    # d/d omega: row 0 constant, rows 1, 2 rotate
    out[1, 0, 0] = 0.0
    out[1, 0, 1] = 0.0
    out[1, 0, 2] = 0.0
    out[1, 1, 0] = -so * sk + co * sp * ck
    out[1, 1, 1] = -so * ck - co * sp * sk
    out[1, 1, 2] = -co * cp
    out[1, 2, 0] = co * sk + so * sp * ck
    out[1, 2, 1] = co * ck - so * sp * sk
    out[1, 2, 2] = -so * cp
    # d/d phi
    out[2, 0, 0] = -sp * ck
    out[2, 0, 1] = sp * sk
    out[2, 0, 2] = cp
    out[2, 1, 0] = so * cp * ck
    out[2, 1, 1] = -so * cp * sk
    out[2, 1, 2] = so * sp
    out[2, 2, 0] = -co * cp * ck
    out[2, 2, 1] = co * cp * sk
    out[2, 2, 2] = -co * sp
    # d/d kappa
    out[3, 0, 0] = -cp * sk
    out[3, 0, 1] = -cp * ck
    out[3, 0, 2] = 0.0
    out[3, 1, 0] = co * ck - so * sp * sk
    out[3, 1, 1] = -co * sk - so * sp * ck
    out[3, 1, 2] = 0.0
    out[3, 2, 0] = so * ck + co * sp * sk
    out[3, 2, 1] = -so * sk + co * sp * ck
    out[3, 2, 2] = 0.0


@njit(**_JIT)
def _kepler_terms(coef, kc):
    """Rotating-frame acceleration at the state (S0, u) and its derivatives (once per call)."""
    r0 = np.empty(3)
    r0[0] = coef[0]
    r0[1] = coef[4]
    r0[2] = coef[8]
    om = kc[13]
    g, gg = gravity_and_gradient(r0, kc[12], kc[14], kc[15])
    a = g
    a[0] += om * om * r0[0] + 2.0 * om * coef[5]
    a[1] += om * om * r0[1] - 2.0 * om * coef[1]
    gg[0, 0] += om * om
    gg[1, 1] += om * om
    return a, gg


@njit(**_JIT)
def _pose(kind, coef, kc, acc, tau, s, sdot, ang, angdot):
    """Position (LGS) and its tau-derivative, angles and their tau-derivatives, at tau."""
    for e in range(3):
        c0 = coef[(3 + e) * 4]
        c1 = coef[(3 + e) * 4 + 1]
        c2 = coef[(3 + e) * 4 + 2]
        c3 = coef[(3 + e) * 4 + 3]
        ang[e] = c0 + tau * (c1 + tau * (c2 + tau * c3))
        angdot[e] = c1 + tau * (2.0 * c2 + 3.0 * tau * c3)
    if kind == KIND_POLYNOMIAL:
        for e in range(3):
            c0 = coef[e * 4]
            c1 = coef[e * 4 + 1]
            c2 = coef[e * 4 + 2]
            c3 = coef[e * 4 + 3]
            s[e] = c0 + tau * (c1 + tau * (c2 + tau * c3))
            sdot[e] = c1 + tau * (2.0 * c2 + 3.0 * tau * c3)
        return
    h = 0.5 * tau * tau
    for i in range(3):
        se_i = coef[i * 4] + coef[i * 4 + 1] * tau + acc[i] * h - kc[9 + i]
        sd_i = coef[i * 4 + 1] + acc[i] * tau
        sdot[i] = sd_i
        s[i] = se_i
    # rotate ECEF offsets into the LGS
    x, y, z = s[0], s[1], s[2]
    vx, vy, vz = sdot[0], sdot[1], sdot[2]
    for i in range(3):
        s[i] = kc[3 * i] * x + kc[3 * i + 1] * y + kc[3 * i + 2] * z
        sdot[i] = kc[3 * i] * vx + kc[3 * i + 1] * vy + kc[3 * i + 2] * vz


@njit(**_JIT)
def _line_newton_step(d, ddt, f: float, xo: float, tpl: float) -> float:
    """Newton step (lines) on the along-track condition ``-f d_x/d_z = xo``; NaN if singular."""
    g = -f * d[0] / d[2] - xo
    dg_dl = -f * (ddt[0] * d[2] - d[0] * ddt[2]) / (d[2] * d[2]) * tpl
    if dg_dl == 0.0 or not np.isfinite(dg_dl):
        return np.nan
    return g / dg_dl


@njit(**_JIT)
def _orbital_frame(s, v, c):
    """Orbital frame from the LGS position ``s`` and Earth-fixed velocity ``v`` (LGS axes);
    ``c`` = R_ecef->lgs @ origin, so ``s + c`` is the geocentric position in LGS axes.

    Rows: x along track (velocity without its radial part: follows the ground track, i.e. yaw
    steering), y = z x x, z radial (away from the Earth). Returns (R, dR/ds, dR/dv) with
    dR[row, col, var].
    """
    g = s + c
    gn = np.sqrt(g @ g)
    z = g / gn
    dz = (np.eye(3) - np.outer(z, z)) / gn  # dz/ds
    vz = v @ z
    h = v - vz * z
    hn = np.sqrt(h @ h)
    x = h / hn
    px = (np.eye(3) - np.outer(x, x)) / hn
    # dh/ds = -(z v^T + vz I) dz/ds ; dh/dv = I - z z^T
    dh_ds = -(np.outer(z, v) + vz * np.eye(3)) @ dz
    dh_dv = np.eye(3) - np.outer(z, z)
    dx_ds = px @ dh_ds
    dx_dv = px @ dh_dv
    y = np.cross(z, x)
    r = np.empty((3, 3))
    r[0] = x
    r[1] = y
    r[2] = z
    d_s = np.zeros((3, 3, 3))
    d_v = np.zeros((3, 3, 3))
    for k in range(3):
        dzk = dz[:, k]
        dxk = dx_ds[:, k]
        dyk = np.cross(dzk, x) + np.cross(z, dxk)
        dxv = dx_dv[:, k]
        dyv = np.cross(z, dxv)
        for col in range(3):
            d_s[0, col, k] = dxk[col]
            d_s[1, col, k] = dyk[col]
            d_s[2, col, k] = dzk[col]
            d_v[0, col, k] = dxv[col]
            d_v[1, col, k] = dyv[col]
    return r, d_s, d_v


@njit(**_JIT)
def _mount(angle: float):
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros((3, 3))
    m[0, 0] = c
    m[0, 2] = s
    m[1, 1] = 1.0
    m[2, 0] = -s
    m[2, 2] = c
    return m


@njit(**_JIT)
def _oa_state(coef, kc, acc, da_dr, tau, rot):
    """Everything the orbit-attitude projection needs at tau: S, Sdot, M, dM/dtau, the attitude
    part A = Ry(mount) R_att and its angle derivatives, and the orbital frame derivatives."""
    s = np.empty(3)
    sdot = np.empty(3)
    ang = np.empty(3)
    angdot = np.empty(3)
    _pose(KIND_KEPLER, coef, kc, acc, tau, s, sdot, ang, angdot)
    _rotation_into(ang[0], ang[1], ang[2], rot)
    r0 = kc[0:9].reshape(3, 3)
    c = r0 @ kc[9:12]
    vdot = r0 @ acc
    ro, d_s, d_v = _orbital_frame(s, sdot, c)
    mnt = _mount(kc[16])
    a_att = mnt @ rot[0]
    dro_dt = np.zeros((3, 3))
    for k in range(3):
        dro_dt += d_s[:, :, k] * sdot[k] + d_v[:, :, k] * vdot[k]
    m = a_att @ ro
    dm_dt = a_att @ dro_dt
    for e in range(3):
        dm_dt += (mnt @ rot[1 + e]) * angdot[e] @ ro
    return s, sdot, ang, m, dm_dt, a_att, mnt, ro, d_s, d_v


@njit(**_JIT)
def _project_oa(coef, kc, p, oc, want_jac: bool):
    """``project`` for the orbit-attitude kind (same returns)."""
    f = oc[3]
    px = oc[4]
    xo = oc[5]
    yo = oc[6]
    cc = oc[7]
    tpl = oc[8]
    line = oc[0]
    ok = False
    rot = np.empty((4, 3, 3))
    acc, da_dr = _kepler_terms(coef, kc)
    d = np.zeros(3)
    ddt = np.zeros(3)
    for it in range(31):
        tau = line * tpl
        s, sdot, ang, m, dm_dt, a_att, mnt, ro, d_s, d_v = _oa_state(coef, kc, acc, da_dr, tau, rot)
        v = p - s
        d = m @ v
        ddt = dm_dt @ v - m @ sdot
        if it == 30 or ok:
            break
        step = _line_newton_step(d, ddt, f, xo, tpl)
        if not np.isfinite(step):
            break
        line -= step
        if abs(step) < 1e-8:
            ok = True
    iz = 1.0 / d[2]
    y = -f * d[1] * iz
    col = cc + (y - yo) / px
    dl_dc = np.zeros(N_COEF)
    dl_dp = np.zeros(3)
    dc_dc = np.zeros(N_COEF)
    dc_dp = np.zeros(3)
    if not want_jac:
        return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp
    tau = line * tpl
    gx = np.array([-f * iz, 0.0, f * d[0] * iz * iz])
    gy = np.array([0.0, -f * iz, f * d[1] * iz * iz])
    dx_dl = (gx @ ddt) * tpl
    dy_dl = (gy @ ddt) * tpl
    for j in range(3):
        dxp = gx[0] * m[0, j] + gx[1] * m[1, j] + gx[2] * m[2, j]
        dyp = gy[0] * m[0, j] + gy[1] * m[1, j] + gy[2] * m[2, j]
        dl_dp[j] = -dxp / dx_dl
        dc_dp[j] = (dyp + dy_dl * dl_dp[j]) / px
    # attitude angles (relative to the orbital frame)
    tp = 1.0
    for k in range(4):
        for e in range(3):
            dd = (mnt @ rot[1 + e] @ ro) @ v * tp
            idx = (3 + e) * 4 + k
            dl_dc[idx] = -(gx @ dd) / dx_dl
            dc_dc[idx] = ((gy @ dd) + dy_dl * dl_dc[idx]) / px
        tp *= tau
    # state: S_lgs = R0 (S0 + u t + a h - O), V_lgs = R0 (u + a t); a = a(S0, u)
    r0 = kc[0:9].reshape(3, 3)
    h = 0.5 * tau * tau
    da_du = np.zeros((3, 3))
    da_du[0, 1] = 2.0 * kc[13]
    da_du[1, 0] = -2.0 * kc[13]
    ds_dth = np.empty((3, 6))
    dv_dth = np.empty((3, 6))
    ds_dth[:, 0:3] = r0 @ (np.eye(3) + h * da_dr)
    ds_dth[:, 3:6] = r0 @ (tau * np.eye(3) + h * da_du)
    dv_dth[:, 0:3] = r0 @ (tau * da_dr)
    dv_dth[:, 3:6] = r0 @ (np.eye(3) + tau * da_du)
    for q in range(6):
        dro = np.zeros((3, 3))
        for k in range(3):
            dro += d_s[:, :, k] * ds_dth[k, q] + d_v[:, :, k] * dv_dth[k, q]
        dd = a_att @ dro @ v - m @ np.ascontiguousarray(ds_dth[:, q])
        idx = (q % 3) * 4 + (0 if q < 3 else 1)
        dl_dc[idx] = -(gx @ dd) / dx_dl
        dc_dc[idx] = ((gy @ dd) + dy_dl * dl_dc[idx]) / px
    return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp


@njit(**_JIT)
def project(kind, coef, kc, p, oc, want_jac: bool):
    """Exact pushbroom projection of ground point ``p`` (LGS, m) with its observation constants.

    Solves ``-f d_x(tau(L))/d_z = xo`` for the line L by Newton's method starting at the
    observed line, then evaluates the column. Returns (ok, line, column, dL_dcoef[24],
    dL_dp[3], dC_dcoef[24], dC_dp[3]); derivatives by the implicit function theorem.
    """
    if kind == KIND_ORBIT_ATTITUDE:
        return _project_oa(coef, kc, p, oc, want_jac)
    f = oc[3]
    px = oc[4]
    xo = oc[5]
    yo = oc[6]
    cc = oc[7]
    tpl = oc[8]
    line = oc[0]
    ok = False
    rot = np.empty((4, 3, 3))
    s = np.empty(3)
    sdot = np.empty(3)
    ang = np.empty(3)
    angdot = np.empty(3)
    d = np.empty(3)
    ddt = np.empty(3)
    v = np.empty(3)
    if kind == KIND_KEPLER:
        acc, da_dr = _kepler_terms(coef, kc)
    else:
        acc = np.zeros(3)
        da_dr = np.zeros((3, 3))
    for it in range(31):
        tau = line * tpl
        _pose(kind, coef, kc, acc, tau, s, sdot, ang, angdot)
        _rotation_into(ang[0], ang[1], ang[2], rot)
        for i in range(3):
            v[i] = p[i] - s[i]
        for i in range(3):
            di = 0.0
            dti = 0.0
            for j in range(3):
                mij = rot[0, i, j]
                dmij = rot[1, i, j] * angdot[0] + rot[2, i, j] * angdot[1] + rot[3, i, j] * angdot[2]
                di += mij * v[j]
                dti += dmij * v[j] - mij * sdot[j]
            d[i] = di
            ddt[i] = dti
        if it == 30 or ok:
            break
        step = _line_newton_step(d, ddt, f, xo, tpl)
        if not np.isfinite(step):
            break
        line -= step
        if abs(step) < 1e-8:
            ok = True
    iz = 1.0 / d[2]
    y = -f * d[1] * iz
    col = cc + (y - yo) / px
    dl_dc = np.zeros(N_COEF)
    dl_dp = np.zeros(3)
    dc_dc = np.zeros(N_COEF)
    dc_dp = np.zeros(3)
    if not want_jac:
        return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp
    tau = line * tpl
    # gradients of x and y (mm) wrt d
    gx0, gx2 = -f * iz, f * d[0] * iz * iz
    gy1, gy2 = -f * iz, f * d[1] * iz * iz
    dx_dl = (gx0 * ddt[0] + gx2 * ddt[2]) * tpl
    dy_dl = (gy1 * ddt[1] + gy2 * ddt[2]) * tpl
    # wrt P: dd/dP = M
    for j in range(3):
        dxp = gx0 * rot[0, 0, j] + gx2 * rot[0, 2, j]
        dyp = gy1 * rot[0, 1, j] + gy2 * rot[0, 2, j]
        dl_dp[j] = -dxp / dx_dl
        dc_dp[j] = (dyp + dy_dl * dl_dp[j]) / px
    # wrt the coefficients: dd/dc = dM/dang (P - S) dang/dc - M dS/dc
    # angles: dang_e/dc[(3+e)*4+k] = tau^k
    gvx = np.empty(3)  # d x / d ang_e
    gvy = np.empty(3)
    for e in range(3):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for j in range(3):
            a0 += rot[1 + e, 0, j] * v[j]
            a1 += rot[1 + e, 1, j] * v[j]
            a2 += rot[1 + e, 2, j] * v[j]
        gvx[e] = gx0 * a0 + gx2 * a2
        gvy[e] = gy1 * a1 + gy2 * a2
    tp = 1.0
    for k in range(4):
        for e in range(3):
            idx = (3 + e) * 4 + k
            dxc = gvx[e] * tp
            dyc = gvy[e] * tp
            dl_dc[idx] = -dxc / dx_dl
            dc_dc[idx] = (dyc + dy_dl * dl_dc[idx]) / px
        tp *= tau
    # position: dx/dS_lgs = -(gx^T M), dy/dS_lgs likewise
    wx = np.empty(3)
    wy = np.empty(3)
    for j in range(3):
        wx[j] = -(gx0 * rot[0, 0, j] + gx2 * rot[0, 2, j])
        wy[j] = -(gy1 * rot[0, 1, j] + gy2 * rot[0, 2, j])
    if kind == KIND_POLYNOMIAL:
        tp = 1.0
        for k in range(4):
            for e in range(3):
                idx = e * 4 + k
                dl_dc[idx] = -(wx[e] * tp) / dx_dl
                dc_dc[idx] = (wy[e] * tp + dy_dl * dl_dc[idx]) / px
            tp *= tau
    else:
        # S_lgs = R (S0 + u tau + a h - O); dS_ecef/dS0 = I + h da/dr, dS_ecef/du = tau I + h da/du
        h = 0.5 * tau * tau
        om2 = 2.0 * kc[13] * h
        # row vectors wx^T R and wy^T R (ECEF)
        ex = np.empty(3)
        ey = np.empty(3)
        for j in range(3):
            ex[j] = wx[0] * kc[j] + wx[1] * kc[3 + j] + wx[2] * kc[6 + j]
            ey[j] = wy[0] * kc[j] + wy[1] * kc[3 + j] + wy[2] * kc[6 + j]
        for j in range(3):
            # d/dS0_j
            dxs = ex[j]
            dys = ey[j]
            for i in range(3):
                dxs += ex[i] * h * da_dr[i, j]
                dys += ey[i] * h * da_dr[i, j]
            idx = j * 4
            dl_dc[idx] = -dxs / dx_dl
            dc_dc[idx] = (dys + dy_dl * dl_dc[idx]) / px
        # d/du: tau I + h * [[0, 2W, 0], [-2W, 0, 0], [0, 0, 0]]
        dxu0 = ex[0] * tau - ex[1] * om2
        dyu0 = ey[0] * tau - ey[1] * om2
        dxu1 = ex[1] * tau + ex[0] * om2
        dyu1 = ey[1] * tau + ey[0] * om2
        dxu2 = ex[2] * tau
        dyu2 = ey[2] * tau
        for j, dxu, dyu in ((0, dxu0, dyu0), (1, dxu1, dyu1), (2, dxu2, dyu2)):
            idx = j * 4 + 1
            dl_dc[idx] = -dxu / dx_dl
            dc_dc[idx] = (dyu + dy_dl * dl_dc[idx]) / px
    return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp


@njit(**_JIT)
def assemble(base, free_idx, p):
    """Full coefficient vector: ``base`` with the free entries replaced by ``p``."""
    coef = base.copy()
    for j in range(free_idx.shape[0]):
        coef[free_idx[j]] = p[j]
    return coef


@njit(**_JIT)
def object_to_camera(kind, coef, kc, tau: float):
    """The rotation M (object LGS -> camera) at scaled time tau, for every kind."""
    if kind == KIND_ORBIT_ATTITUDE:
        rot = np.empty((4, 3, 3))
        acc, da_dr = _kepler_terms(coef, kc)
        return _oa_state(coef, kc, acc, da_dr, tau, rot)[3]
    ang = platform_state(kind, coef, kc, tau)[3]
    return rotation_and_derivatives(ang[0], ang[1], ang[2])[0]


@njit(**_JIT)
def ray(kind, coef, kc, oc):
    """Perspective centre S (LGS) and unit viewing direction (LGS) of an observation's pixel."""
    tau = oc[0] * oc[8]
    s, ds_dc, ds_dt, ang, da_dc, da_dt = platform_state(kind, coef, kc, tau)
    m = object_to_camera(kind, coef, kc, tau)
    f = oc[3]
    y = (oc[1] - oc[7]) * oc[4] + oc[6]
    cam = np.array([oc[5], y, -f])
    dvec = m.T @ cam
    dvec /= np.sqrt(dvec @ dvec)
    return s, dvec


@njit(**_JIT)
def intersect_all(kinds, coefs, kcs, obs_img, ocs, order, bounds, which):
    """Least-squares intersection of the rays of each selected point (midpoint in 3D).

    ``order``/``bounds`` group the observations by point (observations of point q are
    order[bounds[q]:bounds[q+1]]); ``which`` lists the points to compute. Returns (len(which), 3);
    NaN where fewer than two independent rays exist.
    """
    out = np.full((which.shape[0], 3), np.nan)
    for w in range(which.shape[0]):
        q = which[w]
        a = np.zeros((3, 3))
        b = np.zeros(3)
        n = 0
        for t in range(bounds[q], bounds[q + 1]):
            k = order[t]
            im = obs_img[k]
            s, d = ray(kinds[im], coefs[im], kcs[im], ocs[k])
            for i in range(3):
                for j in range(3):
                    qij = (1.0 if i == j else 0.0) - d[i] * d[j]
                    a[i, j] += qij
                    b[i] += qij * s[j]
            n += 1
        if n >= 2 and abs(np.linalg.det(a)) > 1e-18:
            out[w] = np.linalg.solve(a, b)
    return out


# ---- interior orientation (docs/models.md section 8) ----------------------------------------
# Full IOP vector of a camera: x0, y0, df, k1, k2, sy, then per chip (a0, b0, a1, b1, delta).
IOP_OPTICAL = ("x0", "y0", "df", "k1", "k2", "sy")
IOP_CHIP = ("a0", "b0", "a1", "b1", "delta")
MAX_CHIPS = 8
N_IOP = len(IOP_OPTICAL) + len(IOP_CHIP) * MAX_CHIPS


@njit(**_JIT)
def camera_model(oc, iop, chip: int, chip_len: float, col: float, want: bool):
    """Ideal focal-plane coordinates (x_i, y_i) of column ``col`` on chip ``chip`` (mm) and the
    effective focal length; with derivatives wrt the column and the IOP vector.

    Returns (xi, yi, F, dxi_dc, dyi_dc, dxi_diop[N_IOP], dyi_diop[N_IOP]).
    """
    px = oc[4]
    xo = oc[5]
    yo = oc[6]
    ys = (col - oc[7]) * px
    b = 6 + 5 * chip
    a0, b0, a1, b1, de = iop[b], iop[b + 1], iop[b + 2], iop[b + 3], iop[b + 4]
    x0, y0, df, k1, k2, sy = iop[0], iop[1], iop[2], iop[3], iop[4], iop[5]
    xb = xo + a0 + b1 * ys + de * ys * ys / (2.0 * chip_len) - x0
    yb = ys + yo + b0 + (a1 + sy) * ys - y0
    r2 = xb * xb + yb * yb
    dfac = 1.0 - k1 * r2 - k2 * r2 * r2
    xi = xb * dfac
    yi = yb * dfac
    dxi_diop = np.zeros(N_IOP)
    dyi_diop = np.zeros(N_IOP)
    # d dfac / d xb, d yb
    dd_dr2 = -k1 - 2.0 * k2 * r2
    dxi_dxb = dfac + xb * dd_dr2 * 2.0 * xb
    dxi_dyb = xb * dd_dr2 * 2.0 * yb
    dyi_dxb = yb * dd_dr2 * 2.0 * xb
    dyi_dyb = dfac + yb * dd_dr2 * 2.0 * yb
    dxb_dc = (b1 + de * ys / chip_len) * px
    dyb_dc = (1.0 + a1 + sy) * px
    dxi_dc = dxi_dxb * dxb_dc + dxi_dyb * dyb_dc
    dyi_dc = dyi_dxb * dxb_dc + dyi_dyb * dyb_dc
    if want:
        # xb depends on x0, a0, b1, delta; yb on y0, b0, a1, sy
        for idx, gx, gy in (
            (0, -1.0, 0.0),
            (b, 1.0, 0.0),
            (b + 3, ys, 0.0),
            (b + 4, ys * ys / (2.0 * chip_len), 0.0),
            (1, 0.0, -1.0),
            (b + 1, 0.0, 1.0),
            (b + 2, 0.0, ys),
            (5, 0.0, ys),
        ):
            dxi_diop[idx] += dxi_dxb * gx + dxi_dyb * gy
            dyi_diop[idx] += dyi_dxb * gx + dyi_dyb * gy
        dxi_diop[3] = -xb * r2
        dyi_diop[3] = -yb * r2
        dxi_diop[4] = -xb * r2 * r2
        dyi_diop[4] = -yb * r2 * r2
    return xi, yi, oc[3] + df, dxi_dc, dyi_dc, dxi_diop, dyi_diop


@njit(**_JIT)
def project_cam(kind, coef, kc, p, oc, iop, chip: int, chip_len: float, want_jac: bool):
    """Exact projection with interior orientation: solve both collinearity conditions
    ``x_i(C) = -F d_x/d_z``, ``y_i(C) = -F d_y/d_z`` for (L, C) by 2D Newton from the observed
    values. Returns (ok, L, C, dL_dcoef[24], dL_dp[3], dC_dcoef[24], dC_dp[3], dL_diop, dC_diop).
    """
    tpl = oc[8]
    line = oc[0]
    col = oc[1]
    ok = False
    rot = np.empty((4, 3, 3))
    s = np.empty(3)
    sdot = np.empty(3)
    ang = np.empty(3)
    angdot = np.empty(3)
    d = np.empty(3)
    ddt = np.empty(3)
    v = np.empty(3)
    if kind == KIND_KEPLER:
        acc, da_dr = _kepler_terms(coef, kc)
    else:
        acc = np.zeros(3)
        da_dr = np.zeros((3, 3))
    xi = yi = big_f = dxi_dc = dyi_dc = 0.0
    dxi_diop = np.zeros(N_IOP)
    dyi_diop = np.zeros(N_IOP)
    j11 = j12 = j21 = j22 = 0.0
    for it in range(31):
        tau = line * tpl
        _pose(kind, coef, kc, acc, tau, s, sdot, ang, angdot)
        _rotation_into(ang[0], ang[1], ang[2], rot)
        for i in range(3):
            v[i] = p[i] - s[i]
        for i in range(3):
            di = 0.0
            dti = 0.0
            for j in range(3):
                mij = rot[0, i, j]
                dmij = rot[1, i, j] * angdot[0] + rot[2, i, j] * angdot[1] + rot[3, i, j] * angdot[2]
                di += mij * v[j]
                dti += dmij * v[j] - mij * sdot[j]
            d[i] = di
            ddt[i] = dti
        xi, yi, big_f, dxi_dc, dyi_dc, dxi_diop, dyi_diop = camera_model(oc, iop, chip, chip_len, col, it == 30 or ok)
        if it == 30 or ok:
            break
        g1 = xi + big_f * d[0] / d[2]
        g2 = yi + big_f * d[1] / d[2]
        j11 = big_f * (ddt[0] * d[2] - d[0] * ddt[2]) / (d[2] * d[2]) * tpl
        j21 = big_f * (ddt[1] * d[2] - d[1] * ddt[2]) / (d[2] * d[2]) * tpl
        j12 = dxi_dc
        j22 = dyi_dc
        det = j11 * j22 - j12 * j21
        if det == 0.0 or not np.isfinite(det):
            break
        dl = (j22 * g1 - j12 * g2) / det
        dc = (-j21 * g1 + j11 * g2) / det
        line -= dl
        col -= dc
        if abs(dl) < 1e-8 and abs(dc) < 1e-8:
            ok = True
    dl_dc = np.zeros(N_COEF)
    dl_dp = np.zeros(3)
    dc_dc = np.zeros(N_COEF)
    dc_dp = np.zeros(3)
    dl_di = np.zeros(N_IOP)
    dc_di = np.zeros(N_IOP)
    if not want_jac:
        return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp, dl_di, dc_di
    tau = line * tpl
    iz = 1.0 / d[2]
    # g = (x_i + F d_x/d_z, y_i + F d_y/d_z); its derivatives wrt d
    hx0, hx2 = big_f * iz, -big_f * d[0] * iz * iz
    hy1, hy2 = big_f * iz, -big_f * d[1] * iz * iz
    j11 = (hx0 * ddt[0] + hx2 * ddt[2]) * tpl
    j21 = (hy1 * ddt[1] + hy2 * ddt[2]) * tpl
    j12 = dxi_dc
    j22 = dyi_dc
    det = j11 * j22 - j12 * j21
    # inverse of [[j11, j12], [j21, j22]]
    i11, i12, i21, i22 = j22 / det, -j12 / det, -j21 / det, j11 / det

    def _solve(gx, gy):
        return -(i11 * gx + i12 * gy), -(i21 * gx + i22 * gy)

    for j in range(3):
        gx = hx0 * rot[0, 0, j] + hx2 * rot[0, 2, j]
        gy = hy1 * rot[0, 1, j] + hy2 * rot[0, 2, j]
        dl_dp[j], dc_dp[j] = _solve(gx, gy)
    gvx = np.empty(3)
    gvy = np.empty(3)
    for e in range(3):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for j in range(3):
            a0 += rot[1 + e, 0, j] * v[j]
            a1 += rot[1 + e, 1, j] * v[j]
            a2 += rot[1 + e, 2, j] * v[j]
        gvx[e] = hx0 * a0 + hx2 * a2
        gvy[e] = hy1 * a1 + hy2 * a2
    tp = 1.0
    for k in range(4):
        for e in range(3):
            idx = (3 + e) * 4 + k
            dl_dc[idx], dc_dc[idx] = _solve(gvx[e] * tp, gvy[e] * tp)
        tp *= tau
    wx = np.empty(3)
    wy = np.empty(3)
    for j in range(3):
        wx[j] = -(hx0 * rot[0, 0, j] + hx2 * rot[0, 2, j])
        wy[j] = -(hy1 * rot[0, 1, j] + hy2 * rot[0, 2, j])
    if kind == KIND_POLYNOMIAL:
        tp = 1.0
        for k in range(4):
            for e in range(3):
                idx = e * 4 + k
                dl_dc[idx], dc_dc[idx] = _solve(wx[e] * tp, wy[e] * tp)
            tp *= tau
    else:
        h = 0.5 * tau * tau
        om2 = 2.0 * kc[13] * h
        ex = np.empty(3)
        ey = np.empty(3)
        for j in range(3):
            ex[j] = wx[0] * kc[j] + wx[1] * kc[3 + j] + wx[2] * kc[6 + j]
            ey[j] = wy[0] * kc[j] + wy[1] * kc[3 + j] + wy[2] * kc[6 + j]
        for j in range(3):
            gxs = ex[j]
            gys = ey[j]
            for i in range(3):
                gxs += ex[i] * h * da_dr[i, j]
                gys += ey[i] * h * da_dr[i, j]
            dl_dc[j * 4], dc_dc[j * 4] = _solve(gxs, gys)
        for j in range(3):
            if j == 0:
                gxu, gyu = ex[0] * tau - ex[1] * om2, ey[0] * tau - ey[1] * om2
            elif j == 1:
                gxu, gyu = ex[1] * tau + ex[0] * om2, ey[1] * tau + ey[0] * om2
            else:
                gxu, gyu = ex[2] * tau, ey[2] * tau
            dl_dc[j * 4 + 1], dc_dc[j * 4 + 1] = _solve(gxu, gyu)
    # interior orientation: dg/diop = (dx_i/diop, dy_i/diop) + (d_x/d_z, d_y/d_z) for df
    for q in range(N_IOP):
        gx = dxi_diop[q]
        gy = dyi_diop[q]
        if q == 2:
            gx += d[0] * iz
            gy += d[1] * iz
        if gx != 0.0 or gy != 0.0:
            dl_di[q], dc_di[q] = _solve(gx, gy)
    return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp, dl_di, dc_di


@njit(**_JIT)
def ideal_direction(oc, iop, chip: int, chip_len: float):
    """Camera-frame direction (x_i, y_i, -F) of the observed pixel (unnormalised)."""
    xi, yi, big_f, _a, _b, _c, _d = camera_model(oc, iop, chip, chip_len, oc[1], False)
    out = np.empty(3)
    out[0] = xi
    out[1] = yi
    out[2] = -big_f
    return out


# ---- residual blocks over image and camera tables ----------------------------------------
# img_tab row (67): kind, nfree, free_idx[24], base[24], kc[17]
# cam_tab row (2 + 2 N_IOP): nfree, has_iop, free_idx[N_IOP], base[N_IOP]
# observation record (15): image, camera, image slot, camera slot (-1: constant), chip index,
#                          chip length (mm), oc[9]
IMG_TAB = 67
CAM_TAB = 2 + 2 * N_IOP
OBS_REC = 15


@njit(**_JIT)
def _eval_record(r, img_tab, cam_tab, p, params, want: bool):
    im = int(r[0])
    cm = int(r[1])
    islot = int(r[2])
    cslot = int(r[3])
    it = img_tab[im]
    kind = int(it[0])
    nf = int(it[1])
    coef = it[26:50].copy()
    if islot >= 0:
        pi = params[islot]
        for j in range(nf):
            coef[int(it[2 + j])] = pi[j]
    kc = it[50:67]
    oc = r[6:15]
    ct = cam_tab[cm]
    if ct[1] != 0.0:
        iop = ct[2 + N_IOP : 2 + 2 * N_IOP].copy()
        if cslot >= 0:
            pc = params[cslot]
            for j in range(int(ct[0])):
                iop[int(ct[2 + j])] = pc[j]
        return project_cam(kind, coef, kc, p, oc, iop, int(r[4]), r[5], want)
    ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp = project(kind, coef, kc, p, oc, want)
    empty = np.empty(0)  # no interior orientation: _fill skips the camera (slot -1)
    return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp, empty, empty


@njit(**_JIT)
def _fill(i, r, img_tab, cam_tab, w, jacs, dl_dc, dc_dc, dl_di, dc_di):
    islot = int(r[2])
    cslot = int(r[3])
    if islot >= 0:
        it = img_tab[int(r[0])]
        nf = int(it[1])
        ji = jacs[islot]
        for j in range(nf):
            fj = int(it[2 + j])
            ji[(2 * i) * nf + j] = -dl_dc[fj] * w
            ji[(2 * i + 1) * nf + j] = -dc_dc[fj] * w
    if cslot >= 0:
        ct = cam_tab[int(r[1])]
        nc = int(ct[0])
        jc = jacs[cslot]
        for j in range(nc):
            fj = int(ct[2 + j])
            jc[(2 * i) * nc + j] = -dl_di[fj] * w
            jc[(2 * i + 1) * nc + j] = -dc_di[fj] * w


@njit(**_JIT)
def point_obs_block(rec, img_tab, cam_tab, p, params, res, jac_p, jacs, want_jac: bool):
    """All observations of one estimated point. Parameter blocks: the point, then ``params``
    (image and camera blocks, referenced by the records' slots). Writes Ceres' arrays."""
    k = rec.shape[0]
    ok = True
    if want_jac:
        for a in jacs:
            for q in range(a.shape[0]):
                a[q] = 0.0
    for i in range(k):
        r = rec[i]
        good, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp, dl_di, dc_di = _eval_record(r, img_tab, cam_tab, p, params, want_jac)
        w = 1.0 / r[8]
        r0 = (r[6] - ln) * w
        r1 = (r[7] - cl) * w
        if not (np.isfinite(r0) and np.isfinite(r1)):
            ok = False
        res[2 * i] = r0
        res[2 * i + 1] = r1
        if want_jac:
            for j in range(3):
                jac_p[(2 * i) * 3 + j] = -dl_dp[j] * w
                jac_p[(2 * i + 1) * 3 + j] = -dc_dp[j] * w
            _fill(i, r, img_tab, cam_tab, w, jacs, dl_dc, dc_dc, dl_di, dc_di)
    return ok


@njit(**_JIT)
def fixed_obs_block(rec, img_tab, cam_tab, pts, params, res, jacs, want_jac: bool):
    """Observations of fixed ground points ``pts`` (m, 3) (one image's resection block)."""
    k = rec.shape[0]
    ok = True
    if want_jac:
        for a in jacs:
            for q in range(a.shape[0]):
                a[q] = 0.0
    for i in range(k):
        r = rec[i]
        good, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp, dl_di, dc_di = _eval_record(r, img_tab, cam_tab, pts[i], params, want_jac)
        w = 1.0 / r[8]
        r0 = (r[6] - ln) * w
        r1 = (r[7] - cl) * w
        if not (np.isfinite(r0) and np.isfinite(r1)):
            ok = False
        res[2 * i] = r0
        res[2 * i + 1] = r1
        if want_jac:
            _fill(i, r, img_tab, cam_tab, w, jacs, dl_dc, dc_dc, dl_di, dc_di)
    return ok


@njit(**_JIT)
def all_observation_blocks(rec, img_tab, cam_tab, img_p, cam_p, pts, pt_idx, estimated, img_col, cam_col, width):
    """Whitened residuals and dense Jacobian pieces of every record (for the covariance).

    ``img_p`` (nimg, 24) and ``cam_p`` (ncam, N_IOP) hold the current free parameters; slots in
    ``rec`` are ignored. Returns res (n, 2), jf (n, 2, width) with column indices fcol (n, width)
    (-1 padding) over the image and camera parameters, jpt (n, 2, 3), ok (n).
    """
    n = rec.shape[0]
    res = np.empty((n, 2))
    jf = np.zeros((n, 2, width))
    fcol = -np.ones((n, width), dtype=np.int64)
    jpt = np.zeros((n, 2, 3))
    ok = np.empty(n, dtype=np.bool_)
    for i in range(n):
        r = rec[i]
        im = int(r[0])
        cm = int(r[1])
        it = img_tab[im]
        ct = cam_tab[cm]
        nf = int(it[1])
        nc = int(ct[0])
        coef = it[26:50].copy()
        for j in range(nf):
            coef[int(it[2 + j])] = img_p[im, j]
        oc = r[6:15]
        p = pts[pt_idx[i]]
        if ct[1] != 0.0:
            iop = ct[2 + N_IOP : 2 + 2 * N_IOP].copy()
            for j in range(nc):
                iop[int(ct[2 + j])] = cam_p[cm, j]
            good, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp, dl_di, dc_di = project_cam(int(it[0]), coef, it[50:67], p, oc, iop, int(r[4]), r[5], True)
        else:
            good, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp = project(int(it[0]), coef, it[50:67], p, oc, True)
            dl_di = np.zeros(N_IOP)
            dc_di = np.zeros(N_IOP)
        w = 1.0 / oc[2]
        res[i, 0] = (oc[0] - ln) * w
        res[i, 1] = (oc[1] - cl) * w
        ok[i] = good and np.isfinite(res[i, 0]) and np.isfinite(res[i, 1])
        for j in range(nf):
            fj = int(it[2 + j])
            fcol[i, j] = img_col[im] + j
            jf[i, 0, j] = -dl_dc[fj] * w
            jf[i, 1, j] = -dc_dc[fj] * w
        for j in range(nc):
            fj = int(ct[2 + j])
            fcol[i, nf + j] = cam_col[cm] + j
            jf[i, 0, nf + j] = -dl_di[fj] * w
            jf[i, 1, nf + j] = -dc_di[fj] * w
        if estimated[pt_idx[i]]:
            for j in range(3):
                jpt[i, 0, j] = -dl_dp[j] * w
                jpt[i, 1, j] = -dc_dp[j] * w
    return res, jf, fcol, jpt, ok


@njit(**_JIT)
def ray_cam(kind, coef, kc, oc, iop, chip: int, chip_len: float):
    """Perspective centre S and unit viewing direction (LGS) of an observed pixel, with IOP."""
    tau = oc[0] * oc[8]
    s, ds_dc, ds_dt, ang, da_dc, da_dt = platform_state(kind, coef, kc, tau)
    m = object_to_camera(kind, coef, kc, tau)
    dvec = m.T @ ideal_direction(oc, iop, chip, chip_len)
    dvec /= np.sqrt(dvec @ dvec)
    return s, dvec
