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

The computation (:class:`_Block`): the tracks are flattened once into one entry per measurement
and every track's point is solved at once. A ray depends only on its measurement and its image's
bias, so each image's rays are kept until its bias changes (the bias is estimated one image at a
time), and a measurement's effect is found with only its own image's rays computed again at the
moved positions (the other rays reused) and only the other members of its tracks projected.
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


class _Block:
    """Tracks ``{image: (line, column)}`` flattened to one entry per measurement (track by
    track, a track's images in ascending order): ``track``, ``image``, ``pos`` (n, 2) and, when
    given, the stated ``sigma``. The rays of an image depend only on its measurements and its
    bias: :meth:`rays` keeps each image's and computes them again only when its bias changed."""

    def __init__(self, tracks: list[dict[int, np.ndarray]], models: list, heights: tuple[float, float], sizes,
                 sigmas: list[dict[int, float]] | None = None):
        self.models, self.sizes = models, sizes
        self.span = (heights[0] - 100.0, heights[1] + 100.0)
        self.n_tracks = len(tracks)
        counts = [len(t) for t in tracks]
        images = [sorted(t) for t in tracks]
        self.track = np.repeat(np.arange(len(tracks)), counts)
        self.image = np.array([i for im in images for i in im], dtype=int)
        self.pos = np.array([t[i] for t, im in zip(tracks, images, strict=True) for i in im], float).reshape(-1, 2)
        if sigmas is not None:
            self.sigma = np.array([s[i] for s, im in zip(sigmas, images, strict=True) for i in im], float)
        self.size = np.asarray(counts, dtype=int)
        self.first = np.cumsum(self.size) - self.size  # a track's first entry: its reference (the lowest image)
        self.rows = {int(i): np.flatnonzero(self.image == i) for i in np.unique(self.image)}
        self._cache: dict[int, tuple[bytes, np.ndarray, np.ndarray]] = {}

    def corrected(self, bias: np.ndarray, i: int, rows: np.ndarray, pos: np.ndarray | None = None) -> np.ndarray:
        """Image ``i``'s measurements (or ``pos``) at ``rows``, its bias removed."""
        p = self.pos[rows] if pos is None else pos
        return p - apply_bias(bias, i, p, self.sizes[i])

    def image_rays(self, bias: np.ndarray, i: int, rows: np.ndarray, pos: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The rays of image ``i``'s entries ``rows`` (at ``pos`` instead of their measurements if given)."""
        return _rays(self.models[i], self.corrected(bias, i, rows, pos), self.span)

    def rays(self, bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(origins, directions) (n, 3) of every entry's ray, the bias removed."""
        o, d = np.empty((len(self.image), 3)), np.empty((len(self.image), 3))
        for i, rows in self.rows.items():
            key = bias[i].tobytes()
            if i not in self._cache or self._cache[i][0] != key:
                self._cache[i] = (key, *self.image_rays(bias, i, rows))
            o[rows], d[rows] = self._cache[i][1], self._cache[i][2]
        return o, d

    def points(self, o: np.ndarray, d: np.ndarray, leave_out: bool, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The intersected point (n, 3) of each entry's track (``leave_out``: without the entry's
        own ray, tracks of three or more images only) and the entries it is for; NaN where a ray
        (another's, with ``leave_out``) failed. Only at ``rows`` (entry indices) if given.

        A track's point is the one nearest to its rays (origins o, unit directions d) in the least-
        squares sense: sum (I - d d^T) x = sum (I - d d^T) o. The sums of every track at once (a
        left-out ray's share taken off again), solved as one stack of 3 x 3 systems."""
        n = len(self.image)
        bad = ~(np.all(np.isfinite(o), axis=1) & np.all(np.isfinite(d), axis=1))
        o, d = np.where(bad[:, None], 0.0, o), np.where(bad[:, None], 0.0, d)
        proj = np.eye(3) - d[:, :, None] * d[:, None, :]  # I - d d^T
        proj[bad] = 0.0
        rhs = np.einsum("nij,nj->ni", proj, o)
        a = np.stack([np.bincount(self.track, weights=c, minlength=self.n_tracks) for c in proj.reshape(n, 9).T], axis=1).reshape(-1, 3, 3)
        b = np.stack([np.bincount(self.track, weights=c, minlength=self.n_tracks) for c in rhs.T], axis=1)
        n_bad = np.bincount(self.track, weights=bad, minlength=self.n_tracks)
        e = np.arange(n) if rows is None else rows
        k = self.track[e]
        if leave_out:
            use = self.size[k] >= 3
            a_e, b_e = a[k] - proj[e], b[k] - rhs[e]
            ok = use & (n_bad[k] - bad[e] == 0)
        else:
            use = np.ones(len(e), dtype=bool)
            a_e, b_e = a[k], b[k]
            ok = n_bad[k] == 0
        xyz = np.full((len(e), 3), np.nan)
        if ok.any():
            xyz[ok] = np.linalg.solve(a_e[ok], b_e[ok][:, :, None])[:, :, 0]
        return xyz, use

    def residuals(self, bias: np.ndarray, leave_out: bool, rays: tuple[np.ndarray, np.ndarray] | None = None,
                  rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(residuals (m, 2), used (m,)) of the entries (all, or ``rows``): measured - bias -
        projected, the point from ``rays`` (default :meth:`rays`); NaN where not used (``leave_out``
        in a track of fewer than three images) or a ray or projection failed."""
        o, d = self.rays(bias) if rays is None else rays
        e = np.arange(len(self.image)) if rows is None else np.asarray(rows)
        xyz, use = self.points(o, d, leave_out, e)
        out = np.full((len(e), 2), np.nan)
        image = self.image[e]
        for i in np.unique(image[use]):
            sel = np.flatnonzero(use & (image == i))
            with np.errstate(all="ignore"):
                line, col, _chip = self.models[i].ground_to_image(xyz[sel])
            pred = np.column_stack([np.asarray(line, float).ravel(), np.asarray(col, float).ravel()])
            out[sel] = self.corrected(bias, int(i), e[sel]) - pred
        return out, use

    def as_dicts(self, res: np.ndarray, use: np.ndarray) -> list[dict[int, np.ndarray]]:
        """Per track ``{image: residual}`` of the entries used."""
        out: list[dict[int, np.ndarray]] = [{} for _ in range(self.n_tracks)]
        track, image = self.track.tolist(), self.image.tolist()
        for e in np.flatnonzero(use).tolist():
            out[track[e]][image[e]] = res[e]
        return out


def residuals(tracks: list[dict[int, np.ndarray]], models: list, heights: tuple[float, float], bias: np.ndarray,
              sizes: list[tuple[int, int]], leave_out: bool = False) -> list[dict[int, np.ndarray]]:
    """Per track ``{image: measured - bias - projected (line, column)}`` (module docstring),
    the point intersected from all the track's rays, or (``leave_out``, tracks of three or
    more images) from the other images' rays only; NaN where a ray or a projection fails
    (:meth:`_Block.points`)."""
    block = _Block(tracks, models, heights, sizes)
    if not len(block.image):
        return [{} for _ in tracks]
    return block.as_dicts(*block.residuals(bias, leave_out))


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
    return _image_bias(_Block([t for t in tracks if len(t) >= 3], models, heights, sizes))


def _image_bias(block: _Block) -> np.ndarray:
    """:func:`image_bias` of the tracks of three or more images ``block``; an image's rays are
    computed again only when its bias has changed."""
    sizes = block.sizes
    bias = np.zeros((len(block.models), 3, 2))
    for _ in range(BIAS_ITERATIONS):
        largest = 0.0
        for i in range(1, len(block.models)):  # one image at a time (all at once overshoots)
            rows = block.rows.get(i, np.zeros(0, dtype=int))
            if len(rows) < 3:
                continue
            r, _use = block.residuals(bias, leave_out=True, rows=rows)
            fine = np.all(np.isfinite(r), axis=1)
            if fine.sum() < 3:
                continue
            pos = block.pos[rows[fine]]
            step = _robust_affine(_design(pos, sizes[i]), r[fine])
            bias[i] += step
            largest = max(largest, float(np.max(np.abs(_design(pos, sizes[i]) @ step))))
        if largest < 0.01:
            break
    return bias


def _outliers(block: _Block, res: np.ndarray, use: np.ndarray) -> np.ndarray:
    """The tracks with a measurement whose residual is near or beyond its limit (module
    docstring), to be judged one by one; a margin of 1e-9 of the limit covers the order of the
    sums."""
    total = np.bincount(block.track, weights=block.sigma**2, minlength=block.n_tracks)
    limit = np.maximum(OUTLIER_SIGMAS * np.sqrt(total), OUTLIER_FLOOR_PX)[block.track]
    fine = np.all(np.isfinite(res), axis=1)
    with np.errstate(invalid="ignore"):
        e = np.where(fine, np.hypot(res[:, 0], res[:, 1]), np.inf)
    near = use & (e > (1.0 - 1e-9) * limit)
    return np.unique(block.track[near])


def verify(tracks: list[dict[int, np.ndarray]], sigmas: list[dict[int, float]], models: list, heights: tuple[float, float],
           sizes: list[tuple[int, int]]) -> tuple[list[set[int]], np.ndarray, list[dict[int, np.ndarray]]]:
    """The measurements to remove (per track, the images), the per-image bias and the final
    residuals (against the point the other images give) of tracks ``{image: (line, column)}``
    with stated ``sigmas`` ``{image: px}``, the reference the lowest image (module docstring)."""
    multi = [k for k, t in enumerate(tracks) if len(t) >= 3]  # the others have no residuals
    block = _Block([tracks[k] for k in multi], models, heights, sizes, [sigmas[k] for k in multi])
    bias = _image_bias(block)  # the same rays as the residuals below
    removed: list[set[int]] = [set() for _ in tracks]
    final: list[dict[int, np.ndarray]] = [{} for _ in tracks]
    if not multi:
        return removed, bias, final
    res, use = block.residuals(bias, leave_out=True)  # all tracks at once
    for k, r in zip(multi, block.as_dicts(res, use), strict=True):
        final[k] = r
    for q in _outliers(block, res, use).tolist():  # the others pass as they are
        k = multi[q]
        t = dict(tracks[k])
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


def _calibration_design(block: _Block, bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows of :func:`sigma_scales`' least squares, two per measurement with a finite
    residual (line, column): the coefficients of each image's squared factor in the residual's
    predicted variance (n_rows, n_images) and the squared residual (n_rows,).

    The effect of measurement j on the residual of i (another member of its track) is the
    change of i's residual when j is moved by :data:`DELTA_PX` along each axis, over
    :data:`DELTA_PX`: only j's rays are computed again (every other ray as it was), and only the
    other members of j's tracks are projected again."""
    n_images = len(block.models)
    o, d = block.rays(bias)
    r0, _use = block.residuals(bias, leave_out=True, rays=(o, d))
    is_ref = np.zeros(len(block.image), dtype=bool)
    is_ref[block.first] = True
    gsq = np.zeros((len(block.image), n_images, 2))  # sum over j's two moves of (d residual of the entry / d move)^2
    for j, rows_j in block.rows.items():
        moved = rows_j[~is_ref[rows_j]]
        if not len(moved):
            continue
        in_moved = np.zeros(block.n_tracks, dtype=bool)
        in_moved[block.track[moved]] = True
        targets = np.flatnonzero(in_moved[block.track] & (block.image != j))
        for axis in range(2):
            step = np.zeros(2)
            step[axis] = DELTA_PX
            o1, d1 = o.copy(), d.copy()
            o1[moved], d1[moved] = block.image_rays(bias, j, moved, block.pos[moved] + step)
            r1, _u = block.residuals(bias, leave_out=True, rays=(o1, d1), rows=targets)
            gsq[targets, j] += ((r1 - r0[targets]) / DELTA_PX) ** 2
    s2 = np.zeros((block.n_tracks, n_images))
    s2[block.track, block.image] = block.sigma**2
    fine = np.flatnonzero(np.all(np.isfinite(r0), axis=1))
    a = s2[block.track[fine]][:, None, :] * np.transpose(gsq[fine], (0, 2, 1))  # (m, axis, image)
    own = np.flatnonzero(~is_ref[fine])
    a[own, :, block.image[fine[own]]] += block.sigma[fine[own], None] ** 2
    return a.reshape(-1, n_images), (r0[fine] ** 2).reshape(-1)


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
    block = _Block([t for t, _s in multi], models, heights, sizes, [s for _t, s in multi])
    a, y = _calibration_design(block, bias)
    if not len(y):
        return np.ones(n)
    is_ref = np.zeros(len(block.image), dtype=bool)
    is_ref[block.first] = True
    own = np.bincount(block.image[~is_ref], minlength=n)
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
