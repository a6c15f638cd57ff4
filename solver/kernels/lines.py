"""Straight-line kernels (numba): the equivalent planes model, the exact pushbroom image of an
object line, and the signed distances of measured points from it (docs/models.md, straight
lines; :mod:`solver.observations.lines` holds the family that uses them: its docstring states
the models, frames and units).

Frames and units as in :mod:`solver.kernels`: object points in the LGS (m), focal-plane
coordinates in mm, image coordinates in pixels (x = line, y = column); ``form`` is
:data:`~solver.kernels.layout.FORM_Y` (y = a x + b) or :data:`~solver.kernels.layout.FORM_X`
(x = a' y + b').
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @njit)
from solver.kernels.layout import FORM_Y
from solver.kernels.layout import JIT as _JIT
from solver.kernels.platform import platform_state
from solver.kernels.projection import project, runtime_flag
from solver.kernels.rotation import rotation_and_derivatives


@njit(**_JIT)
def _cross(a, b):
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@njit(**_JIT)
def two_point_line(form: int, x1: float, y1: float, x2: float, y2: float):
    """(a, b) of the line through (x1, y1), (x2, y2) and d(a, b)/d(x1, y1, x2, y2) (seed 002 eqs 5-6)."""
    j = np.zeros((2, 4))
    if form == FORM_Y:
        dx = x2 - x1
        a = (y2 - y1) / dx
        b = y1 - a * x1
        j[0, 0] = a / dx
        j[0, 1] = -1.0 / dx
        j[0, 2] = -a / dx
        j[0, 3] = 1.0 / dx
        j[1, 0] = -a - x1 * j[0, 0]
        j[1, 1] = 1.0 - x1 * j[0, 1]
        j[1, 2] = -x1 * j[0, 2]
        j[1, 3] = -x1 * j[0, 3]
    else:
        dy = y2 - y1
        a = (x2 - x1) / dy
        b = x1 - a * y1
        j[0, 0] = -1.0 / dy
        j[0, 1] = a / dy
        j[0, 2] = 1.0 / dy
        j[0, 3] = -a / dy
        j[1, 0] = 1.0 - y1 * j[0, 0]
        j[1, 1] = -a - y1 * j[0, 1]
        j[1, 2] = -y1 * j[0, 2]
        j[1, 3] = -y1 * j[0, 3]
    return a, b, j


@njit(**_JIT)
def planes_model(kind, coef, kc, p1, p2, tau: float, f: float, form: int, want_jac: bool):
    """Equivalent planes model (seed 002 eqs 1-4) at scaled time ``tau``.

    ``p1``, ``p2`` LGS (m), ``f`` focal length (mm). Returns (ab[2], d ab/d coef [2, 24],
    d ab/d (P1, P2) [2, 6]); ab = (a, b) of form 0 (y = a x + b) or 1 (x = a' y + b'), b in mm.
    """
    s, ds_dc, _ds_dt, ang, da_dc, _da_dt = platform_state(kind, coef, kc, tau)
    m, dmo, dmp, dmk = rotation_and_derivatives(ang[0], ang[1], ang[2])
    u = p2 - p1
    w = p1 - s
    nv = _cross(u, w)
    n = m @ nv
    num = 0 if form == FORM_Y else 1
    den = 1 - num
    d = n[den]
    ab = np.empty(2)
    ab[0] = -n[num] / d
    ab[1] = f * n[2] / d
    jc = np.zeros((2, 24))
    jp = np.zeros((2, 6))
    if not want_jac:
        return ab, jc, jp
    g0 = dmo @ nv
    g1 = dmp @ nv
    g2 = dmk @ nv
    dn = np.zeros((3, 24))
    col = np.empty(3)
    for j in range(24):
        nonzero = False
        for i in range(3):
            col[i] = ds_dc[i, j]
            if col[i] != 0.0:
                nonzero = True
        for i in range(3):
            dn[i, j] = g0[i] * da_dc[0, j] + g1[i] * da_dc[1, j] + g2[i] * da_dc[2, j]
        if nonzero:
            mc = m @ _cross(u, col)  # dN/dS = -[u]x
            for i in range(3):
                dn[i, j] -= mc[i]
    dnp = np.zeros((3, 6))
    q = p2 - s
    e = np.zeros(3)
    for k in range(3):
        e[:] = 0.0
        e[k] = 1.0
        c1 = m @ _cross(q, e)  # dN/dP1 e = (P2 - S) x e
        c2 = m @ _cross(e, w)  # dN/dP2 e = e x (P1 - S)
        for i in range(3):
            dnp[i, k] = c1[i]
            dnp[i, 3 + k] = c2[i]
    d2 = d * d
    for j in range(24):
        jc[0, j] = -(dn[num, j] * d - n[num] * dn[den, j]) / d2
        jc[1, j] = f * (dn[2, j] * d - n[2] * dn[den, j]) / d2
    for j in range(6):
        jp[0, j] = -(dnp[num, j] * d - n[num] * dnp[den, j]) / d2
        jp[1, j] = f * (dnp[2, j] * d - n[2] * dnp[den, j]) / d2
    return ab, jc, jp


@njit(**_JIT)
def pushbroom_line(kind, coef, kc, p1, p2, oc1, oc2, mp1, mp2, form: int, want_jac: bool):
    """(a, b) of the line through the exact pushbroom projections of P1 and P2.

    ``oc1``/``oc2`` observation constants of the projections (chip, start line), ``mp`` the
    coordinate map of each point: x = mp[0] + (L - mp[1]) mp[2], y = mp[3] + (C - mp[4]) mp[5]
    (pixels: (0, 0, 1, 0, 0, 1); pseudo-frame: (xo, L_r, k, yo, c_chip, pixel)).
    Returns (ok, ab[2], d ab/d coef [2, 24], d ab/d (P1, P2) [2, 6]).
    """
    ok1, l1, c1, dl1_dc, dl1_dp, dc1_dc, dc1_dp = project(kind, coef, kc, p1, oc1, want_jac)
    ok2, l2, c2, dl2_dc, dl2_dp, dc2_dc, dc2_dp = project(kind, coef, kc, p2, oc2, want_jac)
    x1 = mp1[0] + (l1 - mp1[1]) * mp1[2]
    y1 = mp1[3] + (c1 - mp1[4]) * mp1[5]
    x2 = mp2[0] + (l2 - mp2[1]) * mp2[2]
    y2 = mp2[3] + (c2 - mp2[4]) * mp2[5]
    a, b, j = two_point_line(form, x1, y1, x2, y2)
    ab = np.empty(2)
    ab[0] = a
    ab[1] = b
    jc = np.zeros((2, 24))
    jp = np.zeros((2, 6))
    if want_jac:
        for r in range(2):
            for k in range(24):
                jc[r, k] = (
                    j[r, 0] * mp1[2] * dl1_dc[k]
                    + j[r, 1] * mp1[5] * dc1_dc[k]
                    + j[r, 2] * mp2[2] * dl2_dc[k]
                    + j[r, 3] * mp2[5] * dc2_dc[k]
                )
            for k in range(3):
                jp[r, k] = j[r, 0] * mp1[2] * dl1_dp[k] + j[r, 1] * mp1[5] * dc1_dp[k]
                jp[r, 3 + k] = j[r, 2] * mp2[2] * dl2_dp[k] + j[r, 3] * mp2[5] * dc2_dp[k]
    return ok1 and ok2, ab, jc, jp


@njit(**_JIT)
def _closest_point(kind, coef, kc, p1, u, oc0, ml, mc, si):
    """Newton search of the object-line parameter s whose image is closest to the measured
    point (ml, mc), from ``si``. Returns (found, s, line, column, tangent line, tangent column,
    dL_dcoef, dL_dp, dC_dcoef, dC_dp) at the last projection."""
    oc = oc0.copy()
    q = np.empty(3)
    converged = False
    good = False
    ln = cl = tl = tc = 0.0
    dl_dc = np.zeros(24)
    dc_dc = np.zeros(24)
    dl_dp = np.zeros(3)
    dc_dp = np.zeros(3)
    for it in range(12):
        for k in range(3):
            q[k] = p1[k] + si * u[k]
        good, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp = project(kind, coef, kc, q, oc, runtime_flag(True))
        tl = dl_dp[0] * u[0] + dl_dp[1] * u[1] + dl_dp[2] * u[2]
        tc = dc_dp[0] * u[0] + dc_dp[1] * u[1] + dc_dp[2] * u[2]
        t2 = tl * tl + tc * tc
        ds = ((ml - ln) * tl + (mc - cl) * tc) / t2
        if not np.isfinite(ds):
            break
        oc[0] = ln
        if abs(ds) * math.sqrt(t2) < 1e-9:
            converged = True
            break
        si += ds
    return good and converged, si, ln, cl, tl, tc, dl_dc, dl_dp, dc_dc, dc_dp


@njit(**_JIT)
def line_distances(kind, coef, kc, p1, p2, ocs, s, want_jac: bool):
    """Signed image distances (px) of measured points from the exact pushbroom image of a line.

    ``ocs`` (n, 9): observation constants of each measured point (oc[0] = measured line,
    oc[1] = measured column, chip constants of that point). ``s`` (n,) holds the parameters of
    the closest object-line points Q(s) = P1 + s (P2 - P1). Each search starts from the
    measured point projected on the chord of the endpoints' images at ``coef`` (as
    :func:`start` does), so an evaluation does not depend on earlier ones; ``s`` is the
    fallback start and is updated where a search converged. Returns (ok, d[n],
    d d/d coef [n, 24], d d/d (P1, P2) [n, 6]) with d = n . (m - q(s*)), n the unit normal
    (-dC/ds, dL/ds)/|q'| of the projected line.
    """
    n = ocs.shape[0]
    u = p2 - p1
    dist = np.full(n, np.nan)
    jc = np.zeros((n, 24))
    jp = np.zeros((n, 6))
    if n == 0 or s.shape[0] != n or ocs.shape[1] < 9 or p1.shape[0] != 3 or p2.shape[0] != 3:
        return False, dist, jc, jp
    g1, l1, c1, _a, _b, _c, _d = project(kind, coef, kc, p1, ocs[0].copy(), runtime_flag(False))
    g2, l2, c2, _a, _b, _c, _d = project(kind, coef, kc, p2, ocs[n - 1].copy(), runtime_flag(False))
    chord2 = (l2 - l1) ** 2 + (c2 - c1) ** 2
    chord = g1 and g2 and np.isfinite(chord2) and chord2 > 1e-12
    all_ok = True
    for i in range(n):
        ml = ocs[i, 0]
        mc = ocs[i, 1]
        start_s = s[i]
        if chord:
            start_s = ((ml - l1) * (l2 - l1) + (mc - c1) * (c2 - c1)) / chord2
        found, si, ln, cl, tl, tc, dl_dc, dl_dp, dc_dc, dc_dp = _closest_point(
            kind, coef, kc, p1, u, ocs[i], ml, mc, start_s
        )
        if not found and chord:
            found, si, ln, cl, tl, tc, dl_dc, dl_dp, dc_dc, dc_dp = _closest_point(
                kind, coef, kc, p1, u, ocs[i], ml, mc, s[i]
            )
        nrm = math.sqrt(tl * tl + tc * tc)
        nl = -tc / nrm
        nc = tl / nrm
        dist[i] = nl * (ml - ln) + nc * (mc - cl)
        if found:
            s[i] = si
        if want_jac:
            for k in range(24):
                jc[i, k] = -(nl * dl_dc[k] + nc * dc_dc[k])
            for k in range(3):
                g = -(nl * dl_dp[k] + nc * dc_dp[k])
                jp[i, k] = g * (1.0 - si)
                jp[i, 3 + k] = g * si
        all_ok = all_ok and found and np.isfinite(dist[i])
    return all_ok, dist, jc, jp


@njit(**_JIT)
def frame_xy(kind, coef, kc, tau: float, p, f: float):
    """Focal-plane coordinates (mm) of LGS point ``p`` for a frame camera at scaled time ``tau``."""
    s, _a, _b, ang, _c, _d = platform_state(kind, coef, kc, tau)
    m = rotation_and_derivatives(ang[0], ang[1], ang[2])[0]
    d = m @ (p - s)
    return -f * d[0] / d[2], -f * d[1] / d[2]
