"""SIFT features of an image, detected once and reused by every pair the image is in.

An image is cut into square blocks of :data:`BLOCK_PX` pixels (a multiple of the decimation);
a block's features are detected the first time a window that touches it is asked for, on a
read decimated by ``decimation`` (:meth:`solver.matching.raster.Raster.decimated`: OpenCV's
SIFT doubles its input first, so the finest scale is still the full resolution's, at a quarter
of the cost) that takes the missing blocks' bounding box plus :data:`MARGIN_PX` of context, and
kept with the block. So a window of the image is detected once, whichever pair asks for it and
in whatever role; large images are detected only where a pair needs them. In the image's last
pair only the blocks of the last few rows of tiles are kept (:meth:`FeatureCache.keep_recent`).

Positions are (line, column) in our convention (pixel centres, top-left at (0, 0)), full
resolution; descriptors are OpenCV's (128 values from 0 to 255, stored as uint8); the response
is SIFT's (the strength of the extremum, for choosing the strongest features of a cell).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solver.matching.orientation import MatchImage

BLOCK_PX = 32  # side of a detection block (full-resolution pixels, a multiple of the decimation)
MARGIN_PX = 32  # context read around the blocks being detected (full-resolution pixels)


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


def sift(image8: np.ndarray, n: int = 0) -> Features:
    """SIFT features of an 8-bit array (array coordinates: line, column of pixel centres), the
    strongest ``n`` (all for 0), in a deterministic order."""
    import cv2

    # precise upscale: OpenCV's default doubling puts every keypoint 0.25 px (of its input) down
    # and right of the feature; k times that after a read decimated by k
    detector = cv2.SIFT_create(nfeatures=n, enable_precise_upscale=True)
    kps, desc = detector.detectAndCompute(image8, None)
    if desc is None or not kps:
        return Features.empty()
    xy = np.array([k.pt for k in kps], float)  # OpenCV: x = column, y = line, pixel centres at integers
    response = np.array([k.response for k in kps], np.float32)
    order = np.lexsort((xy[:, 0], xy[:, 1]))  # deterministic order
    # OpenCV's SIFT descriptors are integers 0..255 held in floats
    return Features(xy[order][:, ::-1].copy(), np.clip(np.rint(desc[order]), 0, 255).astype(np.uint8), response[order])


def detect(image: MatchImage, row0: int, col0: int, rows: int, cols: int, k: int, n: int = 0) -> Features:
    """SIFT features (full-resolution line, column) of a window read decimated by k."""
    values, r0, c0 = image.raster.decimated(row0, col0, rows, cols, k)
    if values.size == 0:
        return Features.empty()
    f = sift(image.raster.to_8bit(values), n)
    f.pos = f.pos * k + (r0 + (k - 1) / 2.0, c0 + (k - 1) / 2.0)
    return f


class FeatureCache:
    """One image's features, detected block by block the first time a window needs them
    (module docstring)."""

    def __init__(self, image: MatchImage, decimation: int):
        self.image, self.k = image, decimation
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

    def _fill(self, rows: range, cols: range) -> None:
        b, m = self.block, MARGIN_PX
        for (i0, i1), (j0, j1) in _rectangles({(i, j) for i in rows for j in cols if (i, j) not in self.blocks}):
            f = detect(self.image, i0 * b - m, j0 * b - m, (i1 - i0) * b + 2 * m, (j1 - j0) * b + 2 * m, self.k)
            self.detections += 1
            bi = np.floor(f.pos[:, 0] / b).astype(int)
            bj = np.floor(f.pos[:, 1] / b).astype(int)
            width = j1 - j0
            inside = (bi >= i0) & (bi < i1) & (bj >= j0) & (bj < j1)
            key = np.where(inside, (bi - i0) * width + (bj - j0), -1)
            order = np.argsort(key, kind="stable")  # each block's features in their detection order
            bounds = np.searchsorted(key[order], np.arange(-1, (i1 - i0) * width) + 0.5)
            for n in range((i1 - i0) * width):
                i, j = i0 + n // width, j0 + n % width
                self.blocks[(i, j)] = f.take(order[bounds[n]:bounds[n + 1]])
                self.detected.add((i, j))

    def window(self, lo: np.ndarray, hi: np.ndarray) -> Features:
        """The features with ``lo <= position < hi`` (full-resolution line, column), detected
        where not yet done."""
        rows, cols = self._blocks_of(lo, hi)
        self._fill(rows, cols)
        f = Features.concat([self.blocks[(i, j)] for i in rows for j in cols])
        inside = np.all((f.pos >= lo) & (f.pos < hi), axis=1)
        self.requests += 1
        for key in ((i, j) for i in rows for j in cols):
            self.last_use[key] = self.requests
        if self.horizon is not None:  # the blocks last needed ``horizon`` requests ago (after ``since``) go
            self.used_at[self.requests] = [(i, j) for i in rows for j in cols]
            expired = self.requests - self.horizon
            for key in self.used_at.pop(expired, []) if expired > self.since else []:
                if self.last_use.get(key) == expired and key in self.blocks:
                    del self.blocks[key], self.last_use[key]
        return f.take(np.flatnonzero(inside))

    def keep_recent(self, requests: int) -> None:
        """From now on let go of the blocks the last ``requests`` windows did not need, among
        those needed since (the image's last pair: its tiles go over the image once, so such a
        block is seldom needed again; if it is, it is detected again). The blocks detected for
        earlier pairs stay until a window needs them. Bounds the memory by a few rows of tiles."""
        self.horizon, self.since = requests, self.requests

    def retain(self, windows: list[tuple[np.ndarray, np.ndarray]]) -> None:
        """Keep only the blocks that ``windows`` (lo, hi) touch (an image whose later pairs all
        read it as their a: the same tile windows every time)."""
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
    runs: dict[tuple[int, int], list[int]] = {}
    for i in sorted({i for i, _ in cells}):
        js = sorted(j for r, j in cells if r == i)
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
