"""Sub-pixel positions by correlation, and the check of matches against the sensor model.

Correlation (:func:`refine_track`): a track's reference is its first image (lowest index); its
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
``max(3.5 sigma, 0.5 px)`` excluded, sigma from the median absolute deviation); the scatter
about it is the pair's matching precision, and the points beyond are removed.
"""

from __future__ import annotations

import functools

import numpy as np

from solver.matching.orientation import MatchImage, PairMapping, distance_to_segment

SEARCH_PX = 3
RECENTRED_SEARCH_PX = 1  # after a peak inside the search the estimate is on it: +-1 px holds it and its parabola's neighbours
READ_MARGIN_PX = 4  # read around the first iteration's window: the later ones move by a pixel or less
MAX_ITERATIONS = 6
CONVERGED_PX = 0.01
MIN_TEMPLATE_STD = 1e-3  # relative to the image's stretch: a flat template has no position
SIGMA_FLOOR_PX = 0.05  # the least matching precision of a pair (quantisation, resampling)
# The reference measurement is the defining pixel: the tie point is its ground point, so it has
# no matching error; this small sigma only keeps its weight finite. The other image's sigma is
# the rest of the pair's measured scatter (:func:`other_sigma`).
REFERENCE_SIGMA_PX = 0.02


def _parabola(r_minus: float, r0: float, r_plus: float) -> float:
    den = r_minus - 2.0 * r0 + r_plus
    return 0.0 if den >= 0 else float(min(max(0.5 * (r_minus - r_plus) / den, -0.5), 0.5))


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
    the local affine ``jac`` (d other / d reference); None when it fails (module docstring)."""
    import cv2

    half = tpl.shape[0] // 2
    p = np.asarray(start, float).copy()
    read = (0, 0, 0, 0)  # the window read (r0, c0, r1, c1), with READ_MARGIN_PX for the next iterations
    win = np.zeros((0, 0), np.float32)
    on_border = True  # the first iteration searches the whole +-SEARCH_PX
    for it in range(MAX_ITERATIONS):
        search = SEARCH_PX if on_border else RECENTRED_SEARCH_PX
        radius = half + search
        uu, vv = _offsets(radius)
        lines = p[0] + jac[0, 0] * uu + jac[0, 1] * vv
        cols = p[1] + jac[1, 0] * uu + jac[1, 1] * vv
        # an affine grid's extremes are at its corners (rounding is monotonic: the same values as min and max)
        cl, cc = lines[::2 * radius, ::2 * radius], cols[::2 * radius, ::2 * radius]
        r0, c0 = int(np.floor(cl.min())) - 3, int(np.floor(cc.min())) - 3
        r1, c1 = int(np.ceil(cl.max())) + 4, int(np.ceil(cc.max())) + 4
        if r0 < 0 or c0 < 0 or r1 > other.lines or c1 > other.columns:
            return None
        if r0 < read[0] or c0 < read[1] or r1 > read[2] or c1 > read[3]:
            m = READ_MARGIN_PX
            read = (max(r0 - m, 0), max(c0 - m, 0), min(r1 + m, other.lines), min(c1 + m, other.columns))
            win = other.raster.window(read[0], read[1], read[2] - read[0], read[3] - read[1])
        # every sample and its bicubic neighbours are inside the read: the border mode never acts
        warped = cv2.remap(win, (cols - read[1]).astype(np.float32), (lines - read[0]).astype(np.float32), cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        res = cv2.matchTemplate(warped, tpl, cv2.TM_CCOEFF_NORMED)
        i, j = np.unravel_index(int(np.argmax(res)), res.shape)
        peak = float(res[i, j])
        if not np.isfinite(peak):
            return None
        on_border = i in (0, res.shape[0] - 1) or j in (0, res.shape[1] - 1)
        if on_border:
            shift = np.array([i - search, j - search], float)
            if it == MAX_ITERATIONS - 1:
                return None
        else:
            shift = np.array([i - search + _parabola(res[i - 1, j], peak, res[i + 1, j]),
                              j - search + _parabola(res[i, j - 1], peak, res[i, j + 1])])
        p = p + jac @ shift
        if not on_border and np.max(np.abs(shift)) < CONVERGED_PX:
            break
    if peak < min_ncc:
        return None
    return p, peak


def refine_track(members: dict[int, np.ndarray], images: list[MatchImage], mapping, half: int, min_ncc: float) -> dict[int, tuple[np.ndarray, float]]:
    """Refined members ``{image: ((line, column), ncc)}`` of a track (module docstring); the
    reference (first image) at an integer pixel with NCC 1. ``mapping(a, b)`` gives the
    :class:`PairMapping` of a pair. Fewer than two members: empty."""
    ref = min(members)
    centre = np.rint(members[ref])
    tpl = template(images[ref], centre, half)
    if tpl is None:
        return {}
    out = {ref: (centre, 1.0)}
    for m in sorted(members):
        if m == ref:
            continue
        pm: PairMapping = mapping(ref, m)
        jac = pm.jacobian(float(centre[0]), float(centre[1]))
        if not np.all(np.isfinite(jac)):
            continue
        start = members[m] + jac @ (centre - members[ref])
        got = correlate(tpl, images[m], start, jac, min_ncc)
        if got is not None:
            out[m] = got
    return out if len(out) >= 2 else {}


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
        new = ok & (np.abs(np.nan_to_num(resid, nan=np.inf)) <= max(3.5 * sigma, 0.5))
        if np.array_equal(new, keep):
            break
        keep = new
    if keep.sum() >= 2:
        sigma = max(float(np.sqrt(np.mean(resid[keep] ** 2))), SIGMA_FLOOR_PX)
    return keep, sigma, resid
