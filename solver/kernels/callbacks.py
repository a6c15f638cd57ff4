"""C callbacks (numba ``@cfunc``) of the compiled residual blocks: the same observation blocks
as :mod:`solver.kernels.blocks`, called by Ceres through a function pointer from the C++ cost
function of :mod:`solver.engine.native` (no Python object, no GIL: Ceres may evaluate them on
every core).

Signature of every callback (C)::

    bool callback(const int64 *block, double *img_tab, const double *const *parameters,
                  double *residuals, double **jacobians, int want_jacobians)

``block`` is the residual block's descriptor, int64 words at the offsets ``B_*`` below (built
by :mod:`solver.engine.residual_blocks`); ``img_tab`` the calling thread's copy of the packed
image table (pass images cache their propagated segment in it); ``parameters`` and
``jacobians`` Ceres' arrays of pointers, in the block's parameter order; ``jacobians`` is null
when ``want_jacobians`` is 0, otherwise every entry points to writable storage (the C++ side
supplies scratch for the blocks Ceres holds constant).

The physics is the one of :func:`solver.kernels.blocks.point_obs_block` and
:func:`solver.kernels.blocks.fixed_obs_block`, called here with the parameter blocks copied
into the rows of one padded array instead of a tuple; both paths are tested against each other
(tests/solver/engine/test_compiled_evaluation.py).

Each callback is compiled (or loaded from the disk cache) when it is first asked for
(:func:`__getattr__`), so a solve loads only the ones its residual blocks use.
"""

from __future__ import annotations

import threading

import numpy as np
from numba import carray, cfunc, njit, types
from numba.core import cgutils
from numba.extending import intrinsic

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @cfunc)
from solver.kernels.blocks import fixed_obs_block, point_obs_block
from solver.kernels.layout import (
    LT_BASE,
    LT_DISTANCES,
    LT_FREE,
    LT_KC,
    LT_KC_LEN,
    LT_KIND,
    LT_M,
    LT_MODE,
    LT_NFREE,
    LT_OCS,
    LT_P1,
    LT_P2,
    LT_PLANES,
    LT_S,
    LT_SCAL,
    LT_TARGET,
    LT_W,
    LT_WORDS,
    OBS_REC,
    PIXEL_MAP,
)
from solver.kernels.lines import line_distances, planes_model, pushbroom_line
from solver.kernels.projection import runtime_flag
from solver.kernels.propagation import PASS_T_OFF, ensure_segment, pass_state

# descriptor of a residual block (int64 words)
B_CONTEXT = 0  # address of the context words (C_* below), shared by every block of one solve
B_REC = 1  # address of the block's first observation record (OBS_REC doubles each)
B_NREC = 2  # number of observation records
B_NSLOTS = 3  # parameter blocks the records' slots index (after the point, for point blocks)
B_MAXSIZE = 4  # largest of those blocks
B_DATA = 5  # fixed blocks: address of the ground points (NREC x 3, LGS m); pass terms: of the term's data
B_SIZES = 6  # the sizes of the residual block's parameter blocks, in Ceres' order
B_HEADER = B_SIZES

# context words
C_IMG_ROWS = 0  # image table rows
C_IMG_COLS = 1  # image table columns
C_CAM_TAB = 2  # address of the camera table
C_CAM_ROWS = 3
C_CAM_COLS = 4
N_CONTEXT = 5

# descriptor of a pass-state term (:class:`solver.observations.passes.PassStateTerm`)
PS_KC = 0  # address of the term's private trajectory segment (kc, written by ensure_segment)
PS_KC_LEN = 1
PS_M = 2  # rows: 3 (position) or 6 (position and velocity)
PS_B = 3  # address of the observed state (m doubles, ECEF m and m/s)
PS_W = 4  # address of the weights 1/sigma (m doubles)
PS_WORDS = 5

CALLBACK_SIGNATURE = types.boolean(types.voidptr, types.voidptr, types.voidptr, types.voidptr, types.voidptr, types.intc)
_CFUNC = dict(nopython=True, cache=True, error_model="numpy")


@intrinsic
def _pointer(typingctx, address):
    """The int64 ``address`` as a ``void *`` (for :func:`numba.carray`)."""
    sig = types.voidptr(types.int64)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)

    return sig, codegen


@njit(inline="always", error_model="numpy")
def _doubles(address, n):
    """The ``n`` doubles at the int64 ``address``."""
    return carray(_pointer(address), (n,), dtype=np.float64)


@njit(inline="always", error_model="numpy")
def _doubles_at(pointer, n):
    """The ``n`` doubles at ``pointer`` (a ``void *`` argument)."""
    return carray(pointer, (n,), dtype=np.float64)


def _point_block_callback(block, table, parameters, residuals, jacobians, want):
    """All observations of one estimated point: parameter blocks [point (3), slots...]."""
    head = carray(block, (B_HEADER,), dtype=np.int64)
    nrec = head[B_NREC]
    nslots = head[B_NSLOTS]
    width = head[B_MAXSIZE]
    sizes = carray(block, (B_SIZES + 1 + nslots,), dtype=np.int64)[B_SIZES:]
    ctx = carray(_pointer(head[B_CONTEXT]), (N_CONTEXT,), dtype=np.int64)
    img_tab = carray(table, (ctx[C_IMG_ROWS], ctx[C_IMG_COLS]), dtype=np.float64)
    cam_tab = carray(_pointer(ctx[C_CAM_TAB]), (ctx[C_CAM_ROWS], ctx[C_CAM_COLS]), dtype=np.float64)
    rec = carray(_pointer(head[B_REC]), (nrec, OBS_REC), dtype=np.float64)
    pptr = carray(parameters, (nslots + 1,), dtype=np.int64)
    point = _doubles(pptr[0], 3)
    params = np.zeros((nslots, width))
    for s in range(nslots):
        src = _doubles(pptr[s + 1], sizes[s + 1])
        for q in range(sizes[s + 1]):
            params[s, q] = src[q]
    res = _doubles_at(residuals, 2 * nrec)
    rows = 2 * nrec
    if want == 0:  # no Jacobian: empty views stand for the arrays it would fill (no allocation)
        return point_obs_block(rec, img_tab, cam_tab, point, params, res, res[:0], params[:0], runtime_flag(False))
    jacs = np.empty((nslots, rows * width))
    jptr = carray(jacobians, (nslots + 1,), dtype=np.int64)
    jac_p = _doubles(jptr[0], 3 * rows)
    ok = point_obs_block(rec, img_tab, cam_tab, point, params, res, jac_p, jacs, runtime_flag(True))
    for s in range(nslots):
        n = rows * sizes[s + 1]
        dst = _doubles(jptr[s + 1], n)
        for q in range(n):
            dst[q] = jacs[s, q]
    return ok


def _fixed_block_callback(block, table, parameters, residuals, jacobians, want):
    """Observations of fixed ground points in one image (a resection block): parameter blocks [slots...]."""
    head = carray(block, (B_HEADER,), dtype=np.int64)
    nrec = head[B_NREC]
    nslots = head[B_NSLOTS]
    width = head[B_MAXSIZE]
    sizes = carray(block, (B_SIZES + nslots,), dtype=np.int64)[B_SIZES:]
    ctx = carray(_pointer(head[B_CONTEXT]), (N_CONTEXT,), dtype=np.int64)
    img_tab = carray(table, (ctx[C_IMG_ROWS], ctx[C_IMG_COLS]), dtype=np.float64)
    cam_tab = carray(_pointer(ctx[C_CAM_TAB]), (ctx[C_CAM_ROWS], ctx[C_CAM_COLS]), dtype=np.float64)
    rec = carray(_pointer(head[B_REC]), (nrec, OBS_REC), dtype=np.float64)
    pts = carray(_pointer(head[B_DATA]), (nrec, 3), dtype=np.float64)
    pptr = carray(parameters, (nslots,), dtype=np.int64)
    params = np.zeros((nslots, width))
    for s in range(nslots):
        src = _doubles(pptr[s], sizes[s])
        for q in range(sizes[s]):
            params[s, q] = src[q]
    res = _doubles_at(residuals, 2 * nrec)
    rows = 2 * nrec
    if want == 0:  # no Jacobian: an empty view stands for the array it would fill (no allocation)
        return fixed_obs_block(rec, img_tab, cam_tab, pts, params, res, params[:0], runtime_flag(False))
    jacs = np.empty((nslots, rows * width))
    ok = fixed_obs_block(rec, img_tab, cam_tab, pts, params, res, jacs, runtime_flag(True))
    jptr = carray(jacobians, (nslots,), dtype=np.int64)
    for s in range(nslots):
        n = rows * sizes[s]
        dst = _doubles(jptr[s], n)
        for q in range(n):
            dst[q] = jacs[s, q]
    return ok


def _pass_state_callback(block, table, parameters, residuals, jacobians, want):
    """A weighted state vector observing the propagated pass state at its epoch:
    r = W (S(t; x0) - b) on the pass block x0 (6: ECEF position m, velocity m/s). The segment
    is the term's own (one residual block is never evaluated by two threads at once)."""
    d = carray(block, (PS_WORDS,), dtype=np.int64)
    kc = _doubles(d[PS_KC], d[PS_KC_LEN])
    m = d[PS_M]
    b = _doubles(d[PS_B], m)
    w = _doubles(d[PS_W], m)
    pptr = carray(parameters, (1,), dtype=np.int64)
    src = _doubles(pptr[0], 6)
    x0 = np.empty(6)
    for i in range(6):
        x0[i] = src[i]
    ensure_segment(kc, x0)
    p, v, _a, ds, dv = pass_state(kc, kc[PASS_T_OFF], True)
    res = _doubles_at(residuals, m)
    ok = True
    for i in range(m):
        val = p[i] if i < 3 else v[i - 3]
        res[i] = w[i] * (val - b[i])
        if not np.isfinite(res[i]):
            ok = False
    if want != 0:
        jptr = carray(jacobians, (1,), dtype=np.int64)
        jac = _doubles(jptr[0], m * 6)
        for i in range(m):
            for j in range(6):
                jac[i * 6 + j] = w[i] * (ds[i, j] if i < 3 else dv[i - 3, j])
    return ok


def _line_term_callback(block, table, parameters, residuals, jacobians, want):
    """A straight-line term on one image's parameter block (:class:`solver.observations.lines.LineTerm`):
    the equivalent planes model, the rigorous distances of measured points, or the rigorous
    line through the projected endpoints against a fitted image line, whitened by the term's
    matrix W: r = W (observed - model), J = W d(observed - model)/dp. Non-finite residuals fail
    the evaluation (as on the Python path). ``table`` is unused: a line image is never a pass
    image, its constants are the term's own."""
    d = carray(block, (LT_WORDS,), dtype=np.int64)
    mode = d[LT_MODE]
    kind = d[LT_KIND]
    nf = d[LT_NFREE]
    m = d[LT_M]
    kc = _doubles(d[LT_KC], d[LT_KC_LEN])
    coef = _doubles(d[LT_BASE], 24).copy()
    free = carray(_pointer(d[LT_FREE]), (nf,), dtype=np.int64)
    p1 = _doubles(d[LT_P1], 3)
    p2 = _doubles(d[LT_P2], 3)
    w = carray(_pointer(d[LT_W]), (m, m), dtype=np.float64)
    scal = _doubles(d[LT_SCAL], 3)
    form = int(scal[2])
    pptr = carray(parameters, (1,), dtype=np.int64)
    x = _doubles(pptr[0], nf)
    for j in range(nf):
        coef[free[j]] = x[j]
    wantj = want != 0
    r = np.empty(m)
    if mode == LT_DISTANCES:
        ocs = carray(_pointer(d[LT_OCS]), (m, 9), dtype=np.float64)
        s = _doubles(d[LT_S], m)
        ok, dist, jc, _jp = line_distances(kind, coef, kc, p1, p2, ocs, s, wantj)
        for i in range(m):
            r[i] = dist[i]
        sign = 1.0
    else:
        target = _doubles(d[LT_TARGET], 2)
        if mode == LT_PLANES:
            ab, jc, _jp = planes_model(kind, coef, kc, p1, p2, scal[0], scal[1], form, wantj)
            ok = True
        else:
            eo = carray(_pointer(d[LT_OCS]), (2, 9), dtype=np.float64)
            pm = np.array(PIXEL_MAP)
            ok, ab, jc, _jp = pushbroom_line(kind, coef, kc, p1, p2, eo[0].copy(), eo[1].copy(), pm, pm, form, wantj)
        for i in range(2):
            r[i] = target[i] - ab[i]
        sign = -1.0
    res = _doubles_at(residuals, m)
    good = ok
    for i in range(m):
        acc = 0.0
        for k in range(m):
            acc += w[i, k] * r[k]
        res[i] = acc if ok else np.nan
        good = good and np.isfinite(res[i])
    if wantj:
        jptr = carray(jacobians, (1,), dtype=np.int64)
        jac = _doubles(jptr[0], m * nf)
        for i in range(m):
            for j in range(nf):
                acc = 0.0
                for k in range(m):
                    acc += w[i, k] * jc[k, free[j]]
                jac[i * nf + j] = sign * acc
    return good


CALLBACKS = ("point_block_callback", "fixed_block_callback", "pass_state_callback", "line_term_callback")
_LOADING = threading.Lock()


def __getattr__(name: str):
    """A callback compiled (or loaded from the disk cache) on first use, not at import: loading
    one takes 10-40 ms, and a job without straight lines or pass states needs only the point
    blocks'."""
    if name not in CALLBACKS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    with _LOADING:  # two threads solving at once compile or load each callback once
        compiled = globals().get(name)
        if compiled is None:
            compiled = cfunc(CALLBACK_SIGNATURE, **_CFUNC)(globals()["_" + name])
            globals()[name] = compiled
    return compiled


def load_all() -> None:
    """Compile or load every callback now (a worker before its first job, the warm-up)."""
    for name in CALLBACKS:
        __getattr__(name)
