"""Pairwise matching of SIFT features inside the band the orientation predicts.

For a pair (a, b), a is cut into the cells of a ``grid`` x ``grid`` layout; in every cell whose
centre lies in the overlap, a window of ``tile_px`` pixels around the centre is read at full
resolution and SIFT features (OpenCV) are detected in it (the strongest ``max_features``), so
the features spread over the whole overlap. Windows are read decimated by ``decimation`` (2 by
default: OpenCV's SIFT doubles its input first, so the finest scale is still the full
resolution's, at a quarter of the cost; positions are refined by correlation later). Each feature's epipolar segment in b (its position
at the lowest and the highest terrain height, :class:`PairMapping`) gives the window of b to
read, and a b feature is a candidate only within ``search_px`` of that segment (the band's
half-width: the orientation's uncertainty, pixels of b). Among candidates:

- ratio test (Lowe): the best descriptor distance below ``ratio`` times the second best;
- mutual consistency: the b feature's best a feature (among those whose band holds it) is the
  same;
- RANSAC (OpenCV ``estimateAffine2D``, fixed seed) of a local affine model a -> b over the
  cell's matches, threshold ``ransac_px``: the terrain is smooth over a tile, a false match
  is not.

Positions are (line, column) in our convention (pixel centres, top-left at (0, 0)).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solver.matching.orientation import MatchImage, PairMapping

MIN_TILE_MATCHES = 5  # fewer matches in a tile cannot be checked by a local affine RANSAC
MIN_TILE_PX = 128
RANSAC_SEED = 12345


@dataclass(frozen=True)
class MatchSettings:
    """How to match (defaults suit 8-16 bit optical images of 1-30 m GSD)."""

    grid: int = 16  # cells per image side: detection tiles and thinning cells
    tile_px: int = 256  # side of the detection window in each cell (pixels of a; at most the cell, at least 128)
    max_features: int = 300  # strongest SIFT features kept per tile of a
    ratio: float = 0.8  # Lowe's ratio test
    search_px: float = 30.0  # half-width of the search band around the epipolar segment (px of b)
    ransac_px: float = 2.0  # RANSAC threshold of the tile's affine model (px of b)
    template_half_px: int = 12  # correlation template: (2 h + 1) pixels square
    min_ncc: float = 0.7  # lowest accepted normalised cross-correlation peak
    per_cell: int = 4  # tie points kept per thinning cell of each image
    max_window_px: int = 2048  # a predicted b window larger than this is skipped (orientation far off)
    decimation: int = 2  # features are detected on windows read decimated by this factor (SIFT doubles them first)


@dataclass
class PairMatches:
    """The accepted SIFT matches of a pair and their counts at each stage."""

    a: int
    b: int
    pa: np.ndarray  # (n, 2) line, column in a
    pb: np.ndarray  # (n, 2) line, column in b
    counts: dict[str, int] = field(default_factory=dict)


def _sift(image8: np.ndarray, n: int):
    import cv2

    # precise upscale: OpenCV's default doubling puts every keypoint 0.25 px (of its input) down
    # and right of the feature; k times that after a read decimated by k
    sift = cv2.SIFT_create(nfeatures=n, enable_precise_upscale=True)
    kps, desc = sift.detectAndCompute(image8, None)
    if desc is None or not kps:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    xy = np.array([k.pt for k in kps], float)  # OpenCV: x = column, y = line, pixel centres at integers
    order = np.lexsort((xy[:, 0], xy[:, 1]))  # deterministic order
    return xy[order][:, ::-1].copy(), desc[order].astype(np.float32)


def _distances(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    d2 = (da * da).sum(1)[:, None] + (db * db).sum(1)[None, :] - 2.0 * da @ db.T
    return np.sqrt(np.maximum(d2, 0.0))


def _ransac(pa: np.ndarray, pb: np.ndarray, threshold: float) -> np.ndarray:
    import cv2

    cv2.setRNGSeed(RANSAC_SEED)
    _m, inliers = cv2.estimateAffine2D(
        pa[:, ::-1].astype(np.float32), pb[:, ::-1].astype(np.float32), method=cv2.RANSAC,
        ransacReprojThreshold=threshold, maxIters=2000, confidence=0.995, refineIters=10,
    )
    if inliers is None:
        return np.zeros(len(pa), dtype=bool)
    return inliers.ravel().astype(bool)


def tile_centres(image: MatchImage, grid: int) -> np.ndarray:
    """(grid^2, 2) centres (line, column) of the image's cells, row by row."""
    lc = (np.arange(grid) + 0.5) * image.lines / grid
    cc = (np.arange(grid) + 0.5) * image.columns / grid
    ll, cc2 = np.meshgrid(lc, cc, indexing="ij")
    return np.column_stack([ll.ravel(), cc2.ravel()])


def _detect(image: MatchImage, row0: int, col0: int, rows: int, cols: int, k: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """SIFT features (full-resolution line, column; descriptors) of a window read decimated by k."""
    values, r0, c0 = image.raster.decimated(row0, col0, rows, cols, k)
    if values.size == 0:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    pos, desc = _sift(image.raster.to_8bit(values), n)
    return pos * k + (r0 + (k - 1) / 2.0, c0 + (k - 1) / 2.0), desc


def _band(kb: np.ndarray, s0: np.ndarray, s1: np.ndarray, search_px: float) -> np.ndarray:
    """(na, nb) mask: b feature j within ``search_px`` of a feature i's epipolar segment. The
    segments of one tile share their direction to well under a degree: the tile's mean
    direction is used for all, which turns the test into outer differences of 1-D arrays."""
    d = (s1 - s0).mean(axis=0)
    length = float(np.hypot(*d))
    u = d / length if length > 1e-9 else np.array([1.0, 0.0])
    cross = lambda p: p[:, 0] * u[1] - p[:, 1] * u[0]  # noqa: E731
    along = np.sum((s1 - s0) * u, axis=1)
    perp = cross(kb)[None, :] - cross(s0)[:, None]
    t = (kb @ u)[None, :] - (s0 @ u)[:, None]
    beyond = np.maximum(np.maximum(-t, t - along[:, None]), 0.0)
    return perp * perp + beyond * beyond <= search_px * search_px


def band_matches(da: np.ndarray, db: np.ndarray, kb: np.ndarray, s0: np.ndarray, s1: np.ndarray, s: MatchSettings, counts: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into a's and b's features) of the matches that pass the band, the ratio test and
    the mutual check (module docstring): descriptors ``da`` (na, 128), ``db`` (nb, 128); b's
    positions ``kb`` (nb, 2); a's epipolar segments ``s0``, ``s1`` (na, 2) in b. Counts the
    candidates (a features with a b feature in their band) and the survivors of each test."""
    dist = np.where(_band(kb, s0, s1, s.search_px), _distances(da, db), np.inf)
    rows = np.arange(len(da))
    best = np.argmin(dist, axis=1)
    d1 = dist[rows, best]
    if dist.shape[1] > 1:
        d2 = np.partition(dist, 1, axis=1)[:, 1]
    else:
        d2 = np.full(len(da), np.inf)
    ok = np.isfinite(d1) & (d1 < s.ratio * d2)
    counts["candidates"] = counts.get("candidates", 0) + int(np.isfinite(d1).sum())
    counts["ratio"] = counts.get("ratio", 0) + int(ok.sum())
    back = np.argmin(dist, axis=0)
    ok &= back[best] == rows
    counts["mutual"] = counts.get("mutual", 0) + int(ok.sum())
    return rows[ok], best[ok]


def match_tile(a: MatchImage, b: MatchImage, mapping: PairMapping, centre: np.ndarray, s: MatchSettings, counts: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """SIFT matches (pa, pb) of one tile of a centred at ``centre`` (module docstring)."""
    cell = min(a.lines, a.columns) / s.grid
    tile = int(min(s.tile_px, max(cell, MIN_TILE_PX)))  # tiles of small images do not overlap much
    half = tile // 2
    k = s.decimation
    empty = (np.zeros((0, 2)), np.zeros((0, 2)))
    ka, da = _detect(a, int(round(centre[0])) - half, int(round(centre[1])) - half, tile, tile, k, s.max_features)
    if not len(ka):
        return empty
    s0, s1 = mapping.segment(ka[:, 0], ka[:, 1])
    good = np.all(np.isfinite(s0), 1) & np.all(np.isfinite(s1), 1)
    ka, da, s0, s1 = ka[good], da[good], s0[good], s1[good]
    if not len(ka):
        return empty
    ends = np.vstack([s0, s1])
    pad = s.search_px + 16 * k
    lo, hi = np.floor(ends.min(0) - pad).astype(int), np.ceil(ends.max(0) + pad).astype(int)
    lo, hi = np.maximum(lo, 0), np.minimum(hi, [b.lines, b.columns])  # segments may run out of b
    if np.any(hi <= lo):
        return empty
    if np.any(hi - lo > s.max_window_px):
        counts["tiles_skipped"] = counts.get("tiles_skipped", 0) + 1
        return empty
    kb, db = _detect(b, lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1], k, 0)
    if not len(kb):
        return empty
    counts["features"] = counts.get("features", 0) + len(ka)
    ia, ib = band_matches(da, db, kb, s0, s1, s, counts)
    pa, pb = ka[ia], kb[ib]
    if len(pa) < MIN_TILE_MATCHES:
        return empty
    keep = _ransac(pa, pb, s.ransac_px * k)
    counts["ransac"] = counts.get("ransac", 0) + int(keep.sum())
    return pa[keep], pb[keep]


def match_pair(a: MatchImage, b: MatchImage, ia: int, ib: int, mapping: PairMapping, s: MatchSettings, progress=None) -> PairMatches:
    """Every tile of a whose centre falls inside b at some height of the range, matched
    (module docstring)."""
    counts: dict[str, int] = {"tiles": 0}
    centres = tile_centres(a, s.grid)
    inside = mapping.reaches_b(centres[:, 0], centres[:, 1])  # at some height of the range
    pas, pbs = [], []
    todo = np.flatnonzero(inside)
    for n, k in enumerate(todo):
        counts["tiles"] += 1
        pa, pb = match_tile(a, b, mapping, centres[k], s, counts)
        pas.append(pa)
        pbs.append(pb)
        if progress is not None:
            progress((n + 1) / len(todo))
    pa = np.vstack(pas) if pas else np.zeros((0, 2))
    pb = np.vstack(pbs) if pbs else np.zeros((0, 2))
    counts["matched"] = len(pa)
    return PairMatches(ia, ib, pa, pb, counts)
