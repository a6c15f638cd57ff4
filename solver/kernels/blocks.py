"""Observation blocks (numba): the whitened residuals and Jacobians of the image-point
observations over the packed image and camera tables (:mod:`solver.kernels.layout`), for the
Ceres cost functions (:mod:`solver.engine.backend`) and the covariance (:mod:`solver.engine.linalg`).
Every record goes through :func:`solver.kernels.projection.project_observation`."""

from __future__ import annotations

from typing import Callable

import numpy as np
from numba import njit

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @njit)
from solver.kernels.layout import (
    IT_BASE,
    IT_FREE,
    IT_KIND,
    IT_NFREE,
    KC_START,
    KIND_PASS,
    N_IOP,
    REC_CAM_SLOT,
    REC_CAMERA,
    REC_CHIP,
    REC_CHIP_LEN,
    REC_COLUMN,
    REC_IMAGE,
    REC_IMG_SLOT,
    REC_LINE,
    REC_OC,
    REC_PASS_SLOT,
    REC_SIGMA,
)
from solver.kernels.layout import JIT as _JIT
from solver.kernels.layout import LEAF as _LEAF
from solver.kernels.projection import project_observation, runtime_flag
from solver.kernels.propagation import PASS_COEF_INDEX, PASS_INDEX, ensure_segment


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
    if r[REC_PASS_SLOT] >= 0:  # a pass image with an estimated pass state
        ensure_segment(kc, params[int(r[REC_PASS_SLOT])])
    oc = r[REC_OC:REC_PASS_SLOT]
    iop = coef[:0]  # no interior orientation (or no camera): _fill skips the camera (slot -1); a view, not an allocation
    if cm >= 0 and cam_tab[cm, 1] != 0.0:
        ct = cam_tab[cm]
        iop = ct[2 + N_IOP : 2 + 2 * N_IOP].copy()
        if cslot >= 0:
            pc = params[cslot]
            for j in range(int(ct[0])):
                iop[int(ct[2 + j])] = pc[j]
    return project_observation(kind, coef, kc, p, oc, iop, int(r[REC_CHIP]), r[REC_CHIP_LEN], want)


@njit(**_LEAF)
def _put_rows(block, i, idx, dl, dc, w):
    """Rows 2i, 2i+1 of a residual block's dense Jacobian wrt one parameter block whose entries
    are dl[idx[j]], dc[idx[j]] (line and column derivatives), whitened and negated."""
    n = idx.shape[0]
    for j in range(n):
        q = int(idx[j])
        block[(2 * i) * n + j] = -dl[q] * w
        block[(2 * i + 1) * n + j] = -dc[q] * w


@njit(**_LEAF)
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


def serial(fill: Callable[[int, int], None], n: int) -> None:
    """Run ``fill(lo, hi)`` over the whole range ``[0, n)`` in this thread."""
    fill(0, n)


def all_observation_blocks(rec, img_tab, cam_tab, img_p, cam_p, pts, pt_idx, estimated, img_col, cam_col, pass_col, width,
                           run: Callable[[Callable[[int, int], None], int], None] = serial):
    """Whitened residuals and dense Jacobian pieces of every record (for the covariance).

    ``img_p`` (nimg, 24) and ``cam_p`` (ncam, N_IOP) hold the current free parameters; pass
    segments in ``img_tab`` must be current; slots in ``rec`` are ignored. Returns res (n, 2),
    jf (n, 2, width) with column indices fcol (n, width) (-1 padding) over the image, camera and
    pass parameters (``pass_col``: first column of each pass), jpt (n, 2, 3), ok (n).

    ``run(fill, n)`` runs ``fill(lo, hi)`` over ranges that cover ``[0, n)`` (:func:`serial`, or
    the caller's threads: the kernel releases the GIL and each record fills its own rows).
    """
    n = rec.shape[0]
    res = np.empty((n, 2))
    jf = np.zeros((n, 2, width))
    fcol = -np.ones((n, width), dtype=np.int64)
    jpt = np.zeros((n, 2, 3))
    ok = np.empty(n, dtype=np.bool_)

    def fill(lo: int, hi: int) -> None:
        observation_blocks_into(lo, hi, rec, img_tab, cam_tab, img_p, cam_p, pts, pt_idx, estimated, img_col, cam_col,
                                pass_col, res, jf, fcol, jpt, ok)

    run(fill, n)
    return res, jf, fcol, jpt, ok


@njit(**_JIT)
def observation_blocks_into(lo, hi, rec, img_tab, cam_tab, img_p, cam_p, pts, pt_idx, estimated, img_col, cam_col, pass_col,
                            res, jf, fcol, jpt, ok):
    """Rows ``lo:hi`` of :func:`all_observation_blocks`' outputs (``jf`` zeroed and ``fcol``
    -1 beforehand)."""
    for i in range(lo, hi):
        r = rec[i]
        im = int(r[REC_IMAGE])
        cm = int(r[REC_CAMERA])
        it = img_tab[im]
        ct = cam_tab[cm]
        nf = int(it[IT_NFREE])
        nc = int(ct[0]) if cm >= 0 else 0  # camera -1: an RPC image (no camera)
        coef = it[IT_BASE:KC_START].copy()
        for j in range(nf):
            coef[int(it[IT_FREE + j])] = img_p[im, j]
        oc = r[REC_OC:REC_PASS_SLOT]
        p = pts[pt_idx[i]]
        iop = coef[:0]  # none (a view, not an allocation)
        if cm >= 0 and ct[1] != 0.0:
            iop = ct[2 + N_IOP : 2 + 2 * N_IOP].copy()
            for j in range(nc):
                iop[int(ct[2 + j])] = cam_p[cm, j]
        good, ln, cl, dl_dc, dl_dp, dc_dc, dc_dp, dl_di, dc_di = project_observation(
            int(it[IT_KIND]), coef, it[KC_START:], p, oc, iop, int(r[REC_CHIP]), r[REC_CHIP_LEN], runtime_flag(True)
        )
        if dl_di.shape[0] == 0:
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
