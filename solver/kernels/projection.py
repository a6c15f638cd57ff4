"""Projection (numba): ground point -> (line, column) of a pushbroom image by Newton's method on
the line, with or without interior orientation, its inverse (the ray of a pixel) and the
intersection of rays. :func:`project_observation` is the one entry point the observation blocks
call; it dispatches the camera-less RPC kind to :mod:`solver.kernels.rpc`."""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.extending import intrinsic

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @njit)
from solver.kernels.layout import JIT as _JIT
from solver.kernels.layout import KIND_KEPLER, KIND_POLYNOMIAL, KIND_RPC, N_COEF, N_IOP
from solver.kernels.platform import (
    _camera_state,
    _coef_gradients_into,
    _derivative_factors,
    _image_camera_vector,
    _projection_terms,
    _projection_work,
    object_to_camera,
    platform_state,
)
from solver.kernels.rpc import rpc_project, rpc_ray


@intrinsic
def runtime_flag(typingctx, flag):
    """``flag`` typed as a plain bool, not as the literal ``True``/``False`` a constant is typed
    as: a kernel called with a literal flag is compiled once per literal (its whole call tree
    twice over, a quarter of a cold compile), with a runtime flag once for both."""
    sig = types.boolean(flag)

    def codegen(context, builder, signature, args):
        return context.cast(builder, args[0], signature.args[0], types.boolean)

    return sig, codegen


@njit(**_JIT)
def _line_newton_step(d0: float, d2: float, t0: float, t2: float, f: float, xo: float, tpl: float) -> float:
    """Newton step (lines) on the along-track condition ``-f d_x/d_z = xo`` (camera vector d,
    its tau-rate t); NaN if singular."""
    g = -f * d0 / d2 - xo
    dg_dl = -f * (t0 * d2 - d0 * t2) / (d2 * d2) * tpl
    if dg_dl == 0.0 or not np.isfinite(dg_dl):
        return np.nan
    return g / dg_dl


# Newton on the line stops once its step is below LINE_STEP_TOL (line), or once the error
# left by stopping after the current step, estimated to second order, is below STOP_ERROR_TOL
# (line and pixel): far below the rounding of the camera vector (~1e-10 line at 700 km). The
# estimate is trusted only where the iteration is plainly converging: a step below
# STOP_STEP_MAX (line) and below a tenth of the step before it.
LINE_STEP_TOL = 1e-8
STOP_ERROR_TOL = 1e-11
STOP_STEP_MAX = 1e-2


@njit(**_JIT)
def _quotient_rates(da: float, dz: float, ta: float, tz: float, pa: float, pz: float, prev_dtau: float):
    """First and (estimated) second tau-derivatives of -d_a/d_z (a: along or across track) from
    the camera vector's components (da, dz), their tau-rates (ta, tz) and the rates before the
    previous step of ``prev_dtau`` (pa, pz), from which d'' is estimated."""
    iz = 1.0 / dz
    q = ta * dz - da * tz  # (d_a' d_z - d_a d_z')
    d2a = (ta - pa) / prev_dtau
    d2z = (tz - pz) / prev_dtau
    return -q * iz * iz, -((d2a * dz - da * d2z) * iz * iz - 2.0 * tz * q * iz * iz * iz)


@njit(**_JIT)
def _stop_error(d0, d1, d2, t0, t1, t2, p0, p1, p2, prev_dtau: float, dtau: float, f: float, tpl: float, px: float) -> float:
    """Error (line, pixel: the larger) of stopping after a Newton step of ``dtau`` (scaled time)
    with the camera vector d moved to the new line to first order (d + t dtau, t its tau-rate)
    instead of evaluated there; d'' is estimated from (p0, p1, p2), dd/dtau before the previous
    step (``prev_dtau``). The along-track function x = -f d_x/d_z is left 0.5 x'' dtau^2 from
    its target (its Newton model is linear), which the slope x' turns into a line error; the
    column's y = -f d_y/d_z is off by that line error times y' and by 0.5 y'' dtau^2."""
    slope_x, second_x = _quotient_rates(d0, d2, t0, t2, p0, p2, prev_dtau)
    slope_y, second_y = _quotient_rates(d1, d2, t1, t2, p1, p2, prev_dtau)
    if slope_x == 0.0:
        return np.inf
    line_err = 0.5 * abs(second_x) * dtau * dtau / abs(slope_x)  # scaled time (f cancels)
    col_err = f * (abs(slope_y) * line_err + 0.5 * abs(second_y) * dtau * dtau) / px
    return max(line_err / tpl, col_err)


@njit(**_JIT)
def project(kind, coef, kc, p, oc, want_jac: bool):
    """Exact pushbroom projection of ground point ``p`` (LGS, m) with its observation constants.

    Solves ``-f d_x(tau(L))/d_z = xo`` for the line L by Newton's method starting at the
    observed line, then evaluates the column. Returns (ok, line, column, dL_dcoef[24],
    dL_dp[3], dC_dcoef[24], dC_dp[3]); derivatives by the implicit function theorem (for
    KIND_PASS the pass-state derivatives are in the coefficient slots PASS_COEF_INDEX).

    The Newton loop holds the camera vector d and its tau-rate in scalars. The per-image kinds
    compute them without work arrays (:func:`_image_camera_vector`) and form the Jacobians'
    factors once, at the end, with :func:`_camera_state`; the orbit-attitude kinds fill their
    factors at every step (their derivatives need the last step's frames).
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
    col = 0.0
    ok = False
    per_image = kind == KIND_POLYNOMIAL or kind == KIND_KEPLER
    rot, mats, vecs, b, da_dr = _projection_work()
    mm, a_att, mnt, ro, dro = mats[0], mats[1], mats[2], mats[3], mats[4]
    s, sdot, v, d, ddt, acc = vecs[0], vecs[1], vecs[2], vecs[3], vecs[4], vecs[5]
    _projection_terms(kind, coef, kc, acc, da_dr, mnt)
    d0 = d1 = d2 = t0 = t1 = t2 = 0.0
    p0 = p1 = p2 = 0.0  # dd/dtau before the previous step
    prev_step = 0.0
    tau = line * tpl
    jac_tau = tau  # where the derivatives are taken: the last line evaluated, or the solution
    for it in range(31):
        tau = line * tpl
        jac_tau = tau
        # a per-image step reads the coefficients only, no work array touched (written out here and
        # in project_cam: a helper taking the work arrays, even a leaf, cost 13 % of a projection)
        if per_image:
            d0, d1, d2, t0, t1, t2 = _image_camera_vector(kind, coef, kc, acc, tau, p)
        else:
            _camera_state(kind, coef, kc, acc, tau, p, rot, s, sdot, v, d, ddt, mm, mnt, ro, dro, vecs[6:], b)
            d0, d1, d2, t0, t1, t2 = d[0], d[1], d[2], ddt[0], ddt[1], ddt[2]
        if it == 30:
            break
        step = _line_newton_step(d0, d2, t0, t2, f, xo, tpl)
        if not np.isfinite(step):
            break
        line -= step
        dtau = -step * tpl
        done = abs(step) < LINE_STEP_TOL
        if not done and it > 0 and abs(step) < STOP_STEP_MAX and abs(step) < 0.1 * abs(prev_step):
            done = _stop_error(d0, d1, d2, t0, t1, t2, p0, p1, p2, -prev_step * tpl, dtau, f, tpl, px) < STOP_ERROR_TOL
        if done:
            ok = True
            # the column from the camera vector moved to the new line to first order (its error
            # is in _stop_error): the same residuals whether or not derivatives are wanted
            col = cc + (-f * (d1 + t1 * dtau) / (d2 + t2 * dtau) - yo) / px
            if abs(step) >= LINE_STEP_TOL:
                # the derivatives at the solution itself: over a step they move by more than the
                # rounding (~1e-5 relative at 0.01 line), enough to change Ceres' path
                jac_tau = line * tpl
            break
        p0, p1, p2 = t0, t1, t2
        prev_step = step
    if not ok:
        col = cc + (-f * d1 / d2 - yo) / px
    grads = np.zeros(2 * N_COEF + 6)  # one allocation for the four derivative vectors
    dl_dc, dc_dc = grads[0:N_COEF], grads[N_COEF : 2 * N_COEF]
    dl_dp, dc_dp = grads[2 * N_COEF : 2 * N_COEF + 3], grads[2 * N_COEF + 3 : 2 * N_COEF + 6]
    if not want_jac:
        return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp
    if per_image or jac_tau != tau:
        tau = jac_tau
        _camera_state(kind, coef, kc, acc, tau, p, rot, s, sdot, v, d, ddt, mm, mnt, ro, dro, vecs[6:], b)
    _derivative_factors(kind, rot, mnt, ro, a_att, mm)
    # the derivatives at the last line evaluated (tau): the solution, or within LINE_STEP_TOL of it
    iz = 1.0 / d[2]
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
    # the coefficients' gradients of x and y into dl_dc and dc_dc, then turned into those of L and C
    _coef_gradients_into(kind, kc, da_dr, tau, s, sdot, v, mm, rot, a_att, mnt, ro, gx0, gx2, gy1, gy2, dl_dc, dc_dc, b, vecs[6:8])
    for idx in range(N_COEF):
        dl_dc[idx] = -dl_dc[idx] / dx_dl
        dc_dc[idx] = (dc_dc[idx] + dy_dl * dl_dc[idx]) / px
    return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp


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
    rot, mats, vecs, b, da_dr = _projection_work()
    mm, a_att, mnt, ro, dro = mats[0], mats[1], mats[2], mats[3], mats[4]
    s, sdot, v, d, ddt, acc = vecs[0], vecs[1], vecs[2], vecs[3], vecs[4], vecs[5]
    _projection_terms(kind, coef, kc, acc, da_dr, mnt)
    xi = yi = big_f = dxi_dc = dyi_dc = 0.0
    dxi_diop = np.zeros(N_IOP)
    dyi_diop = np.zeros(N_IOP)
    j11 = j12 = j21 = j22 = 0.0
    per_image = kind == KIND_POLYNOMIAL or kind == KIND_KEPLER
    tau = line * tpl
    for it in range(31):
        tau = line * tpl
        if per_image:  # as in project: scalars here, the Jacobians' factors at the end
            d0, d1, d2, t0, t1, t2 = _image_camera_vector(kind, coef, kc, acc, tau, p)
        else:
            _camera_state(kind, coef, kc, acc, tau, p, rot, s, sdot, v, d, ddt, mm, mnt, ro, dro, vecs[6:], b)
            d0, d1, d2, t0, t1, t2 = d[0], d[1], d[2], ddt[0], ddt[1], ddt[2]
        xi, yi, big_f, dxi_dc, dyi_dc, dxi_diop, dyi_diop = camera_model(oc, iop, chip, chip_len, col, it == 30 or ok)
        if it == 30 or ok:
            break
        g1 = xi + big_f * d0 / d2
        g2 = yi + big_f * d1 / d2
        j11 = big_f * (t0 * d2 - d0 * t2) / (d2 * d2) * tpl
        j21 = big_f * (t1 * d2 - d1 * t2) / (d2 * d2) * tpl
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
    if per_image:  # the factors at the last state evaluated (the orbit-attitude kinds have them)
        _camera_state(kind, coef, kc, acc, tau, p, rot, s, sdot, v, d, ddt, mm, mnt, ro, dro, vecs[6:], b)
    _derivative_factors(kind, rot, mnt, ro, a_att, mm)
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
    # the coefficients' gradients of g into dl_dc and dc_dc, then solved in place
    _coef_gradients_into(kind, kc, da_dr, tau, s, sdot, v, mm, rot, a_att, mnt, ro, hx0, hx2, hy1, hy2, dl_dc, dc_dc, b, vecs[6:8])
    for idx in range(N_COEF):
        dl_dc[idx], dc_dc[idx] = _solve(dl_dc[idx], dc_dc[idx])
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
    xi, yi, big_f, _a, _b, _c, _d = camera_model(oc, iop, chip, chip_len, oc[1], runtime_flag(False))
    out = np.empty(3)
    out[0] = xi
    out[1] = yi
    out[2] = -big_f
    return out


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
def ray_cam(kind, coef, kc, oc, iop, chip: int, chip_len: float):
    """Perspective centre S and unit viewing direction (LGS) of an observed pixel, with IOP."""
    tau = oc[0] * oc[8]
    s, ds_dc, ds_dt, ang, da_dc, da_dt = platform_state(kind, coef, kc, tau)
    m = object_to_camera(kind, coef, kc, tau)
    dvec = m.T @ ideal_direction(oc, iop, chip, chip_len)
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
        if n >= 2:
            x = np.empty(3)
            if abs(_solve3(a, b, x)) > 1e-18:
                for i in range(3):
                    out[w, i] = x[i]
    return out


@njit(**_JIT)
def _solve3(a, b, x) -> float:
    """Solve the 3 x 3 system ``a x = b`` into ``x`` by LU with partial pivoting, as LAPACK's
    dgesv does (rows scaled by the pivot's reciprocal, the same substitutions); returns the
    determinant of ``a`` (``x`` is not finite when it is 0). ``a`` and ``b`` are left unchanged.

    Written out rather than ``np.linalg.solve`` and ``np.linalg.det``: those compile numba's
    LAPACK bindings and their checks into the kernel, a third of :func:`intersect_all`'s
    compilation, for a 3 x 3 system."""
    lu = a.copy()
    y = b.copy()
    det = 1.0
    for k in range(3):
        piv = k
        for i in range(k + 1, 3):
            if abs(lu[i, k]) > abs(lu[piv, k]):
                piv = i
        if piv != k:
            det = -det
            for j in range(3):
                lu[k, j], lu[piv, j] = lu[piv, j], lu[k, j]
            y[k], y[piv] = y[piv], y[k]
        det *= lu[k, k]
        if lu[k, k] == 0.0:
            continue
        r = 1.0 / lu[k, k]
        for i in range(k + 1, 3):
            lu[i, k] *= r
            for j in range(k + 1, 3):
                lu[i, j] -= lu[i, k] * lu[k, j]
    for k in range(3):  # L y = P b (unit lower)
        for i in range(k + 1, 3):
            y[i] -= y[k] * lu[i, k]
    for k in range(2, -1, -1):  # U x = y
        y[k] /= lu[k, k]
        for i in range(k):
            y[i] -= y[k] * lu[i, k]
    for i in range(3):
        x[i] = y[i]
    return det


@njit(**_JIT)
def project_observation(kind, coef, kc, p, oc, iop, chip: int, chip_len: float, want_jac: bool):
    """The projection entry point of the observation blocks: with interior orientation when
    ``iop`` (the camera's full IOP vector) is given, without when it is empty or the kind has no
    camera (RPC). Returns (ok, L, C, dL_dcoef[24], dL_dp[3], dC_dcoef[24], dC_dp[3], dL_diop,
    dC_diop); the IOP derivatives are empty without interior orientation."""
    if iop.shape[0] > 0 and kind != KIND_RPC:
        return project_cam(kind, coef, kc, p, oc, iop, chip, chip_len, want_jac)
    ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp = project(kind, coef, kc, p, oc, want_jac)
    empty = dl_dc[:0]  # no IOP derivatives (a view, not an allocation)
    return ok, line, col, dl_dc, dl_dp, dc_dc, dc_dp, empty, empty
