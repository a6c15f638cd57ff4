"""RPC00B ground-to-image with an image-space bias (numba), for images whose sensor model is an RPC.

The point is carried in the LGS (metres) like every ground point of the adjustment; the kernel
converts it to WGS 84 geodetic coordinates, evaluates the rational functions and adds the bias
of Grodecki & Dial (2003) evaluated at the **observed** image coordinates (our pixel convention:
the top-left pixel's centre is (0, 0))::

    line   = RPC_line(lat, lon, h)   + a0 + a_line * line_obs + a_column * column_obs
    column = RPC_column(lat, lon, h) + b0 + b_line * line_obs + b_column * column_obs

Layout (written by :mod:`solver.engine.assemble`):

* ``coef`` (24): the bias a0, a_line, a_column, b0, b_line, b_column in slots 0..5 (pixels and
  pixels per pixel), the rest unused;
* ``kc``: R_ecef->lgs (9, row-major), LGS origin in ECEF (3), ellipsoid a (m), e^2, 3 unused,
  then from :data:`RPC_START` the RPC: line_off, samp_off, lat_off, long_off, height_off,
  line_scale, samp_scale, lat_scale, long_scale, height_scale (degrees, metres, pixels) and the
  20 coefficients of line_num, line_den, samp_num, samp_den (RPC00B term order).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @njit)

RPC_START = 17  # first RPC value in kc (after the frame constants shared with the Kepler layout)
RPC_LEN = 10 + 80
KC_A = 12  # kc slot of the ellipsoid's semi-major axis (m)
KC_E2 = 13  # kc slot of the ellipsoid's first eccentricity squared
N_BIAS = 6
_JIT = dict(cache=True, nogil=True, error_model="numpy", fastmath=False)
_DEG = 180.0 / math.pi


@njit(**_JIT)
def terms_and_gradient(x: float, y: float, z: float):
    """The 20 RPC00B terms of normalised (longitude x, latitude y, height z) and their
    derivatives wrt x, y, z: (t[20], tx[20], ty[20], tz[20])."""
    t = np.array([
        1.0, x, y, z, x * y, x * z, y * z, x * x, y * y, z * z, x * y * z, x ** 3, x * y * y, x * z * z,
        x * x * y, y ** 3, y * z * z, x * x * z, y * y * z, z ** 3,
    ])
    tx = np.array([
        0.0, 1.0, 0.0, 0.0, y, z, 0.0, 2 * x, 0.0, 0.0, y * z, 3 * x * x, y * y, z * z,
        2 * x * y, 0.0, 0.0, 2 * x * z, 0.0, 0.0,
    ])
    ty = np.array([
        0.0, 0.0, 1.0, 0.0, x, 0.0, z, 0.0, 2 * y, 0.0, x * z, 0.0, 2 * x * y, 0.0,
        x * x, 3 * y * y, z * z, 0.0, 2 * y * z, 0.0,
    ])
    tz = np.array([
        0.0, 0.0, 0.0, 1.0, 0.0, x, y, 0.0, 0.0, 2 * z, x * y, 0.0, 0.0, 2 * x * z,
        0.0, 0.0, 2 * y * z, x * x, y * y, 3 * z * z,
    ])
    return t, tx, ty, tz


@njit(**_JIT)
def _ratio(num, den, t, tx, ty, tz):
    """r = num.t / den.t and its gradient wrt (x, y, z)."""
    # sums written out: ``@`` on arrays compiles numba's BLAS dot (and its shape checks) into
    # every kernel above this one, a tenth of a cold compile, for 20-term products
    n = d = nx = dx = ny = dy = nz = dz = 0.0
    for k in range(t.shape[0]):
        n += num[k] * t[k]
        d += den[k] * t[k]
        nx += num[k] * tx[k]
        dx += den[k] * tx[k]
        ny += num[k] * ty[k]
        dy += den[k] * ty[k]
        nz += num[k] * tz[k]
        dz += den[k] * tz[k]
    r = n / d
    g = np.empty(3)
    g[0] = (nx - r * dx) / d
    g[1] = (ny - r * dy) / d
    g[2] = (nz - r * dz) / d
    return r, g


@njit(**_JIT)
def rpc_normalised(kc, x: float, y: float, z: float):
    """RPC (line, sample) in pixels of normalised ground coordinates and their gradients wrt
    (x, y, z): (line, sample, dline[3], dsample[3])."""
    r = kc[RPC_START:]
    t, tx, ty, tz = terms_and_gradient(x, y, z)
    ln, gl = _ratio(r[10:30], r[30:50], t, tx, ty, tz)
    sn, gs = _ratio(r[50:70], r[70:90], t, tx, ty, tz)
    return ln * r[5] + r[0], sn * r[6] + r[1], gl * r[5], gs * r[6]


@njit(**_JIT)
def lgs_to_geodetic(kc, p):
    """LGS point (m) to (lon_rad, lat_rad, h_m) on the ellipsoid of kc, and the Jacobian
    d(lon, lat, h)/d(p) (3, 3)."""
    rot = kc[0:9].reshape(3, 3)
    a = kc[KC_A]
    e2 = kc[KC_E2]
    ecef = np.empty(3)  # kc[9:12] + R^T p, written out (see _ratio)
    for i in range(3):
        ecef[i] = kc[9 + i] + (rot[0, i] * p[0] + rot[1, i] * p[1] + rot[2, i] * p[2])
    lon = math.atan2(ecef[1], ecef[0])
    rho = math.hypot(ecef[0], ecef[1])
    lat = math.atan2(ecef[2], rho * (1.0 - e2))
    h = 0.0
    for _ in range(8):
        s = math.sin(lat)
        nn = a / math.sqrt(1.0 - e2 * s * s)
        h = rho / math.cos(lat) - nn
        lat = math.atan2(ecef[2], rho * (1.0 - e2 * nn / (nn + h)))
    sl, cl = math.sin(lat), math.cos(lat)
    so, co = math.sin(lon), math.cos(lon)
    w = math.sqrt(1.0 - e2 * sl * sl)
    nn = a / w
    mm = a * (1.0 - e2) / (w * w * w)
    h = rho / cl - nn
    # the columns of d(ecef)/d(lon, lat, h) are orthogonal: east (N+h)cos(lat), north (M+h), up
    east = np.array([-so, co, 0.0]) / ((nn + h) * cl)
    north = np.array([-sl * co, -sl * so, cl]) / (mm + h)
    up = np.array([cl * co, cl * so, sl])
    jac = np.empty((3, 3))  # rows: d lon / d p = (R east)^T, then R north, R up (written out)
    for i in range(3):
        jac[0, i] = rot[i, 0] * east[0] + rot[i, 1] * east[1] + rot[i, 2] * east[2]
        jac[1, i] = rot[i, 0] * north[0] + rot[i, 1] * north[1] + rot[i, 2] * north[2]
        jac[2, i] = rot[i, 0] * up[0] + rot[i, 1] * up[1] + rot[i, 2] * up[2]
    return lon, lat, h, jac


@njit(**_JIT)
def geodetic_to_lgs(kc, lon: float, lat: float, h: float):
    """(lon_rad, lat_rad, h_m) to the LGS (m)."""
    a = kc[KC_A]
    e2 = kc[KC_E2]
    sl = math.sin(lat)
    nn = a / math.sqrt(1.0 - e2 * sl * sl)
    ecef = np.array([
        (nn + h) * math.cos(lat) * math.cos(lon), (nn + h) * math.cos(lat) * math.sin(lon), (nn * (1.0 - e2) + h) * sl
    ])
    return kc[0:9].reshape(3, 3) @ (ecef - kc[9:12])


@njit(**_JIT)
def rpc_project(coef, kc, p, oc, want_jac: bool):
    """Ground-to-image of LGS point ``p`` through the RPC plus bias (module docstring), at the
    observed (line, column) = oc[0], oc[1]. Returns (ok, line, column, dL_dcoef[24], dL_dp[3],
    dC_dcoef[24], dC_dp[3]) like :func:`solver.kernels.project`."""
    r = kc[RPC_START:]
    lon, lat, h, jg = lgs_to_geodetic(kc, p)
    x = (lon * _DEG - r[3]) / r[8]
    y = (lat * _DEG - r[2]) / r[7]
    z = (h - r[4]) / r[9]
    rl, rs, gl, gs = rpc_normalised(kc, x, y, z)
    lo = oc[0]
    co = oc[1]
    line = rl + coef[0] + coef[1] * lo + coef[2] * co
    col = rs + coef[3] + coef[4] * lo + coef[5] * co
    dl_dc = np.zeros(24)
    dc_dc = np.zeros(24)
    dl_dp = np.zeros(3)
    dc_dp = np.zeros(3)
    if want_jac:
        dl_dc[0] = 1.0
        dl_dc[1] = lo
        dl_dc[2] = co
        dc_dc[3] = 1.0
        dc_dc[4] = lo
        dc_dc[5] = co
        # d(x, y, z)/d(lon, lat, h) is diagonal
        sx = _DEG / r[8]
        sy = _DEG / r[7]
        sz = 1.0 / r[9]
        for j in range(3):
            dl_dp[j] = gl[0] * sx * jg[0, j] + gl[1] * sy * jg[1, j] + gl[2] * sz * jg[2, j]
            dc_dp[j] = gs[0] * sx * jg[0, j] + gs[1] * sy * jg[1, j] + gs[2] * sz * jg[2, j]
    ok = np.isfinite(line) and np.isfinite(col)
    return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp


@njit(**_JIT)
def rpc_image_to_ground(coef, kc, line_obs: float, col_obs: float, h: float):
    """LGS point at ellipsoidal height ``h`` (m) seen at the observed (line, column): the RPC
    inverted by Newton's method in normalised (x, y). Returns (ok, p[3])."""
    r = kc[RPC_START:]
    tl = line_obs - (coef[0] + coef[1] * line_obs + coef[2] * col_obs)
    ts = col_obs - (coef[3] + coef[4] * line_obs + coef[5] * col_obs)
    z = (h - r[4]) / r[9]
    x = 0.0
    y = 0.0
    ok = False
    for _ in range(30):
        rl, rs, gl, gs = rpc_normalised(kc, x, y, z)
        f1 = rl - tl
        f2 = rs - ts
        det = gl[0] * gs[1] - gl[1] * gs[0]
        if det == 0.0 or not np.isfinite(det):
            break
        dx = (gs[1] * f1 - gl[1] * f2) / det
        dy = (-gs[0] * f1 + gl[0] * f2) / det
        x -= dx
        y -= dy
        if abs(dx) < 1e-13 and abs(dy) < 1e-13:
            ok = True
            break
    lon = (x * r[8] + r[3]) / _DEG
    lat = (y * r[7] + r[2]) / _DEG
    return ok, geodetic_to_lgs(kc, lon, lat, h)


@njit(**_JIT)
def rpc_ray(coef, kc, oc):
    """A point (LGS) and the unit direction of the line of sight of an observed pixel: the
    ground points at the top and bottom of the RPC's height range (``height_off +- height_scale/2``)."""
    r = kc[RPC_START:]
    ok1, top = rpc_image_to_ground(coef, kc, oc[0], oc[1], r[4] + 0.5 * r[9])
    ok2, bottom = rpc_image_to_ground(coef, kc, oc[0], oc[1], r[4] - 0.5 * r[9])
    d = bottom - top
    d /= np.sqrt(d @ d)
    return top, d
