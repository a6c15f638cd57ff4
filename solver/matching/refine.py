"""Sub-pixel positions by correlation, and the check of matches against the sensor model.

Correlation (:func:`refine_tracks`): a track's reference is its first image (lowest index); its
measurement is the pixel nearest to the linked position, an integer (line, column), so the tie
point is that pixel's ground point. A (2 h + 1)-pixel template around it is compared with each
other image resampled into the reference's geometry: the local affine of the orientation
(:meth:`PairMapping.jacobian`, terrain-height independent to first order) around the current
estimate, bicubic (OpenCV ``remap``). The normalised cross-correlation (``TM_CCOEFF_NORMED``)
over +-``SEARCH_PX`` shifts, a parabola through the peak and its neighbours on each axis, the
estimate moved by the fitted shift, and again (after a peak inside the search, over
+-``RECENTRED_SEARCH_PX`` only: the estimate is now on the peak; after a peak on the border,
over +-``SEARCH_PX`` again, so a far start moves as far as before), until the shift is below ``CONVERGED_PX``: the
last fit is centred on the peak, which removes the parabola's pull towards whole pixels. A
peak below ``min_ncc``, on the border of the search after the last iteration, or a template
without texture: the image is left out of the track.

Check (:func:`epipolar_check`): the distance of a matched point from its epipolar segment
(the reference pixel's positions at the lowest and highest terrain height) is the orientation's
error (smooth over the image) plus the matching's error. Per pair, a plane in the reference's
(line, column) is fitted robustly to the signed distances (iteratively, points beyond
``3.5 sigma`` excluded, sigma from the median absolute deviation, at least
``SIGMA_FLOOR_PX``); the scatter about it is the pair's matching precision, and the points
beyond are removed. (A floor of 0.5 px on the exclusion, as before, kept on the real Giza pair
seven matches 0.25-0.5 px off, 3.5-7 sigma: they raised the stated scatter from 0.067 to
0.074 px, data snooping then removed them and the adjustment's sigma0 fell to 0.94, at the
chi-square test's lower bound.)
"""

from __future__ import annotations

import functools
from concurrent.futures import Executor

import numpy as np

from solver.matching.orientation import MatchImage, PairMapping, distance_to_segment

SEARCH_PX = 3
RECENTRED_SEARCH_PX = 1  # after a peak inside the search the estimate is on it: +-1 px holds it and its parabola's neighbours
READ_MARGIN_PX = 4  # read around the first iteration's window: the later ones move by a pixel or less
MAX_ITERATIONS = 6
# OpenCV's remap resolves a sample's position to 1/32 px: a smaller shift only wanders by about
# 1/64 px from one iteration to the next (0.01 px: 39 % more correlations on bench_match's crops,
# the same error against the scene's truth, 0.046 px along lines and 0.016 px across)
CONVERGED_PX = 0.02
GRID_CHUNK = 128  # searches whose sample grids are computed together (about 4 MB of float64 temporaries)
MIN_TEMPLATE_STD = 1e-3  # relative to the image's stretch: a flat template has no position
SIGMA_FLOOR_PX = 0.05  # the least matching precision of a pair (quantisation, resampling)
# The reference measurement is the defining pixel: the tie point is its ground point, so it has
# no matching error; this small sigma only keeps its weight finite. The other image's sigma is
# the rest of the pair's measured scatter (:func:`other_sigma`).
REFERENCE_SIGMA_PX = 0.02


@functools.cache
def _offsets(radius: int) -> tuple[np.ndarray, np.ndarray]:
    """The (line, column) offsets (px, each (2 radius + 1)^2, read-only) of a square window."""
    u = np.arange(-radius, radius + 1, dtype=float)
    uu, vv = np.meshgrid(u, u, indexing="ij")
    uu.flags.writeable = vv.flags.writeable = False
    return uu, vv


def template(image: MatchImage, centre: np.ndarray, half: int) -> np.ndarray | None:
    """The (2 half + 1)^2 raw template of ``image`` around an integer ``centre``; None at the
    border or without texture."""
    r, c = int(centre[0]) - half, int(centre[1]) - half
    t = image.raster.window(r, c, 2 * half + 1, 2 * half + 1)
    lo, hi = image.raster.stretch
    if t.shape != (2 * half + 1, 2 * half + 1) or float(t.std()) < MIN_TEMPLATE_STD * (hi - lo):
        return None
    return t


def correlate(tpl: np.ndarray, other: MatchImage, start: np.ndarray, jac: np.ndarray, min_ncc: float) -> tuple[np.ndarray, float] | None:
    """(line, column) in ``other`` of the template's centre and the NCC peak, from ``start`` with
    the local affine ``jac`` (d other / d reference); None when it fails (module docstring).
    One search of :func:`correlate_many`."""
    return correlate_many([tpl], [other], np.asarray(start, float)[None], np.asarray(jac, float)[None], min_ncc)[0]


def correlate_many(tpls: list[np.ndarray], others: list[MatchImage], starts: np.ndarray, jacs: np.ndarray,
                   min_ncc: float, pool: Executor | None = None) -> list[tuple[np.ndarray, float] | None]:
    """:func:`correlate` of many searches at once: template ``tpls[n]`` (all the same size) in
    ``others[n]`` from ``starts[n]`` (line, column) with the local affine ``jacs[n]`` (2 x 2).

    The searches iterate in step (one iteration of every search still going per round): the
    sample grids, the windows to read, the peaks, the parabolas and the moves are whole-array
    operations over the searches, and only OpenCV's ``remap`` and ``matchTemplate`` run once
    per search (about 50 us together, where the arithmetic around them cost four times that
    per search in Python), half of them in ``pool``'s thread when given. A search's result is
    the one it gets alone."""
    n = len(tpls)
    if n == 0:
        return []
    half = tpls[0].shape[0] // 2
    p = np.array(starts, float).reshape(n, 2)
    jacs = np.asarray(jacs, float).reshape(n, 2, 2)
    size = np.array([[o.lines, o.columns] for o in others]).reshape(n, 2)
    read = np.zeros((n, 4), int)  # the window read (r0, c0, r1, c1), with READ_MARGIN_PX for the next iterations
    wins: list[np.ndarray] = [np.zeros((0, 0), np.float32)] * n
    on_border = np.ones(n, dtype=bool)  # the first iteration searches the whole +-SEARCH_PX
    going = np.ones(n, dtype=bool)
    failed = np.zeros(n, dtype=bool)
    peak = np.full(n, -np.inf)
    for it in range(MAX_ITERATIONS):
        # this round's searches of each width, chosen before any of them moves
        rounds = [(np.flatnonzero(going & on_border), SEARCH_PX), (np.flatnonzero(going & ~on_border), RECENTRED_SEARCH_PX)]
        for sel, search in rounds:
            if len(sel):
                _iterate(sel, search, it, tpls, others, half, p, jacs, size, read, wins, on_border, going, failed, peak, pool)
        if not going.any():
            break
    return [None if failed[k] or not peak[k] >= min_ncc else (p[k].copy(), float(peak[k])) for k in range(n)]


def _iterate(sel, search, it, tpls, others, half, p, jacs, size, read, wins, on_border, going, failed, peak, pool) -> None:
    """One iteration of the searches ``sel`` (indices) that search +-``search`` px: the state
    arrays of :func:`correlate_many` updated in place (``pool``: a thread that resamples and
    correlates half of them)."""
    import cv2

    radius = half + search
    uu, vv = _offsets(radius)
    jac, q = jacs[sel], p[sel]
    # the sample grid's extremes are at its corners (rounding is monotonic): the corners' values
    # are the grid's own (the same operations as the whole grid below)
    cu, cv = uu[::2 * radius, ::2 * radius], vv[::2 * radius, ::2 * radius]
    cl = q[:, 0, None, None] + jac[:, 0, 0, None, None] * cu + jac[:, 0, 1, None, None] * cv
    cc = q[:, 1, None, None] + jac[:, 1, 0, None, None] * cu + jac[:, 1, 1, None, None] * cv
    need = np.column_stack([np.floor(cl.min((1, 2))) - 3, np.floor(cc.min((1, 2))) - 3,
                            np.ceil(cl.max((1, 2))) + 4, np.ceil(cc.max((1, 2))) + 4]).astype(int)
    outside = (need[:, 0] < 0) | (need[:, 1] < 0) | (need[:, 2] > size[sel, 0]) | (need[:, 3] > size[sel, 1])
    failed[sel[outside]], going[sel[outside]] = True, False
    if outside.any():
        inside = ~outside
        sel, q, need, jac = sel[inside], q[inside], need[inside], jac[inside]
        if not len(sel):
            return
    m = READ_MARGIN_PX
    for t in np.flatnonzero(np.any((need[:, :2] < read[sel, :2]) | (need[:, 2:] > read[sel, 2:]), axis=1)):
        k = sel[t]
        r0, c0, r1, c1 = need[t]
        read[k] = (max(r0 - m, 0), max(c0 - m, 0), min(r1 + m, size[k, 0]), min(c1 + m, size[k, 1]))
        wins[k] = others[k].raster.window(read[k, 0], read[k, 1], read[k, 2] - read[k, 0], read[k, 3] - read[k, 1])
    w = 2 * search + 1
    res = np.empty((len(sel), w, w), np.float32)

    def fill(part: slice) -> None:
        qq, jj, rr = q[part], jac[part], read[sel[part]]
        my = (qq[:, 0, None, None] + jj[:, 0, 0, None, None] * uu + jj[:, 0, 1, None, None] * vv - rr[:, 0, None, None]).astype(np.float32)
        mx = (qq[:, 1, None, None] + jj[:, 1, 0, None, None] * uu + jj[:, 1, 1, None, None] * vv - rr[:, 1, None, None]).astype(np.float32)
        for t, k in enumerate(sel[part]):
            # every sample and its bicubic neighbours are inside the read: the border mode never acts
            warped = cv2.remap(wins[k], mx[t], my[t], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
            res[part.start + t] = cv2.matchTemplate(warped, tpls[k], cv2.TM_CCOEFF_NORMED)

    # the sample grids of GRID_CHUNK searches at a time (memory); with a pool, every other part
    # in its thread (OpenCV lets go of Python's lock: each search's result is its own)
    step = GRID_CHUNK if pool is None or len(sel) > 2 * GRID_CHUNK else max(1, -(-len(sel) // 2))
    parts = [slice(t0, t0 + step) for t0 in range(0, len(sel), step)]
    ahead = [pool.submit(fill, part) for part in parts[1::2]] if pool is not None else []
    for part in parts[0::2] if pool is not None else parts:
        fill(part)
    for done in ahead:
        done.result()
    res64 = res.astype(np.float64)
    best = np.argmax(res.reshape(len(sel), -1), axis=1)
    i, j = best // w, best % w
    top = res64.reshape(len(sel), -1)[np.arange(len(sel)), best]
    bad = ~np.isfinite(top)
    border = (i == 0) | (i == w - 1) | (j == 0) | (j == w - 1)
    lost = bad | (border & (it == MAX_ITERATIONS - 1))
    inner = ~border & ~bad
    shift = np.column_stack([i - search, j - search]).astype(float)
    if inner.any():
        a, ii, jj, pk = np.flatnonzero(inner), i[inner], j[inner], top[inner]
        shift[inner, 0] += _parabola(res64[a, ii - 1, jj], pk, res64[a, ii + 1, jj])
        shift[inner, 1] += _parabola(res64[a, ii, jj - 1], pk, res64[a, ii, jj + 1])
    moving = ~lost
    p[sel[moving]] += np.einsum("nij,nj->ni", jac[moving], shift[moving])
    peak[sel], on_border[sel] = top, border
    failed[sel[lost]], going[sel[lost]] = True, False
    going[sel[inner & (np.max(np.abs(shift), axis=1) < CONVERGED_PX)]] = False


def _parabola(r_minus: np.ndarray, r0: np.ndarray, r_plus: np.ndarray) -> np.ndarray:
    """The vertex of the parabola through three samples (at -1, 0, +1) of each search, within
    +-0.5; 0 where the samples do not curve down."""
    den = r_minus - 2.0 * r0 + r_plus
    with np.errstate(all="ignore"):
        x = np.clip(0.5 * (r_minus - r_plus) / den, -0.5, 0.5)
    return np.where(den < 0, x, 0.0)


def refine_tracks(tracks: list[dict[int, np.ndarray]], images: list[MatchImage], mapping, half: int, min_ncc: float,
                  pool: Executor | None = None) -> list[dict[int, tuple[np.ndarray, float]]]:
    """Refined members ``{image: ((line, column), ncc)}`` of every track (module docstring): the
    reference (first image) at an integer pixel with NCC 1, empty for a track left with fewer
    than two members; ``mapping(a, b)`` gives the :class:`PairMapping` of a pair. The
    correlations of all of them run together (:func:`correlate_many`, ``pool``: a thread that
    takes half of them)."""
    out: list[dict[int, tuple[np.ndarray, float]]] = [{} for _ in tracks]
    pending: dict[tuple[int, int], list[tuple[int, np.ndarray]]] = {}  # (ref, member) -> (track, centre)
    tpls: dict[int, np.ndarray] = {}
    for k, members in enumerate(tracks):
        ref = min(members)
        centre = np.rint(members[ref])
        tpl = template(images[ref], centre, half)
        if tpl is None:
            continue
        tpls[k] = tpl
        out[k][ref] = (centre, 1.0)
        for m in sorted(members):
            if m != ref:
                pending.setdefault((ref, m), []).append((k, centre))
    searches: list[tuple[int, int]] = []
    starts, jacs = [], []
    for (ref, m), items in sorted(pending.items()):
        centres = np.array([c for _k, c in items])
        jac = mapping(ref, m).jacobians(centres[:, 0], centres[:, 1])
        ok = np.all(np.isfinite(jac), axis=(1, 2))
        for (k, c), J, good in zip(items, jac, ok, strict=True):
            if good:
                searches.append((k, m))
                starts.append(tracks[k][m] + J @ (c - tracks[k][ref]))
                jacs.append(J)
    got = correlate_many([tpls[k] for k, _m in searches], [images[m] for _k, m in searches], np.array(starts).reshape(-1, 2),
                         np.array(jacs).reshape(-1, 2, 2), min_ncc, pool)
    for (k, m), g in zip(searches, got, strict=True):
        if g is not None:
            out[k][m] = g
    return [r if len(r) >= 2 else {} for r in out]


def other_sigma(pair_sigma: float) -> float:
    """The sigma (px) of the non-reference measurements of a pair whose matches scatter by
    ``pair_sigma`` px about their epipolar curves: with :data:`REFERENCE_SIGMA_PX` the two
    variances add up to the scatter's, so the adjustment's residuals across the epipolar
    direction have the measured spread (sigma0 near 1 when the stated precision is right)."""
    return float(np.sqrt(max(pair_sigma**2 - REFERENCE_SIGMA_PX**2, REFERENCE_SIGMA_PX**2)))


def epipolar_check(ref_pos: np.ndarray, pos: np.ndarray, mapping: PairMapping, search_px: float) -> tuple[np.ndarray, float, np.ndarray]:
    """(kept mask, matching sigma px, residuals px) of one pair's refined matches (module
    docstring): ``ref_pos`` (n, 2) in the reference image, ``pos`` (n, 2) in the other."""
    s0, s1 = mapping.segment(ref_pos[:, 0], ref_pos[:, 1])
    perp, beyond = distance_to_segment(pos, s0, s1)
    ok = np.isfinite(perp) & (beyond <= search_px)
    n = len(pos)
    a = np.column_stack([np.ones(n), ref_pos[:, 0] / max(mapping.a.lines, 1), ref_pos[:, 1] / max(mapping.a.columns, 1)])
    keep = ok.copy()
    resid = np.where(ok, perp, np.nan)
    sigma = SIGMA_FLOOR_PX
    for _ in range(10):
        if keep.sum() < 4:
            coef = np.array([np.median(perp[ok]) if ok.any() else 0.0, 0.0, 0.0])
        else:
            coef = np.linalg.lstsq(a[keep], perp[keep], rcond=None)[0]
        resid = np.where(ok, perp - a @ coef, np.nan)
        mad = np.median(np.abs(resid[keep])) if keep.any() else 0.0
        sigma = max(1.4826 * float(mad), SIGMA_FLOOR_PX)
        new = ok & (np.abs(np.nan_to_num(resid, nan=np.inf)) <= 3.5 * sigma)
        if np.array_equal(new, keep):
            break
        keep = new
    if keep.sum() >= 2:
        sigma = max(float(np.sqrt(np.mean(resid[keep] ** 2))), SIGMA_FLOOR_PX)
    return keep, sigma, resid
