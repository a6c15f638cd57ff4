"""Tie points verified in 3-D before they are written.

A pairwise epipolar check cannot see an error along the epipolar line: it is a height. A track
of three or more images can: its rays do not meet. Each track is intersected with the guiding
orientation (the point nearest to its rays in the least-squares sense, ECEF metres; a ray is
the image position's ground points at the lowest and the highest terrain height) and projected
back into its images; the residual (measured - projected, pixels) of each measurement is its
misfit.

The orientation has errors of its own (delivered RPCs: a shift of pixels to tens of pixels; an
initial attitude: a rotation as well), smooth over an image: per image (the first image fixed,
as the block's datum is free) an affine function of (line, column), fitted robustly to the
image's residuals over all tracks, is estimated and removed from the measurements before the
intersection (iterated: the residual of an image against the point the
track's other images give, its median over the tracks).

Then every track of three or more images is tested: each measurement against the point its
other images give, the residual against ``max(OUTLIER_SIGMAS x sqrt(sum of the track's stated
variances), OUTLIER_FLOOR_PX)``. Of a failing track of three images the non-reference
measurements are removed (one blunder along an epipolar line cannot be told from the others:
any of the three rays could be moved to meet the two others; the reference pixel defines the
tie point); of a longer track the worst measurement, and the test is repeated. A two-image
track has no redundancy along the epipolar line (the epipolar check judged it across).

Then the stated sigmas are calibrated on what remains (:func:`sigma_scales`): per image, the
factor of its stated sigmas that makes the kept measurements' residuals (against the point the
track's other images give) as large as their stated sigmas predict. A residual's variance is
the measurement's own plus the other measurements' as they move the point (their effect on the
residual, 2 x 2 per measurement, by moving each by :data:`DELTA_PX`); the reference measurement
defines the tie point and has none. The squared factors are the least-squares solution of the
squared residuals (weighted by their predicted variance's inverse square, residuals beyond
:data:`CALIBRATION_CLIP` predicted sigmas left out, iterated); an image with fewer than
:data:`CALIBRATION_MIN` non-reference measurements in such tracks keeps its stated sigmas.
"""

from __future__ import annotations

import numpy as np

OUTLIER_SIGMAS = 5.0  # a residual beyond this many stated sigmas is a blunder
OUTLIER_FLOOR_PX = 0.5  # ... and beyond half a pixel (the stated sigmas are 0.05-0.2 px)
BIAS_ITERATIONS = 6
DELTA_PX = 0.05  # the move of a measurement that gives its effect on the other residuals
CALIBRATION_MIN = 20  # non-reference measurements in tracks of three or more images an image needs for its sigma's factor
CALIBRATION_CLIP = 3.5  # residuals beyond this many predicted sigmas do not calibrate
CALIBRATION_ITERATIONS = 10


def _rays(model, pos: np.ndarray, heights: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(origin, unit direction) in ECEF of image positions ``pos`` (n, 2)."""
    with np.errstate(all="ignore"):
        lo = np.asarray(model.image_to_ground(pos[:, 0], pos[:, 1], height_m=float(heights[0])), float)
        hi = np.asarray(model.image_to_ground(pos[:, 0], pos[:, 1], height_m=float(heights[1])), float)
    d = hi - lo
    return lo, d / np.linalg.norm(d, axis=1, keepdims=True)


def _intersections(tracks: list[dict[int, np.ndarray]], models: list, heights: tuple[float, float], bias: np.ndarray, sizes):
    """Per track ``{image: (origin, direction)}`` of its measurements' rays (bias removed)."""
    span = (heights[0] - 100.0, heights[1] + 100.0)
    rays: dict[int, list] = {}
    for k, t in enumerate(tracks):
        for i, p in t.items():
            rays.setdefault(i, []).append((k, p))
    out: list[dict[int, tuple[np.ndarray, np.ndarray]]] = [{} for _ in tracks]
    for i, items in rays.items():
        pos = np.array([p for _k, p in items])
        o, d = _rays(models[i], pos - apply_bias(bias, i, pos, sizes[i]), span)
        for (k, _p), oi, di in zip(items, o, d, strict=True):
            out[k][i] = (oi, di)
    return out


def residuals(tracks: list[dict[int, np.ndarray]], models: list, heights: tuple[float, float], bias: np.ndarray,
              sizes: list[tuple[int, int]], leave_out: bool = False) -> list[dict[int, np.ndarray]]:
    """Per track ``{image: measured - bias - projected (line, column)}`` (module docstring),
    the point intersected from all the track's rays, or (``leave_out``, tracks of three or
    more images) from the other images' rays only; NaN where a ray or a projection fails.

    A track's point is the one nearest to its rays (origins o, unit directions d) in the least-
    squares sense: sum (I - d d^T) x = sum (I - d d^T) o. The sums of every track at once (a
    left-out ray's share taken off again), solved as one stack of 3 x 3 systems."""
    rays = _intersections(tracks, models, heights, bias, sizes)
    entries = [(k, i) for k, t in enumerate(tracks) for i in sorted(t)]
    out: list[dict[int, np.ndarray]] = [{} for _ in tracks]
    if not entries:
        return out
    track = np.array([k for k, _i in entries])
    image = np.array([i for _k, i in entries])
    o = np.array([rays[k][i][0] for k, i in entries], float)
    d = np.array([rays[k][i][1] for k, i in entries], float)
    bad = ~(np.all(np.isfinite(o), axis=1) & np.all(np.isfinite(d), axis=1))
    o[bad], d[bad] = 0.0, 0.0
    proj = np.eye(3) - d[:, :, None] * d[:, None, :]  # I - d d^T
    proj[bad] = 0.0
    rhs = np.einsum("nij,nj->ni", proj, o)
    a = np.zeros((len(tracks), 3, 3))
    b = np.zeros((len(tracks), 3))
    np.add.at(a, track, proj)
    np.add.at(b, track, rhs)
    n_bad = np.bincount(track, weights=bad, minlength=len(tracks))
    size = np.bincount(track, minlength=len(tracks))
    if leave_out:
        use = size[track] >= 3
        a_e, b_e = a[track] - proj, b[track] - rhs
        ok = use & (n_bad[track] - bad == 0)
    else:
        use = np.ones(len(entries), dtype=bool)
        a_e, b_e = a[track], b[track]
        ok = n_bad[track] == 0
    xyz = np.full((len(entries), 3), np.nan)
    if ok.any():
        xyz[ok] = np.linalg.solve(a_e[ok], b_e[ok][:, :, None])[:, :, 0]
    for i in np.unique(image[use]):
        sel = np.flatnonzero(use & (image == i))
        with np.errstate(all="ignore"):
            line, col, _chip = models[i].ground_to_image(xyz[sel])
        pred = np.column_stack([np.asarray(line, float).ravel(), np.asarray(col, float).ravel()])
        measured = np.array([tracks[track[e]][i] for e in sel])
        corrected = measured - apply_bias(bias, int(i), measured, sizes[i])
        for e, c, p in zip(sel, corrected, pred, strict=True):
            out[track[e]][int(i)] = c - p
    return out


def _design(pos: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(n, 3): 1, line and column scaled to -1..1 over the image."""
    return np.column_stack([np.ones(len(pos)), 2.0 * pos[:, 0] / max(size[0], 1) - 1.0, 2.0 * pos[:, 1] / max(size[1], 1) - 1.0])


def _robust_affine(a: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(3, 2) coefficients of the residuals ``r`` (n, 2) on the design ``a`` (n, 3), least squares
    with points beyond max(3.5 MAD-sigmas, 0.3 px) left out, three times."""
    keep = np.ones(len(r), dtype=bool)
    coef = np.zeros((3, 2))
    for _ in range(3):
        if keep.sum() < 6:
            coef = np.vstack([np.median(r[keep] if keep.any() else r, axis=0), np.zeros((2, 2))])
            break
        coef = np.linalg.lstsq(a[keep], r[keep], rcond=None)[0]
        e = np.hypot(*(r - a @ coef).T)
        keep = e <= max(3.5 * 1.4826 * float(np.median(e[keep])), 0.3)
    return coef


def apply_bias(bias: np.ndarray, i: int, pos: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The bias (pixels) of image ``i`` at positions ``pos`` (n, 2)."""
    return _design(pos, size) @ bias[i]


def image_bias(tracks: list[dict[int, np.ndarray]], models: list, heights: tuple[float, float], sizes: list[tuple[int, int]]) -> np.ndarray:
    """(n_images, 3, 2) per-image bias of the orientation against the tracks, an affine function
    of (line, column) (:func:`apply_bias`), the first image's zero: fitted robustly to each
    image's residuals against the point the track's other images give (module docstring)."""
    bias = np.zeros((len(models), 3, 2))
    multi = [t for t in tracks if len(t) >= 3]
    for _ in range(BIAS_ITERATIONS):
        largest = 0.0
        for i in range(1, len(models)):  # one image at a time (all at once overshoots)
            mine = [t for t in multi if i in t]
            if len(mine) < 3:
                continue
            res = residuals(mine, models, heights, bias, sizes, leave_out=True)
            rows = [(t[i], r[i]) for t, r in zip(mine, res, strict=True) if i in r and np.all(np.isfinite(r[i]))]
            if len(rows) < 3:
                continue
            pos = np.array([p for p, _r in rows])
            step = _robust_affine(_design(pos, sizes[i]), np.array([r for _p, r in rows]))
            bias[i] += step
            largest = max(largest, float(np.max(np.abs(_design(pos, sizes[i]) @ step))))
        if largest < 0.01:
            break
    return bias


def verify(tracks: list[dict[int, np.ndarray]], sigmas: list[dict[int, float]], models: list, heights: tuple[float, float],
           sizes: list[tuple[int, int]]) -> tuple[list[set[int]], np.ndarray, list[dict[int, np.ndarray]]]:
    """The measurements to remove (per track, the images), the per-image bias and the final
    residuals (against the point the other images give) of tracks ``{image: (line, column)}``
    with stated ``sigmas`` ``{image: px}``, the reference the lowest image (module docstring)."""
    bias = image_bias(tracks, models, heights, sizes)
    removed: list[set[int]] = [set() for _ in tracks]
    final = residuals(tracks, models, heights, bias, sizes, leave_out=True)  # all tracks at once
    for k, track in enumerate(tracks):
        t = dict(track)
        r = final[k]
        while len(t) >= 3:
            if not r:
                (r,) = residuals([t], models, heights, bias, sizes, leave_out=True)  # a track that lost a member
            total = sum(sigmas[k][i] ** 2 for i in t)
            worst, excess = None, 1.0
            for i in t:
                e = float(np.hypot(*r[i])) if np.all(np.isfinite(r[i])) else np.inf
                ratio = e / max(OUTLIER_SIGMAS * float(np.sqrt(total)), OUTLIER_FLOOR_PX)
                if ratio > excess:
                    worst, excess = i, ratio
            if worst is None:
                break
            ref = min(t)
            # three rays with one blunder along an epipolar line: any of them could be moved to
            # meet the others, so the non-reference measurements go (the reference pixel is
            # the tie point's definition); with more rays the worst goes, unless it is the reference
            drop = [i for i in t if i != ref] if (len(t) == 3 or worst == ref) else [worst]
            for i in drop:
                removed[k].add(i)
                del t[i]
            r = {}
        final[k] = r
    return removed, bias, final


def sigma_scales(tracks: list[dict[int, np.ndarray]], sigmas: list[dict[int, float]], models: list, heights: tuple[float, float],
                 bias: np.ndarray, sizes: list[tuple[int, int]]) -> np.ndarray:
    """(n_images,) the factor of each image's stated ``sigmas`` that its tracks' 3-D residuals
    ask for (module docstring): tracks ``{image: (line, column)}`` of three or more images (the
    measurements kept), the reference the lowest image, the orientation with its ``bias``
    (:func:`image_bias`). 1 for an image without enough measurements."""
    n = len(models)
    multi = [(t, s) for t, s in zip(tracks, sigmas, strict=True) if len(t) >= 3]
    if not multi:
        return np.ones(n)
    ts = [t for t, _s in multi]
    r0 = residuals(ts, models, heights, bias, sizes, leave_out=True)
    # effect[q][(i, j)]: d residual of i / d measurement of j (2 x 2), j a non-reference member
    effect: list[dict[tuple[int, int], np.ndarray]] = [{} for _ in ts]
    for j in range(n):
        sel = [q for q, t in enumerate(ts) if j in t and j != min(t)]
        for axis in range(2):
            step = np.zeros(2)
            step[axis] = DELTA_PX
            moved = [{**ts[q], j: ts[q][j] + step} for q in sel]
            for q, r1 in zip(sel, residuals(moved, models, heights, bias, sizes, leave_out=True), strict=True):
                for i in ts[q]:
                    if i != j and i in r1 and i in r0[q]:
                        effect[q].setdefault((i, j), np.zeros((2, 2)))[:, axis] = (r1[i] - r0[q][i]) / DELTA_PX
    rows, ys = [], []
    for q, (t, s) in enumerate(multi):
        ref = min(t)
        for i in t:
            r = r0[q].get(i)
            if r is None or not np.all(np.isfinite(r)):
                continue
            for axis in range(2):
                a = np.zeros(n)
                if i != ref:
                    a[i] += s[i] ** 2
                for j in t:
                    g = effect[q].get((i, j))
                    if g is not None:
                        a[j] += s[j] ** 2 * float(np.sum(g[axis] ** 2))
                rows.append(a)
                ys.append(float(r[axis]) ** 2)
    if not rows:
        return np.ones(n)
    a, y = np.array(rows), np.array(ys)
    own = np.array([sum(1 for t, _s in multi if i in t and i != min(t)) for i in range(n)])
    free = np.flatnonzero(own >= CALIBRATION_MIN)
    v = np.ones(n)
    if not len(free):
        return v
    fixed = np.setdiff1d(np.arange(n), free)
    for it in range(CALIBRATION_ITERATIONS):
        pred = np.maximum(a @ v, 1e-12)
        keep = (y <= CALIBRATION_CLIP**2 * pred) if it else np.ones(len(y), dtype=bool)  # the first from every residual
        w = 1.0 / pred[keep]
        target = y[keep] - a[keep][:, fixed] @ v[fixed]
        sol = np.linalg.lstsq(a[keep][:, free] * w[:, None], target * w, rcond=None)[0]
        v[free] = np.maximum(sol, 1e-6)
    return np.sqrt(v)
