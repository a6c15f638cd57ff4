"""Rotations and frames (numba): M = Rx(omega) Ry(phi) Rz(kappa) and its angle derivatives, the
camera mounting Ry(pitch), and the orbital frame (along track, cross track, radial) of a state
with its derivatives. Conventions: :mod:`solver.kernels` and docs/models.md."""

from __future__ import annotations

import numpy as np
from numba import njit

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @njit)
from solver.kernels.layout import JIT as _JIT
from solver.kernels.layout import LEAF as _LEAF


@njit(**_JIT)
def mat_mat(a, b):
    """``a @ b`` for the small matrices of the kernels (3 x 3, 3 x 6) by plain loops: numba's
    ``@`` calls BLAS, whose call overhead (about half a microsecond) dominated the orbit-attitude
    and pass projections, which multiply a dozen 3 x 3 matrices per Newton step."""
    n, m, k = a.shape[0], b.shape[1], a.shape[1]
    out = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            acc = 0.0
            for q in range(k):
                acc += a[i, q] * b[q, j]
            out[i, j] = acc
    return out


@njit(**_JIT)
def mat_vec(a, v):
    """``a @ v`` for a small matrix and vector by plain loops (see :func:`mat_mat`)."""
    n, k = a.shape[0], a.shape[1]
    out = np.empty(n)
    for i in range(n):
        acc = 0.0
        for q in range(k):
            acc += a[i, q] * v[q]
        out[i] = acc
    return out


@njit(**_JIT)
def rotation_and_derivatives(om: float, ph: float, ka: float):
    """Return M, dM/domega, dM/dphi, dM/dkappa for M = Rx(om) Ry(ph) Rz(ka) (each 3x3)."""
    out = np.empty((4, 3, 3))
    _rotation_into(om, ph, ka, out)
    return out[0], out[1], out[2], out[3]


@njit(**_LEAF)
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


@njit(**_LEAF)
def _mount_into(angle: float, m) -> None:
    """The camera mounting Ry(angle) into ``m`` (3 x 3)."""
    c, s = np.cos(angle), np.sin(angle)
    m[0, 0], m[0, 1], m[0, 2] = c, 0.0, s
    m[1, 0], m[1, 1], m[1, 2] = 0.0, 1.0, 0.0
    m[2, 0], m[2, 1], m[2, 2] = -s, 0.0, c


@njit(**_JIT)
def _mount(angle: float):
    m = np.empty((3, 3))
    _mount_into(angle, m)
    return m


@njit(**_JIT)
def _orbital_frame(s, v, c):
    """Orbital frame from the LGS position ``s`` and Earth-fixed velocity ``v`` (LGS axes);
    ``c`` = R_ecef->lgs @ origin, so ``s + c`` is the geocentric position in LGS axes.

    Rows: x along track (velocity without its radial part: follows the ground track, i.e. yaw
    steering), y = z x x, z radial (away from the Earth). Returns (R, dR/ds, dR/dv) with
    dR[row, col, var].
    """
    g = s + c
    gn = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    z = g / gn
    dz = (np.eye(3) - np.outer(z, z)) / gn  # dz/ds
    vz = v[0] * z[0] + v[1] * z[1] + v[2] * z[2]
    h = v - vz * z
    hn = np.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
    x = h / hn
    px = (np.eye(3) - np.outer(x, x)) / hn
    # dh/ds = -(z v^T + vz I) dz/ds ; dh/dv = I - z z^T
    dh_ds = mat_mat(-(np.outer(z, v) + vz * np.eye(3)), dz)
    dh_dv = np.eye(3) - np.outer(z, z)
    dx_ds = mat_mat(px, dh_ds)
    dx_dv = mat_mat(px, dh_dv)
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


@njit(**_LEAF)
def _orbital_frame_rate_into(s, v, c0: float, c1: float, c2: float, sdot, vdot, r, dr) -> None:
    """Orbital frame (as :func:`_orbital_frame`) into ``r`` and its time derivative along the
    trajectory (position rate ``sdot``, velocity rate ``vdot``) into ``dr``, without the state
    derivatives and without allocating: the form for the Newton iterations on the line.
    (c0, c1, c2) is ``c`` of :func:`_orbital_frame`."""
    g0, g1, g2 = s[0] + c0, s[1] + c1, s[2] + c2
    gn = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    z0, z1, z2 = g0 / gn, g1 / gn, g2 / gn
    zs = z0 * sdot[0] + z1 * sdot[1] + z2 * sdot[2]
    dz0, dz1, dz2 = (sdot[0] - zs * z0) / gn, (sdot[1] - zs * z1) / gn, (sdot[2] - zs * z2) / gn
    vz = v[0] * z0 + v[1] * z1 + v[2] * z2
    h0, h1, h2 = v[0] - vz * z0, v[1] - vz * z1, v[2] - vz * z2
    hn = np.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
    x0, x1, x2 = h0 / hn, h1 / hn, h2 / hn
    dx0, dx1, dx2, dy0, dy1, dy2 = _frame_rows_rate(z0, z1, z2, dz0, dz1, dz2, x0, x1, x2, hn, vz, v[0], v[1], v[2],
                                                     vdot[0], vdot[1], vdot[2])
    r[0, 0], r[0, 1], r[0, 2] = x0, x1, x2
    r[2, 0], r[2, 1], r[2, 2] = z0, z1, z2
    dr[0, 0], dr[0, 1], dr[0, 2] = dx0, dx1, dx2
    dr[2, 0], dr[2, 1], dr[2, 2] = dz0, dz1, dz2
    # y = z x x
    r[1, 0] = z1 * x2 - z2 * x1
    r[1, 1] = z2 * x0 - z0 * x2
    r[1, 2] = z0 * x1 - z1 * x0
    dr[1, 0], dr[1, 1], dr[1, 2] = dy0, dy1, dy2


@njit(**_LEAF)
def _frame_rows_rate(z0, z1, z2, dz0, dz1, dz2, x0, x1, x2, hn, vz, v0, v1, v2, u0, u1, u2):
    """The derivatives of the orbital frame's rows x and y = z x x along a direction in which
    the radial row z moves by (dz0, dz1, dz2) and the velocity by (u0, u1, u2): x is the
    velocity v without its radial part (vz = v . z) normalised (hn its length). The time rate
    (:func:`_orbital_frame_rate_into`) and the state derivatives
    (:func:`solver.kernels.platform._oa_state_gradients`) are this along different directions."""
    dvz = u0 * z0 + u1 * z1 + u2 * z2 + v0 * dz0 + v1 * dz1 + v2 * dz2
    dh0, dh1, dh2 = u0 - dvz * z0 - vz * dz0, u1 - dvz * z1 - vz * dz1, u2 - dvz * z2 - vz * dz2
    xd = x0 * dh0 + x1 * dh1 + x2 * dh2
    dx0, dx1, dx2 = (dh0 - xd * x0) / hn, (dh1 - xd * x1) / hn, (dh2 - xd * x2) / hn
    dy0 = dz1 * x2 - dz2 * x1 + z1 * dx2 - z2 * dx1
    dy1 = dz2 * x0 - dz0 * x2 + z2 * dx0 - z0 * dx2
    dy2 = dz0 * x1 - dz1 * x0 + z0 * dx1 - z1 * dx0
    return dx0, dx1, dx2, dy0, dy1, dy2


@njit(**_JIT)
def _orbital_frame_rate(s, v, c, sdot, vdot):
    """:func:`_orbital_frame_rate_into` returning (R, dR/dt)."""
    r = np.empty((3, 3))
    dr = np.empty((3, 3))
    _orbital_frame_rate_into(s, v, c[0], c[1], c[2], sdot, vdot, r, dr)
    return r, dr


@njit(**_LEAF)
def ro_offset_scalars(kc):
    """R_ecef->lgs @ LGS origin, as three floats: added to an LGS position it gives the
    geocentric position in LGS axes (the orbital frame's radial direction)."""
    c0 = kc[0] * kc[9] + kc[1] * kc[10] + kc[2] * kc[11]
    c1 = kc[3] * kc[9] + kc[4] * kc[10] + kc[5] * kc[11]
    c2 = kc[6] * kc[9] + kc[7] * kc[10] + kc[8] * kc[11]
    return c0, c1, c2
