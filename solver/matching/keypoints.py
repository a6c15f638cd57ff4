"""SIFT features of an image, detected once and reused by every pair the image is in.

An image is cut into square blocks of :data:`BLOCK_PX` pixels (a multiple of the decimation);
a block's features are detected the first time a window that touches it is asked for, on a
read decimated by ``decimation`` (:meth:`solver.matching.raster.Raster.decimated`: OpenCV's
SIFT doubles its input first, so the finest scale is still the full resolution's, at a quarter
of the cost) that takes the missing blocks' bounding box plus :data:`MARGIN_PX` of context, and
kept with the block. So a window of the image is detected once, whichever pair asks for it and
in whatever role; large images are detected only where a pair needs them. In the image's last
pair only the blocks of the last few rows of tiles are kept (:meth:`FeatureCache.keep_recent`).

A small image (one :class:`solver.matching.raster.Raster` holds whole: at most
:data:`solver.matching.raster.WHOLE_MAX_PX` pixels) is detected in strips of :data:`STRIP_BLOCKS`
rows of blocks across its whole width (with :data:`MARGIN_PX` of context), each at the first
window that needs one of its blocks, and its features kept until the image's last pair is done:
a few calls instead of hundreds of margined rectangles, with the margins above and below a strip
only. (One call over the whole image is cheaper still, but SIFT's scale space of a whole image is
about 55 MB per 1,024 px image while it runs: the strips keep the memory of before.)

Detection on more than one core (``PBA_MATCH_THREADS``, :func:`match_threads`): a cache given a
thread pool detects windows announced ahead (:meth:`FeatureCache.prefetch`: the a tiles of a
pair a few tiles ahead, a small image's strips) in the pool's thread while the main thread detects
and matches the others. Inside a SIFT call OpenCV's own threads (as many, set by
:func:`solver.matching.pipeline.match_images`) share the scale space, the extrema and the
descriptors; a call made while they are busy runs in its caller's thread alone; each feature is
computed on its own, so the features do not depend on them. A prefetched detection is used only
for exactly the rectangle the sequential path would detect at that point (the same read, so the
same features); any other is detected by the main thread. The result is the same as with one
thread, whatever the timing.

A detection reads :data:`MARGIN_PX` of context around its blocks (so that a block's features
do not depend on which rectangle detected it); the context's own features are dropped before
their descriptors are computed (a mask: :func:`sift`).

Positions are (line, column) in our convention (pixel centres, top-left at (0, 0)), full
resolution; descriptors are OpenCV's (128 values from 0 to 255, stored as uint8); the response
is SIFT's (the strength of the extremum, for choosing the strongest features of a cell).
"""

from __future__ import annotations

import os
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from solver.matching.orientation import MatchImage

BLOCK_PX = 32  # side of a detection block (full-resolution pixels, a multiple of the decimation)
MARGIN_PX = 32  # context read around the blocks being detected (full-resolution pixels)
THREADS_ENV = "PBA_MATCH_THREADS"  # threads detecting SIFT features (default: 2, or the cores available if fewer)
DEFAULT_THREADS = 2
PREFETCH_TILES = 4  # a tiles of a pair detected ahead in the pool's thread (bounds the features held ahead)
STRIP_BLOCKS = 4  # rows of blocks a small image's strips hold (128 px: SIFT's scale space of a 1,024 px strip is about 10 MB)


def match_threads() -> int:
    """Threads detecting features: ``PBA_MATCH_THREADS``, by default :data:`DEFAULT_THREADS` or
    the cores this process may use if fewer; 1 detects everything in the main thread."""
    value = os.environ.get(THREADS_ENV, "").strip()
    if value:
        try:
            n = int(value)
        except ValueError:
            n = 0
        if n < 1:
            raise ValueError(f"{THREADS_ENV}={value!r}: expected a positive integer")
        return n
    from solver.engine.native import available_cores

    return min(DEFAULT_THREADS, available_cores())


@contextmanager
def detection_pool(threads: int) -> Iterator[Executor | None]:
    """The pool of ``threads - 1`` threads that detect ahead of the main thread (None for one
    thread: everything detected in the main thread); waits for its detections at the end."""
    if threads <= 1:
        yield None
        return
    pool = ThreadPoolExecutor(max_workers=threads - 1, thread_name_prefix="pba-detect")
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


@dataclass
class Features:
    """Features of a window: positions (n, 2) line, column; descriptors (n, 128) uint8;
    responses (n,)."""

    pos: np.ndarray
    desc: np.ndarray
    response: np.ndarray

    @classmethod
    def empty(cls) -> "Features":
        return cls(np.zeros((0, 2)), np.zeros((0, 128), np.uint8), np.zeros(0, np.float32))

    def __len__(self) -> int:
        return len(self.pos)

    def take(self, idx: np.ndarray) -> "Features":
        return Features(self.pos[idx], self.desc[idx], self.response[idx])

    @classmethod
    def concat(cls, parts: list["Features"]) -> "Features":
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        return cls(np.vstack([p.pos for p in parts]), np.vstack([p.desc for p in parts]), np.concatenate([p.response for p in parts]))


def sift(image8: np.ndarray, n: int = 0, mask: np.ndarray | None = None) -> Features:
    """SIFT features of an 8-bit array (array coordinates: line, column of pixel centres), the
    strongest ``n`` (all for 0), in a deterministic order; with ``mask`` (uint8, the array's
    shape) only those whose nearest pixel is non-zero in it. The mask does not change the
    features it keeps: OpenCV detects on the whole array and drops the others before computing
    descriptors (about half of a call's cost), so the context around a window costs no
    descriptors."""
    import cv2

    # precise upscale: OpenCV's default doubling puts every keypoint 0.25 px (of its input) down
    # and right of the feature; k times that after a read decimated by k
    detector = cv2.SIFT_create(nfeatures=n, enable_precise_upscale=True)
    kps, desc = detector.detectAndCompute(image8, mask)
    if desc is None or not kps:
        return Features.empty()
    xy = np.array([k.pt for k in kps], float)  # OpenCV: x = column, y = line, pixel centres at integers
    response = np.array([k.response for k in kps], np.float32)
    order = np.lexsort((xy[:, 0], xy[:, 1]))  # deterministic order
    # OpenCV's SIFT descriptors are integers 0..255 held in floats
    return Features(xy[order][:, ::-1].copy(), np.clip(np.rint(desc[order]), 0, 255).astype(np.uint8), response[order])


def detect(image: MatchImage, row0: int, col0: int, rows: int, cols: int, k: int, n: int = 0,
           inner: tuple[np.ndarray, np.ndarray] | None = None) -> Features:
    """SIFT features (full-resolution line, column) of a window read decimated by k; with
    ``inner`` (lo, hi: full-resolution line, column), at least those with ``lo <= position < hi``
    (the rest of the window is context: its features get no descriptors, :func:`sift`)."""
    values, r0, c0 = image.raster.decimated(row0, col0, rows, cols, k)
    if values.size == 0:
        return Features.empty()
    origin = np.array([r0 + (k - 1) / 2.0, c0 + (k - 1) / 2.0])
    mask = None
    if inner is not None:
        # every decimated pixel nearest to a position in [lo, hi) (OpenCV tests a feature's nearest pixel)
        first = np.maximum(np.floor((np.asarray(inner[0]) - origin) / k).astype(int), 0)
        last = np.ceil((np.asarray(inner[1]) - origin) / k).astype(int) + 1
        mask = np.zeros(values.shape, np.uint8)
        mask[first[0]:last[0], first[1]:last[1]] = 1
    f = sift(image.raster.to_8bit(values), n, mask)
    f.pos = f.pos * k + origin
    return f


class FeatureCache:
    """One image's features, detected block by block the first time a window needs them, or in
    whole-width strips for a small image (``whole``: by default when the raster holds it whole),
    detected ahead in ``pool`` when given (module docstring)."""

    def __init__(self, image: MatchImage, decimation: int, pool: Executor | None = None, whole: bool | None = None):
        from solver.matching.raster import WHOLE_MAX_PX

        self.image, self.k, self.pool = image, decimation, pool
        self.whole = image.lines * image.columns <= WHOLE_MAX_PX if whole is None else whole
        self.pending: dict[tuple[tuple[int, int], tuple[int, int]], Future] = {}  # rectangle -> its detection, started ahead
        self.planned: set[tuple[int, int]] = set()  # blocks of the pending detections
        self.block = BLOCK_PX // decimation * decimation
        self.shape = (-(-image.lines // self.block), -(-image.columns // self.block))
        self.blocks: dict[tuple[int, int], Features] = {}
        self.detections = 0  # SIFT calls made
        self.detected: set[tuple[int, int]] = set()  # every block ever detected
        self.requests = 0
        self.last_use: dict[tuple[int, int], int] = {}  # block -> the request that last needed it
        self.horizon: int | None = None  # keep only the blocks needed within this many requests
        self.since = 0  # ... among those needed after this request
        self.used_at: dict[int, list[tuple[int, int]]] = {}  # request -> the blocks it needed (while a horizon is set)

    def _blocks_of(self, lo: np.ndarray, hi: np.ndarray) -> tuple[range, range]:
        b = self.block
        r = range(max(int(lo[0]) // b, 0), min(int(np.ceil(hi[0] / b)), self.shape[0]))
        c = range(max(int(lo[1]) // b, 0), min(int(np.ceil(hi[1] / b)), self.shape[1]))
        return r, c

    def _plan(self, rows: range, cols: range, skip: set[tuple[int, int]]) -> list[tuple[tuple[int, int], tuple[int, int]]]:
        """The rectangles of blocks the window's detection reads, for its blocks not in the
        cache nor in ``skip`` (for a small image: the strips that hold them)."""
        missing = {(i, j) for i in rows for j in cols if (i, j) not in self.blocks and (i, j) not in skip}
        if self.whole:
            strips = sorted({i // STRIP_BLOCKS for i, _j in missing})
            return [((k * STRIP_BLOCKS, min((k + 1) * STRIP_BLOCKS, self.shape[0])), (0, self.shape[1])) for k in strips]
        return _rectangles(missing)

    def _detect(self, rect: tuple[tuple[int, int], tuple[int, int]]) -> Features:
        """The features of a rectangle of blocks read with :data:`MARGIN_PX` of context."""
        b, m = self.block, MARGIN_PX
        (i0, i1), (j0, j1) = rect
        inner = (np.array([i0 * b, j0 * b]), np.array([i1 * b, j1 * b]))
        return detect(self.image, i0 * b - m, j0 * b - m, (i1 - i0) * b + 2 * m, (j1 - j0) * b + 2 * m, self.k, inner=inner)

    def prefetch(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Start detecting, in the pool's thread, what :meth:`window` (lo, hi) will need when it
        is asked for after the windows announced or asked for before it (nothing without a
        pool). A detection the window finds not started yet is taken back by the main thread."""
        if self.pool is None:
            return
        rows, cols = self._blocks_of(lo, hi)
        for rect in self._plan(rows, cols, self.planned):
            if rect not in self.pending:
                self.pending[rect] = self.pool.submit(self._detect, rect)
                self.planned |= set(self._rect_blocks(rect))

    def prefetch_whole(self) -> None:
        """A small image: start detecting its strips in the pool's thread (:meth:`prefetch`)."""
        if self.whole:
            self.prefetch(np.zeros(2), np.array([self.image.lines, self.image.columns]))

    def drop_pending(self) -> None:
        """Forget the detections started ahead (those not used: the windows went otherwise)."""
        for fut in self.pending.values():
            fut.cancel()
        self.pending.clear()
        self.planned.clear()

    def _rect_blocks(self, rect: tuple[tuple[int, int], tuple[int, int]]) -> list[tuple[int, int]]:
        (i0, i1), (j0, j1) = rect
        return [(i, j) for i in range(i0, i1) for j in range(j0, j1)]

    def _fill(self, rows: range, cols: range) -> None:
        b = self.block
        for rect in self._plan(rows, cols, set()):
            fut = self.pending.pop(rect, None)
            if fut is not None and fut.cancel():  # not started: detected here rather than waited for
                fut = None
            f = self._detect(rect) if fut is None else fut.result()
            blocks = self._rect_blocks(rect)  # row by row
            self.planned -= set(blocks)
            self.detections += 1
            (i0, i1), (j0, j1) = rect
            bi = np.floor(f.pos[:, 0] / b).astype(int)
            bj = np.floor(f.pos[:, 1] / b).astype(int)
            sel = np.flatnonzero((bi >= i0) & (bi < i1) & (bj >= j0) & (bj < j1))  # (not the context's)
            key = (bi[sel] - i0) * (j1 - j0) + (bj[sel] - j0)  # the block's place in ``blocks``
            order = np.argsort(key, kind="stable")  # each block's features in their detection order
            bounds = np.searchsorted(key[order], np.arange(len(blocks) + 1))
            g = f.take(sel[order])  # block after block: one copy, the blocks are views of it
            for (i, j), lo, hi in zip(blocks, bounds[:-1], bounds[1:], strict=True):
                if (i, j) not in self.blocks:  # (a small image's blocks already there stay as they are)
                    self.blocks[(i, j)] = Features(g.pos[lo:hi], g.desc[lo:hi], g.response[lo:hi])
                self.detected.add((i, j))

    def window(self, lo: np.ndarray, hi: np.ndarray) -> Features:
        """The features with ``lo <= position < hi`` (full-resolution line, column), detected
        where not yet done."""
        rows, cols = self._blocks_of(lo, hi)
        self._fill(rows, cols)
        keys = [(i, j) for i in rows for j in cols]
        f = Features.concat([self.blocks[key] for key in keys])
        inside = np.all((f.pos >= lo) & (f.pos < hi), axis=1)
        self.requests += 1
        self.last_use.update(dict.fromkeys(keys, self.requests))
        if self.horizon is not None and not self.whole:  # the blocks last needed ``horizon`` requests ago (after ``since``) go
            self.used_at[self.requests] = keys
            expired = self.requests - self.horizon
            for key in self.used_at.pop(expired, []) if expired > self.since else []:
                if self.last_use.get(key) == expired and key in self.blocks:
                    del self.blocks[key], self.last_use[key]
        return f.take(np.flatnonzero(inside))

    def keep_recent(self, requests: int) -> None:
        """From now on let go of the blocks the last ``requests`` windows did not need, among
        those needed since (the image's last pair: its tiles go over the image once, so such a
        block is seldom needed again; if it is, it is detected again). The blocks detected for
        earlier pairs stay until a window needs them. Bounds the memory by a few rows of tiles.
        A small image keeps all its blocks (detected in one call)."""
        self.horizon, self.since = requests, self.requests

    def retain(self, windows: list[tuple[np.ndarray, np.ndarray]]) -> None:
        """Keep only the blocks that ``windows`` (lo, hi) touch (an image whose later pairs all
        read it as their a: the same tile windows every time). A small image keeps all (one
        detection: a block let go would cost the whole image again)."""
        if self.whole:
            return
        keep = {(i, j) for lo, hi in windows for rows, cols in [self._blocks_of(lo, hi)] for i in rows for j in cols}
        for key in [k for k in self.blocks if k not in keep]:
            del self.blocks[key]
            self.last_use.pop(key, None)

    def detected_fraction(self) -> float:
        """The share of the image's blocks detected so far."""
        return len(self.detected) / (self.shape[0] * self.shape[1])

    def nbytes(self) -> int:
        return sum(f.pos.nbytes + f.desc.nbytes + f.response.nbytes for f in self.blocks.values())


def _rectangles(cells: set[tuple[int, int]]) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """The cells (row, column) as rectangles ((row0, row1), (col0, col1)), ends excluded: the
    runs of each row, merged with the same run of the rows below."""
    by_row: dict[int, list[int]] = {}
    for i, j in sorted(cells):
        by_row.setdefault(i, []).append(j)
    runs: dict[tuple[int, int], list[int]] = {}
    for i, js in by_row.items():
        start = js[0]
        for a, b in zip(js, js[1:] + [None], strict=True):
            if b != a + 1:
                runs.setdefault((start, a + 1), []).append(i)
                start = b
    out = []
    for (j0, j1), rows in sorted(runs.items()):
        r0 = rows[0]
        for a, b in zip(rows, rows[1:] + [None], strict=True):
            if b != a + 1:
                out.append(((r0, a + 1), (j0, j1)))
                r0 = b
    return sorted(out)
