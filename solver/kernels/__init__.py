"""Numerical kernels (numba): rotation, platform evaluation and the pushbroom projection.

Everything that runs once per observation per solver evaluation lives here, compiled with numba
(``error_model="numpy"`` so a division by zero gives inf instead of raising inside Ceres).
The residual blocks in :mod:`solver.engine.backend` and the covariance code (:mod:`solver.engine.linalg`) call only
these functions, so a compiled C++ kernel could replace this package behind the same interface.
Beside it: :mod:`solver.kernels.propagation` (orbit propagation, J2, pass states) and
:mod:`solver.kernels.cache` (the disk cache of the compiled kernels, keyed on their sources).

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

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @njit)
from solver.kernels.propagation import (
    PASS_ATT_OFF,
    PASS_COEF_INDEX,
    PASS_INDEX,
    PASS_T_OFF,
    ensure_segment,
    gravity_and_gradient,
    pass_state,
)
from solver.kernels.rpc import rpc_project, rpc_ray

KIND_POLYNOMIAL = 0
KIND_KEPLER = 1
KIND_ORBIT_ATTITUDE = 2  # Kepler/J2 position, attitude relative to the orbital frame
KIND_PASS = 3  # one propagated orbit per pass (solver.kernels.propagation), attitude as orbit-attitude
KIND_RPC = 4  # RPC00B plus an image-space bias (solver.kernels.rpc): no camera, no platform
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
    ta = _attitude_time(kind, kc, tau)
    for k in range(1, 4):
        tp[k] = tp[k - 1] * ta
    # angles: polynomials for every model
    for e in range(3):
        for k in range(4):
            c = coef[(3 + e) * 4 + k]
            ang[e] += c * tp[k]
            da_dc[e, (3 + e) * 4 + k] = tp[k]
            if k >= 1:
                da_dt[e] += k * c * tp[k - 1]
    for k in range(1, 4):
        tp[k] = tp[k - 1] * tau
    if kind == KIND_POLYNOMIAL:
        for e in range(3):
            for k in range(4):
                c = coef[e * 4 + k]
                s[e] += c * tp[k]
                ds_dc[e, e * 4 + k] = tp[k]
                if k >= 1:
                    ds_dt[e] += k * c * tp[k - 1]
        return s, ds_dc, ds_dt, ang, da_dc, da_dt
    rot = kc[0:9].reshape(3, 3)
    org = kc[9:12]
    if kind == KIND_PASS:
        pe, ve, _ae, dse6, _dv6 = pass_state(kc, kc[PASS_T_OFF] + tau, True)
        s = rot @ (pe - org)
        ds6 = rot @ dse6
        for q in range(6):
            for i in range(3):
                ds_dc[i, PASS_COEF_INDEX[q]] = ds6[i, q]
        ds_dt = rot @ ve
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
def _attitude_time(kind, kc, tau: float) -> float:
    """Time variable of the angle polynomials: tau, shifted for pass images whose attitude is
    shared by the images of one camera (then in s since the pass reference epoch)."""
    if kind == KIND_PASS:
        return tau + kc[PASS_ATT_OFF]
    return tau


@njit(**_JIT)
def _attitude_angles(coef, tau, ang, angdot):
    for e in range(3):
        c0 = coef[(3 + e) * 4]
        c1 = coef[(3 + e) * 4 + 1]
        c2 = coef[(3 + e) * 4 + 2]
        c3 = coef[(3 + e) * 4 + 3]
        ang[e] = c0 + tau * (c1 + tau * (c2 + tau * c3))
        angdot[e] = c1 + tau * (2.0 * c2 + 3.0 * tau * c3)


@njit(**_JIT)
def _pose(kind, coef, kc, acc, tau, s, sdot, ang, angdot):
    """Position (LGS) and its tau-derivative, angles and their tau-derivatives, at tau."""
    _attitude_angles(coef, tau, ang, angdot)
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
def _orbit_pos(kind, coef, kc, acc, tau, s, sdot, vdot):
    """Position (LGS), velocity and acceleration (LGS axes) of the orbit-attitude kinds at tau:
    the Kepler/J2 quadratic (KIND_ORBIT_ATTITUDE) or the propagated pass (KIND_PASS)."""
    r0 = kc[0:9].reshape(3, 3)
    if kind == KIND_PASS:
        pe, ve, ae, _ds, _dv = pass_state(kc, kc[PASS_T_OFF] + tau, False)
        for i in range(3):
            pe[i] -= kc[9 + i]
        s[:] = r0 @ pe
        sdot[:] = r0 @ ve
        vdot[:] = r0 @ ae
        return
    ang = np.empty(3)
    angdot = np.empty(3)
    _pose(KIND_KEPLER, coef, kc, acc, tau, s, sdot, ang, angdot)
    vdot[:] = r0 @ acc


@njit(**_JIT)
def _orbit_jac(kind, kc, da_dr, tau):
    """d(S, V)/d(state) in LGS axes (3 x 6 each): state = (S0, u) at line 0 for the Kepler
    quadratic, the pass state x0 at the reference epoch for KIND_PASS."""
    r0 = kc[0:9].reshape(3, 3)
    ds_dth = np.empty((3, 6))
    dv_dth = np.empty((3, 6))
    if kind == KIND_PASS:
        _p, _v, _a, ds, dv = pass_state(kc, kc[PASS_T_OFF] + tau, True)
        ds_dth[:, :] = r0 @ ds
        dv_dth[:, :] = r0 @ dv
        return ds_dth, dv_dth
    # S_lgs = R0 (S0 + u t + a h - O), V_lgs = R0 (u + a t); a = a(S0, u)
    h = 0.5 * tau * tau
    da_du = np.zeros((3, 3))
    da_du[0, 1] = 2.0 * kc[13]
    da_du[1, 0] = -2.0 * kc[13]
    ds_dth[:, 0:3] = r0 @ (np.eye(3) + h * da_dr)
    ds_dth[:, 3:6] = r0 @ (tau * np.eye(3) + h * da_du)
    dv_dth[:, 0:3] = r0 @ (tau * da_dr)
    dv_dth[:, 3:6] = r0 @ (np.eye(3) + tau * da_du)
    return ds_dth, dv_dth


@njit(**_JIT)
def ro_offset(kc):
    """R_ecef->lgs @ LGS origin: added to an LGS position it gives the geocentric position in
    LGS axes (the orbital frame's radial direction)."""
    return kc[0:9].reshape(3, 3) @ kc[9:12]


@njit(**_JIT)
def _orbital_frame_rate(s, v, c, sdot, vdot):
    """Orbital frame (as :func:`_orbital_frame`) and its time derivative along the trajectory
    (position rate ``sdot``, velocity rate ``vdot``), without the state derivatives: the cheap
    form for the Newton iterations on the line."""
    g0, g1, g2 = s[0] + c[0], s[1] + c[1], s[2] + c[2]
    gn = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    z = np.array([g0 / gn, g1 / gn, g2 / gn])
    zs = z[0] * sdot[0] + z[1] * sdot[1] + z[2] * sdot[2]
    dz = (sdot - zs * z) / gn
    vz = v[0] * z[0] + v[1] * z[1] + v[2] * z[2]
    h = v - vz * z
    hn = np.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
    x = h / hn
    dvz = vdot[0] * z[0] + vdot[1] * z[1] + vdot[2] * z[2] + v[0] * dz[0] + v[1] * dz[1] + v[2] * dz[2]
    dh = vdot - dvz * z - vz * dz
    xd = x[0] * dh[0] + x[1] * dh[1] + x[2] * dh[2]
    dx = (dh - xd * x) / hn
    r = np.empty((3, 3))
    dr = np.empty((3, 3))
    for i in range(3):
        r[0, i] = x[i]
        r[2, i] = z[i]
        dr[0, i] = dx[i]
        dr[2, i] = dz[i]
    # y = z x x
    r[1, 0] = z[1] * x[2] - z[2] * x[1]
    r[1, 1] = z[2] * x[0] - z[0] * x[2]
    r[1, 2] = z[0] * x[1] - z[1] * x[0]
    dr[1, 0] = dz[1] * x[2] - dz[2] * x[1] + z[1] * dx[2] - z[2] * dx[1]
    dr[1, 1] = dz[2] * x[0] - dz[0] * x[2] + z[2] * dx[0] - z[0] * dx[2]
    dr[1, 2] = dz[0] * x[1] - dz[1] * x[0] + z[0] * dx[1] - z[1] * dx[0]
    return r, dr


@njit(**_JIT)
def _oa_pose(kind, coef, kc, acc, tau, rot):
    """What the orbit-attitude projection needs at tau: S, Sdot, M = A R_orbit, dM/dtau, the
    attitude part A = Ry(mount) R_att, the mounting and R_orbit (``rot`` receives R_att and its
    angle derivatives)."""
    s = np.empty(3)
    sdot = np.empty(3)
    vdot = np.empty(3)
    ang = np.empty(3)
    angdot = np.empty(3)
    _orbit_pos(kind, coef, kc, acc, tau, s, sdot, vdot)
    _attitude_angles(coef, _attitude_time(kind, kc, tau), ang, angdot)
    _rotation_into(ang[0], ang[1], ang[2], rot)
    ro, dro_dt = _orbital_frame_rate(s, sdot, ro_offset(kc), sdot, vdot)
    mnt = _mount(kc[16])
    a_att = mnt @ rot[0]
    m = a_att @ ro
    dm_dt = a_att @ dro_dt
    datt = rot[1] * angdot[0] + rot[2] * angdot[1] + rot[3] * angdot[2]
    dm_dt += mnt @ datt @ ro
    return s, sdot, m, dm_dt, a_att, mnt, ro


@njit(**_JIT)
def _state_directions(kind, kc, da_dr, tau, s, sdot, a_att, m, v):
    """dd/d(state_q) (6 x 3) of the camera vector d = A R_orbit(S, V) (P - S) for the
    orbit-attitude kinds: through S(t) and through the orbital frame's dependence on S and V."""
    ds_dth, dv_dth = _orbit_jac(kind, kc, da_dr, tau)
    _ro, d_s, d_v = _orbital_frame(s, sdot, ro_offset(kc))
    out = np.empty((6, 3))
    for q in range(6):
        dro = np.zeros((3, 3))
        for k in range(3):
            dro += d_s[:, :, k] * ds_dth[k, q] + d_v[:, :, k] * dv_dth[k, q]
        out[q] = a_att @ dro @ v - m @ np.ascontiguousarray(ds_dth[:, q])
    return out


@njit(**_JIT)
def _camera_state(kind, coef, kc, acc, tau, p, rot, s, sdot, ang, angdot, v, d, ddt, mm, a_att, mnt, ro):
    """Everything a projection needs at tau, for every kind, filled in place: S, dS/dtau, the
    rotation M (``mm``), v = P - S, d = M v and dd/dtau; ``rot`` receives the angle rotation and
    its angle derivatives (the attitude part for the orbit-attitude kinds), and for those kinds
    ``a_att``, ``mnt``, ``ro`` the factors A = Ry(mount) R_att, Ry(mount) and R_orbit (left as
    they are for the other kinds)."""
    if kind == KIND_ORBIT_ATTITUDE or kind == KIND_PASS:
        s1, sdot1, m, dm_dt, a1, mnt1, ro1 = _oa_pose(kind, coef, kc, acc, tau, rot)
        s[:] = s1
        sdot[:] = sdot1
        mm[:, :] = m
        a_att[:, :] = a1
        mnt[:, :] = mnt1
        ro[:, :] = ro1
        for i in range(3):
            v[i] = p[i] - s[i]
        d[:] = m @ v
        ddt[:] = dm_dt @ v - m @ sdot
        return
    _pose(kind, coef, kc, acc, tau, s, sdot, ang, angdot)
    _rotation_into(ang[0], ang[1], ang[2], rot)
    mm[:, :] = rot[0]
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


@njit(**_JIT)
def _coef_gradients(kind, kc, da_dr, tau, s, sdot, v, mm, rot, a_att, mnt, ro, gx0, gx2, gy1, gy2):
    """Derivatives along every coefficient of two image functions whose gradients wrt the
    camera vector d are (gx0, 0, gx2) and (0, gy1, gy2), at the line's tau: returns (gxs[24],
    gys[24]). For KIND_PASS the pass-state derivatives are in the slots PASS_COEF_INDEX."""
    gxs = np.zeros(N_COEF)
    gys = np.zeros(N_COEF)
    oa = kind == KIND_ORBIT_ATTITUDE or kind == KIND_PASS
    # angles: dd/d(angle) = dM/d(angle) v (orbit-attitude: Ry(mount) dR_att R_orbit v), x t^k
    ta = _attitude_time(kind, kc, tau)
    rov = ro @ v if oa else v
    for e in range(3):
        if oa:
            dd = mnt @ (rot[1 + e] @ rov)
            d0, d1, d2 = dd[0], dd[1], dd[2]
        else:  # scalar form: this runs for every observation of the per-image models
            d0 = rot[1 + e, 0, 0] * v[0] + rot[1 + e, 0, 1] * v[1] + rot[1 + e, 0, 2] * v[2]
            d1 = rot[1 + e, 1, 0] * v[0] + rot[1 + e, 1, 1] * v[1] + rot[1 + e, 1, 2] * v[2]
            d2 = rot[1 + e, 2, 0] * v[0] + rot[1 + e, 2, 1] * v[1] + rot[1 + e, 2, 2] * v[2]
        gxd = gx0 * d0 + gx2 * d2
        gyd = gy1 * d1 + gy2 * d2
        tp = 1.0
        for k in range(4):
            gxs[(3 + e) * 4 + k] = gxd * tp
            gys[(3 + e) * 4 + k] = gyd * tp
            tp *= ta
    if oa:
        # state (S0, u) or pass x0: through S(t) and the orbital frame R_orbit(S, V)
        dds = _state_directions(kind, kc, da_dr, tau, s, sdot, a_att, mm, v)
        for q in range(6):
            idx = (q % 3) * 4 + (0 if q < 3 else 1)
            gxs[idx] = gx0 * dds[q, 0] + gx2 * dds[q, 2]
            gys[idx] = gy1 * dds[q, 1] + gy2 * dds[q, 2]
        return gxs, gys
    # position: dd/dS_lgs = -M
    wx = np.empty(3)
    wy = np.empty(3)
    for j in range(3):
        wx[j] = -(gx0 * mm[0, j] + gx2 * mm[2, j])
        wy[j] = -(gy1 * mm[1, j] + gy2 * mm[2, j])
    if kind == KIND_POLYNOMIAL:
        tp = 1.0
        for k in range(4):
            for e in range(3):
                gxs[e * 4 + k] = wx[e] * tp
                gys[e * 4 + k] = wy[e] * tp
            tp *= tau
        return gxs, gys
    # Kepler: S_lgs = R (S0 + u tau + a h - O); dS_ecef/dS0 = I + h da/dr, dS_ecef/du = tau I + h da/du
    h = 0.5 * tau * tau
    om2 = 2.0 * kc[13] * h
    ex = np.empty(3)  # row vectors wx^T R and wy^T R (ECEF)
    ey = np.empty(3)
    for j in range(3):
        ex[j] = wx[0] * kc[j] + wx[1] * kc[3 + j] + wx[2] * kc[6 + j]
        ey[j] = wy[0] * kc[j] + wy[1] * kc[3 + j] + wy[2] * kc[6 + j]
    for j in range(3):
        gxj = ex[j]
        gyj = ey[j]
        for i in range(3):
            gxj += ex[i] * h * da_dr[i, j]
            gyj += ey[i] * h * da_dr[i, j]
        gxs[j * 4] = gxj
        gys[j * 4] = gyj
    # d/du: tau I + h * [[0, 2W, 0], [-2W, 0, 0], [0, 0, 0]]
    gxs[1] = ex[0] * tau - ex[1] * om2
    gys[1] = ey[0] * tau - ey[1] * om2
    gxs[5] = ex[1] * tau + ex[0] * om2
    gys[5] = ey[1] * tau + ey[0] * om2
    gxs[9] = ex[2] * tau
    gys[9] = ey[2] * tau
    return gxs, gys


@njit(**_JIT)
def _kepler_terms_for(kind, coef, kc):
    """The Kepler acceleration terms a projection of this kind needs (zeros where none)."""
    if kind == KIND_KEPLER or kind == KIND_ORBIT_ATTITUDE:
        return _kepler_terms(coef, kc)
    return np.zeros(3), np.zeros((3, 3))


@njit(**_JIT)
def project(kind, coef, kc, p, oc, want_jac: bool):
    """Exact pushbroom projection of ground point ``p`` (LGS, m) with its observation constants.

    Solves ``-f d_x(tau(L))/d_z = xo`` for the line L by Newton's method starting at the
    observed line, then evaluates the column. Returns (ok, line, column, dL_dcoef[24],
    dL_dp[3], dC_dcoef[24], dC_dp[3]); derivatives by the implicit function theorem (for
    KIND_PASS the pass-state derivatives are in the coefficient slots PASS_COEF_INDEX).
    """
    if kind == KIND_RPC:
        return rpc_project(coef, kc, p, oc, want_jac)
    f = oc[3]
    px = oc[4]
    xo = oc[5]
    yo = oc[6]
    cc = oc[7]
    tpl = oc[8]
    line = oc[0]
    ok = False
    acc, da_dr = _kepler_terms_for(kind, coef, kc)
    rot = np.empty((4, 3, 3))
    fac = np.empty((4, 3, 3))  # M, then the orbit-attitude factors A, Ry(mount), R_orbit
    mm, a_att, mnt, ro = fac[0], fac[1], fac[2], fac[3]
    s = np.empty(3)
    sdot = np.empty(3)
    ang = np.empty(3)
    angdot = np.empty(3)
    d = np.empty(3)
    ddt = np.empty(3)
    v = np.empty(3)
    for it in range(31):
        tau = line * tpl
        _camera_state(kind, coef, kc, acc, tau, p, rot, s, sdot, ang, angdot, v, d, ddt, mm, a_att, mnt, ro)
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
        dxp = gx0 * mm[0, j] + gx2 * mm[2, j]
        dyp = gy1 * mm[1, j] + gy2 * mm[2, j]
        dl_dp[j] = -dxp / dx_dl
        dc_dp[j] = (dyp + dy_dl * dl_dp[j]) / px
    gxs, gys = _coef_gradients(kind, kc, da_dr, tau, s, sdot, v, mm, rot, a_att, mnt, ro, gx0, gx2, gy1, gy2)
    for idx in range(N_COEF):
        dl_dc[idx] = -gxs[idx] / dx_dl
        dc_dc[idx] = (gys[idx] + dy_dl * dl_dc[idx]) / px
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
    if kind == KIND_ORBIT_ATTITUDE or kind == KIND_PASS:
        rot = np.empty((4, 3, 3))
        acc = _kepler_terms(coef, kc)[0] if kind == KIND_ORBIT_ATTITUDE else np.zeros(3)
        return _oa_pose(kind, coef, kc, acc, tau, rot)[2]
    ang = platform_state(kind, coef, kc, tau)[3]
    return rotation_and_derivatives(ang[0], ang[1], ang[2])[0]


@njit(**_JIT)
def ray(kind, coef, kc, oc):
    """Perspective centre S (LGS) and unit viewing direction (LGS) of an observation's pixel."""
    if kind == KIND_RPC:
        return rpc_ray(coef, kc, oc)
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
from solver.schema.iop_names import IOP_CHIP, IOP_OPTICAL, MAX_CHIPS  # noqa: E402 (shared with the job schema)

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
    acc, da_dr = _kepler_terms_for(kind, coef, kc)
    fac = np.empty((4, 3, 3))  # M, then the orbit-attitude factors A, Ry(mount), R_orbit
    mm, a_att, mnt, ro = fac[0], fac[1], fac[2], fac[3]
    xi = yi = big_f = dxi_dc = dyi_dc = 0.0
    dxi_diop = np.zeros(N_IOP)
    dyi_diop = np.zeros(N_IOP)
    j11 = j12 = j21 = j22 = 0.0
    for it in range(31):
        tau = line * tpl
        _camera_state(kind, coef, kc, acc, tau, p, rot, s, sdot, ang, angdot, v, d, ddt, mm, a_att, mnt, ro)
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
        gx = hx0 * mm[0, j] + hx2 * mm[2, j]
        gy = hy1 * mm[1, j] + hy2 * mm[2, j]
        dl_dp[j], dc_dp[j] = _solve(gx, gy)
    gxs, gys = _coef_gradients(kind, kc, da_dr, tau, s, sdot, v, mm, rot, a_att, mnt, ro, hx0, hx2, hy1, hy2)
    for idx in range(N_COEF):
        dl_dc[idx], dc_dc[idx] = _solve(gxs[idx], gys[idx])
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
# (the pass kind appends its propagated segment to kc: the row is then longer, see
#  solver.kernels.propagation; kc is always it[KC_START:])
# observation record (16): image, camera, image slot, camera slot (-1: constant), chip index,
#                          chip length (mm), oc[9], pass slot (-1: constant or no pass)
# named offsets of the packed rows (solver.engine.packed_tables writes them, the kernels read them)
IT_KIND = 0  # img_tab: model kind (KIND_*)
IT_NFREE = 1  # img_tab: number of free coefficients
IT_FREE = 2  # img_tab: free coefficient indices, N_COEF slots
IT_BASE = IT_FREE + N_COEF  # img_tab: full coefficient vector (held and current), N_COEF long
KC_START = IT_BASE + N_COEF  # img_tab: kc, N_KEPLER_CONST long (pass kind: + its segment)
IMG_TAB = KC_START + N_KEPLER_CONST
CAM_TAB = 2 + 2 * N_IOP
REC_IMAGE = 0  # observation record: image index
REC_CAMERA = 1  # camera index
REC_IMG_SLOT = 2  # image parameter slot (-1: constant)
REC_CAM_SLOT = 3  # camera parameter slot (-1: constant)
REC_CHIP = 4  # chip index in the camera
REC_CHIP_LEN = 5  # chip length (mm)
REC_OC = 6  # oc[N_OBS_CONST]: line, column, sigma_px, ...
REC_LINE = REC_OC  # observed line (px)
REC_COLUMN = REC_OC + 1  # observed column (px)
REC_SIGMA = REC_OC + 2  # sigma (px)
REC_PASS_SLOT = REC_OC + N_OBS_CONST  # pass parameter slot (-1: constant or no pass)
OBS_REC = REC_PASS_SLOT + 1


@njit(**_JIT)
def _eval_record(r, img_tab, cam_tab, p, params, want: bool):
    im = int(r[REC_IMAGE])
    cm = int(r[REC_CAMERA])
    islot = int(r[REC_IMG_SLOT])
    cslot = int(r[REC_CAM_SLOT])
    it = img_tab[im]
    kind = int(it[IT_KIND])
    nf = int(it[IT_NFREE])
    coef = it[IT_BASE:KC_START].copy()
    if islot >= 0:
        pi = params[islot]
        for j in range(nf):
            coef[int(it[IT_FREE + j])] = pi[j]
    kc = it[KC_START:]
    if kind == KIND_PASS and r[REC_PASS_SLOT] >= 0:
        ensure_segment(kc, params[int(r[REC_PASS_SLOT])])
    oc = r[REC_OC:REC_PASS_SLOT]
    ct = cam_tab[cm]
    if ct[1] != 0.0 and kind != KIND_RPC:
        iop = ct[2 + N_IOP : 2 + 2 * N_IOP].copy()
        if cslot >= 0:
            pc = params[cslot]
            for j in range(int(ct[0])):
                iop[int(ct[2 + j])] = pc[j]
        return project_cam(kind, coef, kc, p, oc, iop, int(r[REC_CHIP]), r[REC_CHIP_LEN], want)
    ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp = project(kind, coef, kc, p, oc, want)
    empty = np.empty(0)  # no interior orientation: _fill skips the camera (slot -1)
    return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp, empty, empty


@njit(**_JIT)
def _put_rows(block, i, idx, dl, dc, w):
    """Rows 2i, 2i+1 of a residual block's dense Jacobian wrt one parameter block whose entries
    are dl[idx[j]], dc[idx[j]] (line and column derivatives), whitened and negated."""
    n = idx.shape[0]
    for j in range(n):
        q = int(idx[j])
        block[(2 * i) * n + j] = -dl[q] * w
        block[(2 * i + 1) * n + j] = -dc[q] * w


@njit(**_JIT)
def _fill(i, r, img_tab, cam_tab, w, jacs, dl_dc, dc_dc, dl_di, dc_di):
    """Observation i's rows in the Jacobians of its image, pass and camera blocks (slots)."""
    islot = int(r[REC_IMG_SLOT])
    if islot >= 0:
        it = img_tab[int(r[REC_IMAGE])]
        _put_rows(jacs[islot], i, it[IT_FREE : IT_FREE + int(it[IT_NFREE])], dl_dc, dc_dc, w)
    pslot = int(r[REC_PASS_SLOT])
    if pslot >= 0:
        _put_rows(jacs[pslot], i, PASS_COEF_INDEX, dl_dc, dc_dc, w)
    cslot = int(r[REC_CAM_SLOT])
    if cslot >= 0:
        ct = cam_tab[int(r[REC_CAMERA])]
        _put_rows(jacs[cslot], i, ct[2 : 2 + int(ct[0])], dl_di, dc_di, w)


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
        w = 1.0 / r[REC_SIGMA]
        r0 = (r[REC_LINE] - ln) * w
        r1 = (r[REC_COLUMN] - cl) * w
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
        w = 1.0 / r[REC_SIGMA]
        r0 = (r[REC_LINE] - ln) * w
        r1 = (r[REC_COLUMN] - cl) * w
        if not (np.isfinite(r0) and np.isfinite(r1)):
            ok = False
        res[2 * i] = r0
        res[2 * i + 1] = r1
        if want_jac:
            _fill(i, r, img_tab, cam_tab, w, jacs, dl_dc, dc_dc, dl_di, dc_di)
    return ok


@njit(**_JIT)
def all_observation_blocks(rec, img_tab, cam_tab, img_p, cam_p, pts, pt_idx, estimated, img_col, cam_col, pass_col, width):
    """Whitened residuals and dense Jacobian pieces of every record (for the covariance).

    ``img_p`` (nimg, 24) and ``cam_p`` (ncam, N_IOP) hold the current free parameters; pass
    segments in ``img_tab`` must be current; slots in ``rec`` are ignored. Returns res (n, 2),
    jf (n, 2, width) with column indices fcol (n, width) (-1 padding) over the image, camera and
    pass parameters (``pass_col``: first column of each pass), jpt (n, 2, 3), ok (n).
    """
    n = rec.shape[0]
    res = np.empty((n, 2))
    jf = np.zeros((n, 2, width))
    fcol = -np.ones((n, width), dtype=np.int64)
    jpt = np.zeros((n, 2, 3))
    ok = np.empty(n, dtype=np.bool_)
    for i in range(n):
        r = rec[i]
        im = int(r[REC_IMAGE])
        cm = int(r[REC_CAMERA])
        it = img_tab[im]
        ct = cam_tab[cm]
        nf = int(it[IT_NFREE])
        nc = int(ct[0]) if int(it[IT_KIND]) != KIND_RPC else 0
        coef = it[IT_BASE:KC_START].copy()
        for j in range(nf):
            coef[int(it[IT_FREE + j])] = img_p[im, j]
        oc = r[REC_OC:REC_PASS_SLOT]
        p = pts[pt_idx[i]]
        if ct[1] != 0.0 and int(it[IT_KIND]) != KIND_RPC:
            iop = ct[2 + N_IOP : 2 + 2 * N_IOP].copy()
            for j in range(nc):
                iop[int(ct[2 + j])] = cam_p[cm, j]
            good, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp, dl_di, dc_di = project_cam(int(it[IT_KIND]), coef, it[KC_START:], p, oc, iop, int(r[REC_CHIP]), r[REC_CHIP_LEN], True)
        else:
            good, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp = project(int(it[IT_KIND]), coef, it[KC_START:], p, oc, True)
            dl_di = np.zeros(N_IOP)
            dc_di = np.zeros(N_IOP)
        w = 1.0 / oc[2]
        res[i, 0] = (oc[0] - ln) * w
        res[i, 1] = (oc[1] - cl) * w
        ok[i] = good and np.isfinite(res[i, 0]) and np.isfinite(res[i, 1])
        for j in range(nf):
            fj = int(it[IT_FREE + j])
            fcol[i, j] = img_col[im] + j
            jf[i, 0, j] = -dl_dc[fj] * w
            jf[i, 1, j] = -dc_dc[fj] * w
        for j in range(nc):
            fj = int(ct[2 + j])
            fcol[i, nf + j] = cam_col[cm] + j
            jf[i, 0, nf + j] = -dl_di[fj] * w
            jf[i, 1, nf + j] = -dc_di[fj] * w
        if int(it[IT_KIND]) == KIND_PASS:
            pc = pass_col[int(it[KC_START + PASS_INDEX])]
            for j in range(6):
                fj = PASS_COEF_INDEX[j]
                fcol[i, nf + nc + j] = pc + j
                jf[i, 0, nf + nc + j] = -dl_dc[fj] * w
                jf[i, 1, nf + nc + j] = -dc_dc[fj] * w
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
