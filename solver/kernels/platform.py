"""Platform evaluation (numba): the perspective centre and the rotation object -> camera of an
image at a scaled time tau, with derivatives, for every platform kind. This module and
:mod:`solver.kernels.projection` are the only places the kernels branch on the kind's dispatch
code (``KIND_*``, :mod:`solver.kernels.layout`); a kind with new mathematics adds its branch
here (and, without a camera, in the projection entry point)."""

from __future__ import annotations

import numpy as np
from numba import njit

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @njit)
from solver.kernels.layout import JIT as _JIT
from solver.kernels.layout import KC_ATT_BASE, KIND_KEPLER, KIND_ORBIT_ATTITUDE, KIND_PASS, KIND_POLYNOMIAL, N_COEF
from solver.kernels.layout import LEAF as _LEAF
from solver.kernels.propagation import (
    PASS_ATT_OFF,
    PASS_COEF_INDEX,
    PASS_T_OFF,
    _hermite_basis,
    gravity_and_gradient_into,
    pass_state,
    pass_state_column,
    pass_values_into,
)
from solver.kernels.rotation import (
    _frame_rows_rate,
    _mount_into,
    _orbital_frame_rate_into,
    _rotation_into,
    mat_mat,
    mat_vec,
    ro_offset_scalars,
    rotation_and_derivatives,
)


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
    _attitude_base_into(kc, ta, ang, da_dt)
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
        s = mat_vec(rot, pe - org)
        ds6 = mat_mat(rot, dse6)
        for q in range(6):
            for i in range(3):
                ds_dc[i, PASS_COEF_INDEX[q]] = ds6[i, q]
        ds_dt = mat_vec(rot, ve)
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
    s = mat_vec(rot, se - org)
    ds_dc = mat_mat(rot, dse)
    ds_dt = mat_vec(rot, sdt)
    return s, ds_dc, ds_dt, ang, da_dc, da_dt


@njit(**_JIT)
def _kepler_terms(coef, kc):
    """Rotating-frame acceleration at the state (S0, u) and its derivatives (once per call)."""
    a = np.empty(3)
    gg = np.empty((3, 3))
    _kepler_terms_into(coef, kc, a, gg)
    return a, gg


@njit(**_LEAF)
def _kepler_terms_into(coef, kc, a, gg) -> None:
    """:func:`_kepler_terms` into ``a`` (3) and ``gg`` (3 x 3)."""
    om = kc[13]
    gravity_and_gradient_into(coef[0], coef[4], coef[8], kc[12], kc[14], kc[15], a, gg)
    a[0] += om * om * coef[0] + 2.0 * om * coef[5]
    a[1] += om * om * coef[4] - 2.0 * om * coef[1]
    gg[0, 0] += om * om
    gg[1, 1] += om * om


@njit(**_LEAF)
def _attitude_time(kind, kc, tau: float) -> float:
    """Time variable of the angle polynomials: tau, shifted for pass images whose attitude is
    shared by the images of one camera (then in s since the pass reference epoch)."""
    if kind == KIND_PASS:
        return tau + kc[PASS_ATT_OFF]
    return tau


@njit(**_LEAF)
def _attitude_base_into(kc, ta: float, ang, angdot) -> None:
    """Add the image's attitude base at the angle polynomials' time ``ta`` (s) to ``ang`` and
    its rate to ``angdot`` (rad, rad/s): the delivered attitude (roll, pitch, yaw relative to
    the orbital frame) interpolated linearly in the angles between its samples, as the
    handbooks of the vendors' line-scan models do, and extended linearly beyond its first and
    last intervals. The polynomials are then a smooth correction to it; its address in ``kc``
    is ``kc[KC_ATT_BASE]`` (0 or a constant vector without the slot: no base, nothing added).
    The derivatives along the coefficients do not change (the base is constant data)."""
    if kc.shape[0] <= KC_ATT_BASE:
        return
    b = int(kc[KC_ATT_BASE])
    if b <= 0:
        return
    n = int(kc[b])
    t0 = b + 1
    if n == 1:
        for e in range(3):
            ang[e] += kc[t0 + n * (1 + e)]
        return
    lo, hi = 0, n - 1  # the interval [lo, lo + 1] that holds ta (the end ones beyond the samples)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if kc[t0 + mid] <= ta:
            lo = mid
        else:
            hi = mid
    dt = kc[t0 + lo + 1] - kc[t0 + lo]
    u = (ta - kc[t0 + lo]) / dt
    for e in range(3):
        a0 = kc[t0 + n * (1 + e) + lo]
        a1 = kc[t0 + n * (1 + e) + lo + 1]
        ang[e] += a0 + u * (a1 - a0)
        angdot[e] += (a1 - a0) / dt


@njit(**_LEAF)
def _cubic(c0: float, c1: float, c2: float, c3: float, tau: float):
    """The cubic c0 + c1 tau + c2 tau^2 + c3 tau^3 and its tau-rate. (The coefficients as floats,
    not an array and a constant index: numba compiles a callee once per constant argument.)"""
    return c0 + tau * (c1 + tau * (c2 + tau * c3)), c1 + tau * (2.0 * c2 + 3.0 * tau * c3)


@njit(**_LEAF)
def _attitude_angles(coef, tau, ang, angdot):
    """The angle polynomials (rad) and their tau-rates at tau, into ``ang`` and ``angdot``."""
    for e in range(3):
        k = (3 + e) * 4
        ang[e], angdot[e] = _cubic(coef[k], coef[k + 1], coef[k + 2], coef[k + 3], tau)


@njit(**_LEAF)
def _to_lgs(kc, x: float, y: float, z: float):
    """The ECEF vector (x, y, z) in LGS axes (the rotation's rows are ``kc[0:9]``), as three floats."""
    return (kc[0] * x + kc[1] * y + kc[2] * z, kc[3] * x + kc[4] * y + kc[5] * z, kc[6] * x + kc[7] * y + kc[8] * z)


@njit(**_LEAF)
def _position_rate(kind, coef, kc, acc, tau):
    """Position (LGS, m) and its tau-rate at tau, as six floats, for every kind but the pass:
    the cubics of the polynomial kind, else the Kepler/J2 quadratic of the Earth-fixed state
    (``acc``: its acceleration) less the LGS origin, in LGS axes."""
    if kind == KIND_POLYNOMIAL:
        s0, w0 = _cubic(coef[0], coef[1], coef[2], coef[3], tau)
        s1, w1 = _cubic(coef[4], coef[5], coef[6], coef[7], tau)
        s2, w2 = _cubic(coef[8], coef[9], coef[10], coef[11], tau)
        return s0, s1, s2, w0, w1, w2
    h = 0.5 * tau * tau
    s0, s1, s2 = _to_lgs(kc, coef[0] + coef[1] * tau + acc[0] * h - kc[9], coef[4] + coef[5] * tau + acc[1] * h - kc[10],
                         coef[8] + coef[9] * tau + acc[2] * h - kc[11])
    w0, w1, w2 = _to_lgs(kc, coef[1] + acc[0] * tau, coef[5] + acc[1] * tau, coef[9] + acc[2] * tau)
    return s0, s1, s2, w0, w1, w2


@njit(**_LEAF)
def _pose(kind, coef, kc, acc, tau, s, sdot, ang, angdot):
    """Position (LGS) and its tau-derivative, angles and their tau-derivatives, at tau."""
    _attitude_angles(coef, tau, ang, angdot)
    s[0], s[1], s[2], sdot[0], sdot[1], sdot[2] = _position_rate(kind, coef, kc, acc, tau)


@njit(**_LEAF)
def _orbit_pos_into(kind, coef, kc, acc, tau, s, sdot, vdot, b, vecs) -> None:
    """Position (LGS), velocity and acceleration (LGS axes) of the orbit-attitude kinds at tau,
    into ``s``, ``sdot``, ``vdot``: the Kepler/J2 quadratic (KIND_ORBIT_ATTITUDE) or the
    propagated pass (KIND_PASS). ``b`` (3 x 6) and ``vecs`` (>= 3 x 3) are scratch."""
    if kind == KIND_PASS:
        pe, ve, ae = vecs[0], vecs[1], vecs[2]
        pass_values_into(kc, kc[PASS_T_OFF] + tau, b, pe, ve, ae)
        s[0], s[1], s[2] = _to_lgs(kc, pe[0] - kc[9], pe[1] - kc[10], pe[2] - kc[11])
        sdot[0], sdot[1], sdot[2] = _to_lgs(kc, ve[0], ve[1], ve[2])
        vdot[0], vdot[1], vdot[2] = _to_lgs(kc, ae[0], ae[1], ae[2])
        return
    # the Kepler position (``kind``, not the constant KIND_KEPLER: a constant argument compiles
    # the callee once more for its value)
    s[0], s[1], s[2], sdot[0], sdot[1], sdot[2] = _position_rate(kind, coef, kc, acc, tau)
    vdot[0], vdot[1], vdot[2] = _to_lgs(kc, acc[0], acc[1], acc[2])


@njit(**_LEAF)
def _state_column(kind, kc, da_dr, tau, bas, k0, q, ds, dv) -> None:
    """Column q of d(S, V)/d(state) in ECEF axes into ``ds``, ``dv`` (3 each): state = (S0, u)
    at line 0 for the Kepler quadratic, the pass state x0 at the reference epoch for KIND_PASS
    (``bas``: the Hermite basis at tau, ``k0``: its interval's first node)."""
    if kind == KIND_PASS:
        pass_state_column(kc, bas, k0, q, ds, dv)
        return
    # S = S0 + u t + a h, V = u + a t with a = a(S0, u): da/dS0 = da_dr, da/du = 2 Omega [[0, 1, 0], [-1, 0, 0], 0]
    h = 0.5 * tau * tau
    j = q % 3
    if q < 3:
        for i in range(3):
            ds[i] = (1.0 if i == j else 0.0) + h * da_dr[i, j]
            dv[i] = tau * da_dr[i, j]
        return
    w2 = 2.0 * kc[13]
    for i in range(3):
        ds[i] = tau if i == j else 0.0
        dv[i] = 1.0 if i == j else 0.0
    if j == 0:
        ds[1] -= h * w2
        dv[1] -= tau * w2
    elif j == 1:
        ds[0] += h * w2
        dv[0] += tau * w2


@njit(**_LEAF)
def _oa_frames_into(kind, coef, kc, acc, tau, rot, s, sdot, ro, dro, b, vecs) -> None:
    """The orbit-attitude kinds' factors at tau, in place and without allocating: S and Sdot
    (LGS), R_att and its angle derivatives (``rot``), R_orbit and its rate (``ro``, ``dro``);
    ``vecs`` (6 x 3) receives the angles in row 4 and their tau-derivatives in row 5 (rows
    0-3 and ``b`` (3 x 6) are scratch)."""
    vdot, ang, angdot = vecs[3], vecs[4], vecs[5]
    _orbit_pos_into(kind, coef, kc, acc, tau, s, sdot, vdot, b, vecs)
    ta = _attitude_time(kind, kc, tau)
    _attitude_angles(coef, ta, ang, angdot)
    _attitude_base_into(kc, ta, ang, angdot)
    _rotation_into(ang[0], ang[1], ang[2], rot)
    c0, c1, c2 = ro_offset_scalars(kc)
    _orbital_frame_rate_into(s, sdot, c0, c1, c2, sdot, vdot, ro, dro)


@njit(**_LEAF)
def _derivative_factors(kind, rot, mnt, ro, a_att, m) -> None:
    """Before derivatives, after the last :func:`_camera_state`: M (``m``) for every kind, and A
    for the orbit-attitude kinds, whose Newton steps do not form them (the per-image kinds
    filled M already)."""
    if kind == KIND_ORBIT_ATTITUDE or kind == KIND_PASS:
        _oa_factors_into(rot, mnt, ro, a_att, m)


@njit(**_LEAF)
def _oa_factors_into(rot, mnt, ro, a_att, m) -> None:
    """A = Ry(mount) R_att and M = A R_orbit from the factors (what the Jacobians need)."""
    for i in range(3):
        for j in range(3):
            a_att[i, j] = mnt[i, 0] * rot[0, 0, j] + mnt[i, 1] * rot[0, 1, j] + mnt[i, 2] * rot[0, 2, j]
    for i in range(3):
        for j in range(3):
            m[i, j] = a_att[i, 0] * ro[0, j] + a_att[i, 1] * ro[1, j] + a_att[i, 2] * ro[2, j]


@njit(**_LEAF)
def _oa_pose_into(kind, coef, kc, acc, tau, rot, s, sdot, m, dm_dt, a_att, mnt, ro, b, vecs, mats) -> None:
    """:func:`_oa_frames_into` and the matrices from its factors: M = A R_orbit, dM/dtau, the
    attitude part A = Ry(mount) R_att and the mounting. ``mats`` (3 x 3 x 3) is scratch."""
    dro, datt, md = mats[0], mats[1], mats[2]
    _oa_frames_into(kind, coef, kc, acc, tau, rot, s, sdot, ro, dro, b, vecs)
    angdot = vecs[5]
    _mount_into(kc[16], mnt)
    _oa_factors_into(rot, mnt, ro, a_att, m)
    for i in range(3):
        for j in range(3):
            datt[i, j] = rot[1, i, j] * angdot[0] + rot[2, i, j] * angdot[1] + rot[3, i, j] * angdot[2]
    for i in range(3):
        for j in range(3):
            md[i, j] = mnt[i, 0] * datt[0, j] + mnt[i, 1] * datt[1, j] + mnt[i, 2] * datt[2, j]
    for i in range(3):
        for j in range(3):
            dm_dt[i, j] = (a_att[i, 0] * dro[0, j] + a_att[i, 1] * dro[1, j] + a_att[i, 2] * dro[2, j]) + (
                md[i, 0] * ro[0, j] + md[i, 1] * ro[1, j] + md[i, 2] * ro[2, j]
            )


@njit(**_JIT)
def _oa_pose(kind, coef, kc, acc, tau, rot):
    """:func:`_oa_pose_into` returning (S, Sdot, M, dM/dtau, A, mounting, R_orbit)."""
    s = np.empty(3)
    sdot = np.empty(3)
    fac = np.empty((5, 3, 3))
    _oa_pose_into(kind, coef, kc, acc, tau, rot, s, sdot, fac[0], fac[1], fac[2], fac[3], fac[4],
                  np.empty((3, 6)), np.empty((6, 3)), np.empty((3, 3, 3)))
    return s, sdot, fac[0], fac[1], fac[2], fac[3], fac[4]


@njit(**_LEAF)
def _oa_state_gradients(kind, kc, da_dr, tau, s, sdot, a_att, m, v, gx0, gx2, gy1, gy2, gxs, gys, bas, col) -> None:
    """Derivatives along the six state components of the two image functions of
    :func:`_coef_gradients_into` (gradients (gx0, 0, gx2), (0, gy1, gy2) wrt d) for the orbit-attitude
    kinds, into their slots of ``gxs``, ``gys``. The camera vector d = A R_orbit(S, V) (P - S)
    moves through S(t) and through the orbital frame's dependence on S and V:

        dd_q = A (dR_orbit/dstate_q) v - M dS/dstate_q,   v = P - S,

    where dR_orbit/dstate_q is the frame's directional derivative along (dS, dV)_q: the
    formulas of :func:`solver.kernels.rotation._orbital_frame_rate` with the state's
    derivatives in place of the time rates. The gradients are applied to A and M first (g A,
    g M), so each component costs a few dot products; in scalars (this runs for every
    observation). ``bas`` (3 x 6) and ``col`` (2 x 3) are scratch."""
    k0 = 0
    if kind == KIND_PASS:
        k0 = _hermite_basis(kc, kc[PASS_T_OFF] + tau, bas)
    c0, c1, c2 = ro_offset_scalars(kc)
    g0, g1, g2 = s[0] + c0, s[1] + c1, s[2] + c2
    gn = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    z0, z1, z2 = g0 / gn, g1 / gn, g2 / gn
    vz = sdot[0] * z0 + sdot[1] * z1 + sdot[2] * z2
    h0, h1, h2 = sdot[0] - vz * z0, sdot[1] - vz * z1, sdot[2] - vz * z2
    hn = np.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
    x0, x1, x2 = h0 / hn, h1 / hn, h2 / hn
    # the gradients through A (row vectors gA) and through M (gM)
    ax0, ax1, ax2 = gx0 * a_att[0, 0] + gx2 * a_att[2, 0], gx0 * a_att[0, 1] + gx2 * a_att[2, 1], gx0 * a_att[0, 2] + gx2 * a_att[2, 2]
    ay0, ay1, ay2 = gy1 * a_att[1, 0] + gy2 * a_att[2, 0], gy1 * a_att[1, 1] + gy2 * a_att[2, 1], gy1 * a_att[1, 2] + gy2 * a_att[2, 2]
    mx0, mx1, mx2 = gx0 * m[0, 0] + gx2 * m[2, 0], gx0 * m[0, 1] + gx2 * m[2, 1], gx0 * m[0, 2] + gx2 * m[2, 2]
    my0, my1, my2 = gy1 * m[1, 0] + gy2 * m[2, 0], gy1 * m[1, 1] + gy2 * m[2, 1], gy1 * m[1, 2] + gy2 * m[2, 2]
    for q in range(6):
        _state_column(kind, kc, da_dr, tau, bas, k0, q, col[0], col[1])
        s0, s1, s2 = _to_lgs(kc, col[0, 0], col[0, 1], col[0, 2])  # dS, dV of the state component in LGS axes
        u0, u1, u2 = _to_lgs(kc, col[1, 0], col[1, 1], col[1, 2])
        zs = z0 * s0 + z1 * s1 + z2 * s2
        dz0, dz1, dz2 = (s0 - zs * z0) / gn, (s1 - zs * z1) / gn, (s2 - zs * z2) / gn
        dx0, dx1, dx2, dy0, dy1, dy2 = _frame_rows_rate(z0, z1, z2, dz0, dz1, dz2, x0, x1, x2, hn, vz, sdot[0], sdot[1], sdot[2],
                                                         u0, u1, u2)
        w0 = dx0 * v[0] + dx1 * v[1] + dx2 * v[2]  # (dR_orbit/dstate_q) v
        w1 = dy0 * v[0] + dy1 * v[1] + dy2 * v[2]
        w2 = dz0 * v[0] + dz1 * v[1] + dz2 * v[2]
        idx = (q % 3) * 4 + (0 if q < 3 else 1)
        gxs[idx] = ax0 * w0 + ax1 * w1 + ax2 * w2 - (mx0 * s0 + mx1 * s1 + mx2 * s2)
        gys[idx] = ay0 * w0 + ay1 * w1 + ay2 * w2 - (my0 * s0 + my1 * s1 + my2 * s2)


@njit(**_LEAF)
def _image_camera_vector(kind, coef, kc, acc, tau, p):
    """d = M (P - S) and dd/dtau at tau for the per-image kinds (polynomial, Kepler), as six
    floats: the arithmetic of :func:`_camera_state`'s per-image branch without its arrays (no
    work array is read or written, so the Newton loop on the line keeps everything in
    registers; on the 100k strip this is most of a residual evaluation). The factors the
    Jacobians need (S, M, its angle derivatives) are left to :func:`_camera_state` at the
    solution."""
    om, dom = _cubic(coef[12], coef[13], coef[14], coef[15], tau)
    ph, dph = _cubic(coef[16], coef[17], coef[18], coef[19], tau)
    ka, dka = _cubic(coef[20], coef[21], coef[22], coef[23], tau)
    s0, s1, s2, w0, w1, w2 = _position_rate(kind, coef, kc, acc, tau)
    co, so = np.cos(om), np.sin(om)
    cp, sp = np.cos(ph), np.sin(ph)
    ck, sk = np.cos(ka), np.sin(ka)
    # M = Rx(om) Ry(ph) Rz(ka) and dM/dtau = sum over the angles of dM/dangle angle' (the
    # entries of solver.kernels.rotation._rotation_into)
    m00, m01, m02 = cp * ck, -cp * sk, sp
    m10, m11, m12 = co * sk + so * sp * ck, co * ck - so * sp * sk, -so * cp
    m20, m21, m22 = so * sk - co * sp * ck, so * ck + co * sp * sk, co * cp
    n00 = -sp * ck * dph - cp * sk * dka
    n01 = sp * sk * dph - cp * ck * dka
    n02 = cp * dph
    n10 = (-so * sk + co * sp * ck) * dom + so * cp * ck * dph + (co * ck - so * sp * sk) * dka
    n11 = (-so * ck - co * sp * sk) * dom - so * cp * sk * dph + (-co * sk - so * sp * ck) * dka
    n12 = -co * cp * dom + so * sp * dph
    n20 = (co * sk + so * sp * ck) * dom - co * cp * ck * dph + (so * ck + co * sp * sk) * dka
    n21 = (co * ck - so * sp * sk) * dom + co * cp * sk * dph + (-so * sk + co * sp * ck) * dka
    n22 = -so * cp * dom - co * sp * dph
    v0, v1, v2 = p[0] - s0, p[1] - s1, p[2] - s2
    d0 = m00 * v0 + m01 * v1 + m02 * v2
    d1 = m10 * v0 + m11 * v1 + m12 * v2
    d2 = m20 * v0 + m21 * v1 + m22 * v2
    t0 = (n00 * v0 - m00 * w0) + (n01 * v1 - m01 * w1) + (n02 * v2 - m02 * w2)
    t1 = (n10 * v0 - m10 * w0) + (n11 * v1 - m11 * w1) + (n12 * v2 - m12 * w2)
    t2 = (n20 * v0 - m20 * w0) + (n21 * v1 - m21 * w1) + (n22 * v2 - m22 * w2)
    return d0, d1, d2, t0, t1, t2


@njit(**_LEAF)
def _camera_state(kind, coef, kc, acc, tau, p, rot, s, sdot, v, d, ddt, mm, mnt, ro, dro, vecs, b):
    """What a Newton step on the line needs at tau, for every kind, filled in place: S, dS/dtau,
    v = P - S, d = M v and dd/dtau; ``rot`` receives the angle rotation and its angle
    derivatives (the attitude part for the orbit-attitude kinds). The per-image kinds also fill
    M (``mm``); the orbit-attitude kinds fill R_orbit and its rate (``ro``, ``dro``) and leave
    M to :func:`_derivative_factors` (the Jacobians alone need it): they form d and its rate as
    products with vectors, Ry(mount) R_att (R_orbit v), with ``mnt`` = Ry(mount) filled by
    :func:`_projection_terms`. ``vecs`` (6 x 3) and ``b`` (3 x 6) are scratch."""
    if kind == KIND_ORBIT_ATTITUDE or kind == KIND_PASS:
        _oa_frames_into(kind, coef, kc, acc, tau, rot, s, sdot, ro, dro, b, vecs)
        angdot = vecs[5]
        v0, v1, v2 = p[0] - s[0], p[1] - s[1], p[2] - s[2]
        v[0], v[1], v[2] = v0, v1, v2
        # w = R_orbit v and its rate dR_orbit/dtau v - R_orbit Sdot
        w0 = ro[0, 0] * v0 + ro[0, 1] * v1 + ro[0, 2] * v2
        w1 = ro[1, 0] * v0 + ro[1, 1] * v1 + ro[1, 2] * v2
        w2 = ro[2, 0] * v0 + ro[2, 1] * v1 + ro[2, 2] * v2
        q0 = dro[0, 0] * v0 + dro[0, 1] * v1 + dro[0, 2] * v2 - (ro[0, 0] * sdot[0] + ro[0, 1] * sdot[1] + ro[0, 2] * sdot[2])
        q1 = dro[1, 0] * v0 + dro[1, 1] * v1 + dro[1, 2] * v2 - (ro[1, 0] * sdot[0] + ro[1, 1] * sdot[1] + ro[1, 2] * sdot[2])
        q2 = dro[2, 0] * v0 + dro[2, 1] * v1 + dro[2, 2] * v2 - (ro[2, 0] * sdot[0] + ro[2, 1] * sdot[1] + ro[2, 2] * sdot[2])
        # t = R_att w and its rate R_att q + (dR_att/dtau) w
        t0 = rot[0, 0, 0] * w0 + rot[0, 0, 1] * w1 + rot[0, 0, 2] * w2
        t1 = rot[0, 1, 0] * w0 + rot[0, 1, 1] * w1 + rot[0, 1, 2] * w2
        t2 = rot[0, 2, 0] * w0 + rot[0, 2, 1] * w1 + rot[0, 2, 2] * w2
        u0 = rot[0, 0, 0] * q0 + rot[0, 0, 1] * q1 + rot[0, 0, 2] * q2
        u1 = rot[0, 1, 0] * q0 + rot[0, 1, 1] * q1 + rot[0, 1, 2] * q2
        u2 = rot[0, 2, 0] * q0 + rot[0, 2, 1] * q1 + rot[0, 2, 2] * q2
        for e in range(3):
            a = angdot[e]
            u0 += a * (rot[1 + e, 0, 0] * w0 + rot[1 + e, 0, 1] * w1 + rot[1 + e, 0, 2] * w2)
            u1 += a * (rot[1 + e, 1, 0] * w0 + rot[1 + e, 1, 1] * w1 + rot[1 + e, 1, 2] * w2)
            u2 += a * (rot[1 + e, 2, 0] * w0 + rot[1 + e, 2, 1] * w1 + rot[1 + e, 2, 2] * w2)
        # d = Ry(mount) t (a rotation about the camera's y axis)
        cm, sm = mnt[0, 0], mnt[0, 2]
        d[0] = cm * t0 + sm * t2
        d[1] = t1
        d[2] = -sm * t0 + cm * t2
        ddt[0] = cm * u0 + sm * u2
        ddt[1] = u1
        ddt[2] = -sm * u0 + cm * u2
        return
    ang, angdot = vecs[4], vecs[5]
    _pose(kind, coef, kc, acc, tau, s, sdot, ang, angdot)
    _rotation_into(ang[0], ang[1], ang[2], rot)
    for i in range(3):  # element by element: a slice assignment of an array compiles numba's
        for j in range(3):  # shape check and its error message (a tenth of a cold compile)
            mm[i, j] = rot[0, i, j]
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


@njit(**_LEAF)
def _coef_gradients_into(kind, kc, da_dr, tau, s, sdot, v, mm, rot, a_att, mnt, ro, gx0, gx2, gy1, gy2, gxs, gys, bas, col) -> None:
    """Derivatives along every coefficient of two image functions whose gradients wrt the
    camera vector d are (gx0, 0, gx2) and (0, gy1, gy2), at the line's tau, into ``gxs`` and
    ``gys`` (24 each, zeros on entry: the slots a kind has no coefficient for stay 0). For
    KIND_PASS the pass-state derivatives are in the slots PASS_COEF_INDEX. ``bas`` (3 x 6) and
    ``col`` (2 x 3) are scratch."""
    oa = kind == KIND_ORBIT_ATTITUDE or kind == KIND_PASS
    # angles: dd/d(angle) = dM/d(angle) v, x t^k; orbit-attitude: Ry(mount) dR_att R_orbit v, the
    # gradients taken through the mounting first (g Ry) and R_orbit v formed once (in scalars:
    # this runs for every observation)
    ta = _attitude_time(kind, kc, tau)
    r0, r1, r2 = v[0], v[1], v[2]
    bx0, bx1, bx2, by0, by1, by2 = gx0, 0.0, gx2, 0.0, gy1, gy2
    if oa:
        r0 = ro[0, 0] * v[0] + ro[0, 1] * v[1] + ro[0, 2] * v[2]
        r1 = ro[1, 0] * v[0] + ro[1, 1] * v[1] + ro[1, 2] * v[2]
        r2 = ro[2, 0] * v[0] + ro[2, 1] * v[1] + ro[2, 2] * v[2]
        bx0, bx1, bx2 = gx0 * mnt[0, 0] + gx2 * mnt[2, 0], gx0 * mnt[0, 1] + gx2 * mnt[2, 1], gx0 * mnt[0, 2] + gx2 * mnt[2, 2]
        by0, by1, by2 = gy1 * mnt[1, 0] + gy2 * mnt[2, 0], gy1 * mnt[1, 1] + gy2 * mnt[2, 1], gy1 * mnt[1, 2] + gy2 * mnt[2, 2]
    for e in range(3):
        d0 = rot[1 + e, 0, 0] * r0 + rot[1 + e, 0, 1] * r1 + rot[1 + e, 0, 2] * r2
        d1 = rot[1 + e, 1, 0] * r0 + rot[1 + e, 1, 1] * r1 + rot[1 + e, 1, 2] * r2
        d2 = rot[1 + e, 2, 0] * r0 + rot[1 + e, 2, 1] * r1 + rot[1 + e, 2, 2] * r2
        gxd = bx0 * d0 + bx1 * d1 + bx2 * d2
        gyd = by0 * d0 + by1 * d1 + by2 * d2
        tp = 1.0
        for k in range(4):
            gxs[(3 + e) * 4 + k] = gxd * tp
            gys[(3 + e) * 4 + k] = gyd * tp
            tp *= ta
    if oa:
        # state (S0, u) or pass x0: through S(t) and the orbital frame R_orbit(S, V)
        _oa_state_gradients(kind, kc, da_dr, tau, s, sdot, a_att, mm, v, gx0, gx2, gy1, gy2, gxs, gys, bas, col)
        return
    # position: dd/dS_lgs = -M (the row vectors w = -g M, in scalars: this runs for every observation)
    wx0 = -(gx0 * mm[0, 0] + gx2 * mm[2, 0])
    wx1 = -(gx0 * mm[0, 1] + gx2 * mm[2, 1])
    wx2 = -(gx0 * mm[0, 2] + gx2 * mm[2, 2])
    wy0 = -(gy1 * mm[1, 0] + gy2 * mm[2, 0])
    wy1 = -(gy1 * mm[1, 1] + gy2 * mm[2, 1])
    wy2 = -(gy1 * mm[1, 2] + gy2 * mm[2, 2])
    if kind == KIND_POLYNOMIAL:
        tp = 1.0
        for k in range(4):
            gxs[k], gxs[4 + k], gxs[8 + k] = wx0 * tp, wx1 * tp, wx2 * tp
            gys[k], gys[4 + k], gys[8 + k] = wy0 * tp, wy1 * tp, wy2 * tp
            tp *= tau
        return
    # Kepler: S_lgs = R (S0 + u tau + a h - O); dS_ecef/dS0 = I + h da/dr, dS_ecef/du = tau I + h da/du
    h = 0.5 * tau * tau
    om2 = 2.0 * kc[13] * h
    # row vectors wx^T R and wy^T R (ECEF)
    ex0, ex1, ex2 = (wx0 * kc[0] + wx1 * kc[3] + wx2 * kc[6], wx0 * kc[1] + wx1 * kc[4] + wx2 * kc[7],
                     wx0 * kc[2] + wx1 * kc[5] + wx2 * kc[8])
    ey0, ey1, ey2 = (wy0 * kc[0] + wy1 * kc[3] + wy2 * kc[6], wy0 * kc[1] + wy1 * kc[4] + wy2 * kc[7],
                     wy0 * kc[2] + wy1 * kc[5] + wy2 * kc[8])
    for j in range(3):
        gxs[j * 4] = ex0 if j == 0 else (ex1 if j == 1 else ex2)
        gys[j * 4] = ey0 if j == 0 else (ey1 if j == 1 else ey2)
        gxs[j * 4] += ex0 * h * da_dr[0, j]
        gxs[j * 4] += ex1 * h * da_dr[1, j]
        gxs[j * 4] += ex2 * h * da_dr[2, j]
        gys[j * 4] += ey0 * h * da_dr[0, j]
        gys[j * 4] += ey1 * h * da_dr[1, j]
        gys[j * 4] += ey2 * h * da_dr[2, j]
    # d/du: tau I + h * [[0, 2W, 0], [-2W, 0, 0], [0, 0, 0]]
    gxs[1] = ex0 * tau - ex1 * om2
    gys[1] = ey0 * tau - ey1 * om2
    gxs[5] = ex1 * tau + ex0 * om2
    gys[5] = ey1 * tau + ey0 * om2
    gxs[9] = ex2 * tau
    gys[9] = ey2 * tau


@njit(**_JIT)
def _projection_work():
    """Work arrays of one projection: ``rot`` (4 x 3 x 3: a rotation and its angle
    derivatives), ``mats`` (5 x 3 x 3: M, A, Ry(mount), R_orbit and its rate), ``vecs``
    (12 x 3: S, Sdot, v, d, dd/dtau, the Kepler acceleration, then six rows of scratch for
    :func:`_camera_state`), ``b`` (3 x 6, scratch) and ``da_dr`` (3 x 3)."""
    m = np.empty((10, 3, 3))  # the 3 x 3 ones as views of one allocation (an allocation costs about 30 ns)
    return m[0:4], m[4:9], np.empty((12, 3)), np.empty((3, 6)), m[9]


@njit(**_LEAF)
def _projection_terms(kind, coef, kc, acc, da_dr, mnt) -> None:
    """What stays constant over a projection's Newton steps, in place: the Kepler acceleration
    and its gradient (``acc``, ``da_dr``; zeros where the kind has none) and, for the
    orbit-attitude kinds, the camera mounting Ry(mount) (``mnt``)."""
    if kind == KIND_KEPLER or kind == KIND_ORBIT_ATTITUDE:
        _kepler_terms_into(coef, kc, acc, da_dr)
    else:
        for i in range(3):  # element by element (see _camera_state)
            acc[i] = 0.0
            for j in range(3):
                da_dr[i, j] = 0.0
    if kind == KIND_ORBIT_ATTITUDE or kind == KIND_PASS:
        _mount_into(kc[16], mnt)


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
def assemble(base, free_idx, p):
    """Full coefficient vector: ``base`` with the free entries replaced by ``p``."""
    coef = base.copy()
    for j in range(free_idx.shape[0]):
        coef[free_idx[j]] = p[j]
    return coef
