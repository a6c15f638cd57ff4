"""Pairwise matching of SIFT features inside the band the orientation predicts.

Features come from each image's cache (:mod:`solver.matching.keypoints`): detected once per
image window, whichever pairs the image is in. For a pair (a, b), a is cut into tiles over the
cells of a ``grid`` x ``grid`` layout (:func:`tiles`): a cell at least :data:`MIN_TILE_PX`
across is a tile, sampled by a window of ``tile_px`` at its centre; smaller cells are grouped
into tiles of about :data:`MIN_TILE_PX`, read whole. Each cell keeps its own strongest features
(:func:`strongest_per_cell`), so the matches spread over the whole overlap, and the tiles do
not overlap, so a feature is matched once per pair. Each feature's epipolar segment in b (its
position at the lowest and the highest terrain height, :class:`PairMapping`) gives the window of
b whose features are the candidates, and a b feature is a candidate only within ``search_px``
of that segment (the band's half-width: the orientation's uncertainty, pixels of b). Among
candidates:

- ratio test (Lowe): the best descriptor distance below ``ratio`` times the second best; the
  nearest descriptors come from OpenCV's FLANN (randomised KD-trees, :func:`_nearest`) in a tile
  of more than :data:`EXACT_PAIRS` descriptor pairs (its recall against the exact search on the
  real Pleiades crops: 99.4 % and 99.7 %, bench/bench_match_recall.py), from every distance
  below (one BLAS product: as fast as FLANN up to about there);
- mutual consistency: the b feature's best a feature (among those whose band holds it) is the
  same (exact);
- RANSAC (OpenCV ``estimateAffine2D``, fixed seed) of a local affine model a -> b over the
  tile's matches, threshold ``ransac_px``: the terrain is smooth over a tile, a false match
  is not.

Features are detected on reads decimated by ``decimation`` (2 by default: OpenCV's SIFT doubles
its input first, so the finest scale is still the full resolution's, at a quarter of the cost;
positions are refined by correlation later), or at full resolution for small images
(:func:`detection_scale`).

Positions are (line, column) in our convention (pixel centres, top-left at (0, 0)).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solver.matching.keypoints import BLOCK_PX, PREFETCH_TILES, FeatureCache, Features
from solver.matching.orientation import MatchImage, PairMapping

EXACT_PAIRS = 4_000_000  # descriptor distances computed exactly up to this many (na x nb) per tile (16 MB)
KNN = 16  # nearest b descriptors asked of FLANN per a feature
FLANN_TREES = 4  # randomised KD-trees
FLANN_CHECKS = 128  # leaves visited per query
FLANN_SEED = 4242
MIN_TILE_MATCHES = 5  # fewer matches in a tile cannot be checked by a local affine RANSAC
MIN_TILE_PX = 128
SMALL_CELL_PX = 64  # images whose cells are all smaller are detected at full resolution
RANSAC_SEED = 12345
NARROW_MARGIN_PX = 32.0  # a tile's band reaches this far (px of b) beyond the heights its neighbours' matches have
NARROW_MIN_BAND_PX = 128.0  # narrowing pays when the whole range's band is longer than this (px of b)
NARROW_RETRY_MATCHES = 10  # a tile narrowed by its neighbours that finds fewer matches is searched over the whole range


@dataclass(frozen=True)
class MatchSettings:
    """How to match (defaults suit 8-16 bit optical images of 1-30 m GSD)."""

    grid: int = 16  # cells per image side: detection tiles and thinning cells
    tile_px: int = 256  # side of the window sampled in each cell of a (pixels; at most the cell); smaller cells are grouped (tiles)
    max_features: int = 300  # strongest SIFT features of a kept per tile_px window (a small cell: its share of the window's area)
    ratio: float = 0.8  # Lowe's ratio test
    search_px: float = 30.0  # half-width of the search band around the epipolar segment (px of b)
    ransac_px: float = 2.0  # RANSAC threshold of the tile's affine model (px of b)
    template_half_px: int = 12  # correlation template: (2 h + 1) pixels square
    min_ncc: float = 0.7  # lowest accepted normalised cross-correlation peak
    per_cell: int = 4  # tie points kept per thinning cell of each image
    max_window_px: int = 2048  # a predicted b window larger than this is skipped (orientation far off)
    decimation: int = 2  # features are detected on windows read decimated by this factor (SIFT doubles them first; 1 for small images: detection_scale)


@dataclass
class PairMatches:
    """The accepted SIFT matches of a pair and their counts at each stage."""

    a: int
    b: int
    pa: np.ndarray  # (n, 2) line, column in a
    pb: np.ndarray  # (n, 2) line, column in b
    counts: dict[str, int] = field(default_factory=dict)


def detection_scale(images: list[MatchImage], s: MatchSettings) -> MatchSettings:
    """``s`` with the decimation the images are detected at: full resolution (1) when every
    image's cells are under :data:`SMALL_CELL_PX` across, where a decimated read leaves too few
    features to fill the cells (the real 400 px Pleiades crops of the tests: 186 SIFT features
    at decimation 2 against 1,797 at full resolution, for 256 cells) and detecting them whole
    costs little."""
    from dataclasses import replace

    if s.decimation > 1 and all(min(im.lines, im.columns) / s.grid < SMALL_CELL_PX for im in images):
        return replace(s, decimation=1)
    return s


def _distances(da: np.ndarray, db: np.ndarray) -> np.ndarray:
    """(na, nb) Euclidean distances between descriptors."""
    da, db = da.astype(np.float32), db.astype(np.float32)
    d2 = (da * da).sum(1)[:, None] + (db * db).sum(1)[None, :] - 2.0 * da @ db.T
    return np.sqrt(np.maximum(d2, 0.0))


def _nearest(da: np.ndarray, db: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(na, k) indices into db and distances of each a descriptor's k nearest b descriptors,
    nearest first, approximately: OpenCV's FLANN, randomised KD-trees built with a fixed seed."""
    import cv2

    cv2.setRNGSeed(FLANN_SEED)  # the trees' random splits: the same result every run
    index = cv2.flann_Index(db.astype(np.float32), {"algorithm": 1, "trees": FLANN_TREES})  # 1: KD-tree forest
    idx, d2 = index.knnSearch(da.astype(np.float32), k, params={"checks": FLANN_CHECKS})
    return idx.astype(np.int64), np.sqrt(np.maximum(d2.astype(np.float64), 0.0))


def _two_nearest_in_band(da: np.ndarray, db: np.ndarray, kb: np.ndarray, band: "_Band", rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exactly, for a features ``rows``: the nearest b feature in the band (-1: none), its
    descriptor distance and the second nearest's (inf: none)."""
    dist = np.where(band.outer(rows, kb), _distances(da[rows], db), np.inf)
    best = np.argmin(dist, axis=1)
    d1 = dist[np.arange(len(rows)), best]
    d2 = np.partition(dist, 1, axis=1)[:, 1] if dist.shape[1] > 1 else np.full(len(rows), np.inf)
    return np.where(np.isfinite(d1), best, -1), d1, d2


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


class _Band:
    """The band test of one tile (module docstring): a b position within ``search_px`` of an a
    feature's epipolar segment. The segments of one tile share their direction to well under a
    degree: the tile's mean direction is used for all, which reduces the test to differences of
    coordinates along and across it."""

    def __init__(self, s0: np.ndarray, s1: np.ndarray, search_px: float):
        d = (s1 - s0).mean(axis=0) if len(s0) else np.zeros(2)
        length = float(np.hypot(*d))
        self.u = d / length if length > 1e-9 else np.array([1.0, 0.0])
        self.perp0 = self._cross(s0)
        self.t0 = s0 @ self.u
        self.along = np.sum((s1 - s0) * self.u, axis=1)
        self.r2 = search_px * search_px

    def _cross(self, p: np.ndarray) -> np.ndarray:
        return p[..., 0] * self.u[1] - p[..., 1] * self.u[0]

    def holds(self, rows: np.ndarray, kb: np.ndarray) -> np.ndarray:
        """Whether b positions ``kb`` (..., 2) lie in the bands of a features ``rows`` (...)."""
        perp = self._cross(kb) - self.perp0[rows]
        t = kb @ self.u - self.t0[rows]
        beyond = np.maximum(np.maximum(-t, t - self.along[rows]), 0.0)
        return perp * perp + beyond * beyond <= self.r2

    def outer(self, rows: np.ndarray, kb: np.ndarray) -> np.ndarray:
        """(len(rows), nb) band mask of a features ``rows`` against every b position."""
        return self.holds(rows[:, None], kb[None, :, :])


def band_matches(da: np.ndarray, db: np.ndarray, kb: np.ndarray, s0: np.ndarray, s1: np.ndarray, s: MatchSettings, counts: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into a's and b's features) of the matches that pass the band, the ratio test and
    the mutual check (module docstring): descriptors ``da`` (na, 128), ``db`` (nb, 128); b's
    positions ``kb`` (nb, 2); a's epipolar segments ``s0``, ``s1`` (na, 2) in b. Counts the
    candidates (a features with a b feature in their band) and the survivors of each test.

    The two nearest candidates of an a feature are found exactly (every distance) in a tile of
    at most :data:`EXACT_PAIRS` distances. In a larger tile they are the first two in the band
    among the feature's :data:`KNN` nearest b descriptors (FLANN, :func:`_nearest`); when fewer
    than two are there and the test cannot be decided from the last of them (a bound on the
    second's distance), the feature's band is searched exactly."""
    na, nb = len(da), len(db)
    if not na or not nb:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    band = _Band(s0, s1, s.search_px)
    rows = np.arange(na)
    if na * nb <= EXACT_PAIRS:
        best, d1, d2 = _two_nearest_in_band(da, db, kb, band, rows)
    else:
        k = min(KNN, nb)
        idx, dist = _nearest(da, db, k)
        rank = np.cumsum(band.holds(rows[:, None], kb[idx]), axis=1)
        has1, has2 = rank[:, -1] >= 1, rank[:, -1] >= 2
        j1, j2 = np.argmax(rank >= 1, axis=1), np.argmax(rank >= 2, axis=1)
        best = np.where(has1, idx[rows, j1], -1)
        d1 = np.where(has1, dist[rows, j1], np.inf)
        d2 = np.where(has2, dist[rows, j2], np.inf)
        if k < nb:  # b features beyond the k nearest are further than the k-th
            d2 = np.where(has1 & ~has2, dist[:, -1], d2)
            todo = np.flatnonzero(~has1 | (has1 & ~has2 & ~(d1 < s.ratio * d2)))
            if len(todo):
                best[todo], d1[todo], d2[todo] = _two_nearest_in_band(da, db, kb, band, todo)
    ok = np.isfinite(d1) & (d1 < s.ratio * d2)
    counts["candidates"] = counts.get("candidates", 0) + int(np.isfinite(d1).sum())
    counts["ratio"] = counts.get("ratio", 0) + int(ok.sum())
    # mutual: each wanted b feature's best a feature among those whose band holds it (exact)
    wanted = np.unique(best[best >= 0])
    if len(wanted):
        back_d = np.where(band.outer(rows, kb[wanted]), _distances(da, db[wanted]), np.inf)
        back = np.full(nb, -1)
        back[wanted] = np.argmin(back_d, axis=0)
        ok &= back[np.maximum(best, 0)] == rows
    counts["mutual"] = counts.get("mutual", 0) + int(ok.sum())
    return rows[ok], best[ok]


def match_tile(a: MatchImage, b: MatchImage, fa: Features, fb_cache: FeatureCache, mapping: PairMapping, s: MatchSettings, counts: dict[str, int],
               heights: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """SIFT matches (pa, pb) of one tile's a features ``fa`` against b's features in the
    window their epipolar segments span (module docstring); the segments over ``heights``
    (ellipsoidal m: the tile's own range, :class:`TileHeights`), by default the mapping's."""
    empty = (np.zeros((0, 2)), np.zeros((0, 2)))
    if heights is None:
        s0, s1 = mapping.segment(fa.pos[:, 0], fa.pos[:, 1])
    else:
        s0, s1 = (mapping.at_height(fa.pos[:, 0], fa.pos[:, 1], h) for h in heights)
    good = np.all(np.isfinite(s0), 1) & np.all(np.isfinite(s1), 1)
    fa, s0, s1 = fa.take(np.flatnonzero(good)), s0[good], s1[good]
    if not len(fa):
        return empty
    ends = np.vstack([s0, s1])
    lo = np.maximum(np.floor(ends.min(0) - s.search_px), 0).astype(int)
    hi = np.minimum(np.ceil(ends.max(0) + s.search_px + 1), [b.lines, b.columns]).astype(int)  # segments may run out of b
    if np.any(hi <= lo):
        return empty
    if np.any(hi - lo > s.max_window_px):
        counts["tiles_skipped"] = counts.get("tiles_skipped", 0) + 1
        return empty
    fb = fb_cache.window(lo, hi)
    if not len(fb):
        return empty
    counts["features"] = counts.get("features", 0) + len(fa)
    ia, ib = band_matches(fa.desc, fb.desc, fb.pos, s0, s1, s, counts)
    pa, pb = fa.pos[ia], fb.pos[ib]
    if len(pa) < MIN_TILE_MATCHES:
        return empty
    keep = _ransac(pa, pb, s.ransac_px * s.decimation)
    counts["ransac"] = counts.get("ransac", 0) + int(keep.sum())
    return pa[keep], pb[keep]


@dataclass(frozen=True)
class Tile:
    """A tile of a: the window its features come from (full-resolution [lo, hi)), and the
    thinning cells (row, column of the grid) it holds."""

    lo: np.ndarray
    hi: np.ndarray
    cells: tuple[tuple[int, int], ...]


def tiles(image: MatchImage, s: MatchSettings) -> tuple[list[Tile], int]:
    """The match tiles of an image and the number of features kept per cell (the strongest).

    Cells at least :data:`MIN_TILE_PX` across are a tile each, detected in a window of
    ``tile_px`` at the cell's centre (a sample of large images) and keeping ``max_features``.
    Smaller cells are grouped, m x m, into tiles at least :data:`MIN_TILE_PX` across (enough
    matches for the tile's RANSAC), detected whole, each cell keeping its share of
    ``max_features`` per ``tile_px`` window (the same density): the tiles do not overlap and
    every cell has its own strongest features, so the matches spread over the whole overlap."""
    g = s.grid
    le = np.linspace(0.0, image.lines, g + 1)
    ce = np.linspace(0.0, image.columns, g + 1)
    cell = min(image.lines, image.columns) / g
    out = []
    if cell >= MIN_TILE_PX:
        side = min(float(s.tile_px), cell)
        for i in range(g):
            for j in range(g):
                centre = np.array([(le[i] + le[i + 1]) / 2.0, (ce[j] + ce[j + 1]) / 2.0])
                lo = np.round((centre - side / 2.0) / BLOCK_PX) * BLOCK_PX  # on the detection blocks: no block detected for a sliver
                lo = np.clip(lo, [le[i], ce[j]], [le[i + 1] - side, ce[j + 1] - side]).round()
                out.append(Tile(lo, lo + round(side), ((i, j),)))
        return out, s.max_features
    m = int(np.ceil(MIN_TILE_PX / cell))
    for i in range(0, g, m):
        for j in range(0, g, m):
            i1, j1 = min(i + m, g), min(j + m, g)
            cells = tuple((r, c) for r in range(i, i1) for c in range(j, j1))
            out.append(Tile(np.floor([le[i], ce[j]]), np.floor([le[i1], ce[j1]]), cells))
    tile = min(float(s.tile_px), MIN_TILE_PX)
    per_cell = int(np.ceil(s.max_features * (image.lines / g) * (image.columns / g) / tile**2))
    return out, per_cell


def strongest_per_cell(f: Features, lines: int, columns: int, grid: int, n: int) -> Features:
    """The ``n`` strongest features (SIFT response) of each thinning cell, in their order."""
    if not len(f):
        return f
    cell = (np.clip((f.pos[:, 0] * grid / lines).astype(int), 0, grid - 1) * grid
            + np.clip((f.pos[:, 1] * grid / columns).astype(int), 0, grid - 1))
    order = np.lexsort((-f.response, cell))
    first = np.searchsorted(cell[order], cell[order], side="left")
    keep = order[np.arange(len(order)) - first < n]
    return f.take(np.sort(keep))


class TileHeights:
    """The height range (ellipsoidal m) each tile of a pair's image a is searched over: a
    shorter range is a shorter band in b, so fewer b features to detect and to compare.

    - With a DEM (``terrain``, :class:`solver.matching.heights.DemHeights`): the DEM's heights
      under the tile (+- its margin).
    - Without, coarse to fine over the tiles in raster order: the heights of the matches found
      in the tile's matched neighbours (left, above left, above, above right), widened each side
      by :data:`NARROW_MARGIN_PX` of b's band and a quarter of their spread. A tile with no
      matched neighbour is searched over the whole range, and so is one whose narrowed band
      found fewer than :data:`NARROW_RETRY_MATCHES` matches (searched again: :meth:`retry`).

    The neighbours narrow only a layout of sampled tiles (cells of at least :data:`MIN_TILE_PX`)
    whose band over the whole range is longer than :data:`NARROW_MIN_BAND_PX` (smaller images
    are detected whole anyway); elsewhere :meth:`of` gives None (the whole range)."""

    def __init__(self, a: MatchImage, mapping: PairMapping, s: MatchSettings, terrain=None):
        self.a, self.terrain, self.grid = a, terrain, s.grid
        self.full = (float(mapping.heights[0]), float(mapping.heights[-1]))
        length = np.hypot(mapping.bl[-1] - mapping.bl[0], mapping.bc[-1] - mapping.bc[0])
        band = float(np.nanmedian(length)) if np.isfinite(length).any() else 0.0
        sampled = min(a.lines, a.columns) / s.grid >= MIN_TILE_PX
        self.on = sampled and band > NARROW_MIN_BAND_PX
        self.margin_m = NARROW_MARGIN_PX * (self.full[1] - self.full[0]) / max(band, 1e-9)
        self.found: dict[tuple[int, int], tuple[float, float]] = {}

    def of(self, n: int, tile: "Tile") -> tuple[float, float] | None:
        """The range of tile ``n`` of the layout (None: the whole range)."""
        if self.terrain is not None:
            got = self.terrain(self.a, tile.lo, tile.hi)
            return None if got is None else (max(got[0], self.full[0]), min(got[1], self.full[1]))
        if not self.on:
            return None
        i, j = divmod(n, self.grid)
        near = [self.found[k] for k in ((i, j - 1), (i - 1, j - 1), (i - 1, j), (i - 1, j + 1)) if k in self.found]
        if not near:
            return None
        lo, hi = min(r[0] for r in near), max(r[1] for r in near)
        m = max(self.margin_m, 0.25 * (hi - lo))
        return max(lo - m, self.full[0]), min(hi + m, self.full[1])

    def retry(self, matched: int) -> bool:
        """Whether a tile narrowed by its neighbours is searched again over the whole range."""
        return self.terrain is None and matched < NARROW_RETRY_MATCHES

    def found_at(self, n: int, heights: np.ndarray) -> None:
        """Record the heights of tile ``n``'s matches (m)."""
        h = heights[np.isfinite(heights)]
        if self.on and len(h) >= NARROW_RETRY_MATCHES:
            self.found[divmod(n, self.grid)] = (float(h.min()), float(h.max()))


def match_pair(a: MatchImage, b: MatchImage, ia: int, ib: int, mapping: PairMapping, s: MatchSettings,
               fa_cache: FeatureCache, fb_cache: FeatureCache, progress=None, terrain=None) -> PairMatches:
    """Every tile of a that falls inside b at some height of the range, matched (module
    docstring) over the tile's height range (:class:`TileHeights`; ``terrain``: a DEM's); the
    features come from the images' caches (detected once per image)."""
    counts: dict[str, int] = {"tiles": 0}
    layout, per_cell = tiles(a, s)
    ranges = TileHeights(a, mapping, s, terrain)
    corners = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 1.0], [0.5, 0.5]])
    reached = []
    for t in layout:
        probe = t.lo + corners * (t.hi - 1 - t.lo)
        reached.append(bool(mapping.reaches_b(probe[:, 0], probe[:, 1]).any()))  # at some height of the range
    ahead = iter([t for t, r in zip(layout, reached, strict=True) if r])
    fb_cache.prefetch_whole()  # a small b: detected whole beside a
    pas, pbs = [], []
    for n, t in enumerate(layout):
        if reached[n]:
            for _ in range(PREFETCH_TILES - len(fa_cache.pending)):  # a's next tiles detected ahead (none without a pool)
                nxt = next(ahead, None)
                if nxt is not None:
                    fa_cache.prefetch(nxt.lo, nxt.hi)
            counts["tiles"] += 1
            fa = fa_cache.window(t.lo, t.hi)
            fa = fa.take(np.flatnonzero(mapping.reaches_b(fa.pos[:, 0], fa.pos[:, 1])))
            fa = strongest_per_cell(fa, a.lines, a.columns, s.grid, per_cell)
            if len(fa):
                heights = ranges.of(n, t)
                tried: dict[str, int] = {}
                pa, pb = match_tile(a, b, fa, fb_cache, mapping, s, tried, heights)
                if heights is not None and ranges.retry(len(pa)):
                    counts["tiles_widened"] = counts.get("tiles_widened", 0) + 1
                    tried = {}
                    pa, pb = match_tile(a, b, fa, fb_cache, mapping, s, tried)
                elif heights is not None:
                    counts["tiles_narrowed"] = counts.get("tiles_narrowed", 0) + 1
                for key, v in tried.items():
                    counts[key] = counts.get(key, 0) + v
                if len(pa):
                    ranges.found_at(n, mapping.height_of(pa, pb))
                pas.append(pa)
                pbs.append(pb)
        if progress is not None:
            progress((n + 1) / len(layout))
    fa_cache.drop_pending()  # (a's tiles went otherwise than announced: detections not used)
    pa = np.vstack(pas) if pas else np.zeros((0, 2))
    pb = np.vstack(pbs) if pbs else np.zeros((0, 2))
    counts["matched"] = len(pa)
    return PairMatches(ia, ib, pa, pb, counts)
