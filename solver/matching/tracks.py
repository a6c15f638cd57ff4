"""Multi-image tie points from pairwise matches, and their thinning to an even spread.

Linking: every end of a pairwise match is a node (image, line, column); nodes are joined by
their match and by proximity (two nodes of one image within ``LINK_RADIUS_PX`` times the
detection's decimation are the same feature seen from two pairs). A connected component (union-find
over arrays, :func:`components`) is a track. A track whose nodes in one
image lie further than ``MAX_SPREAD_PX`` apart links two different features (a chain of matches
that went astray somewhere): it is dropped whole, never split by guessing.

Thinning: tracks in order of (more images, more supporting matches, position) are kept while
one of the image cells they fall in (``grid`` x ``grid`` per image) holds fewer than
``per_cell`` tie points: an even spread over every image, multi-image points first.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

LINK_RADIUS_PX = 1.5
MAX_SPREAD_PX = 2.0


@dataclass
class Track:
    """One tie point: its images (indices) and (line, column) in each; the number of pairwise
    matches that support it. Its members are not changed once made (the key is kept)."""

    members: dict[int, np.ndarray]
    support: int
    _key: tuple | None = field(default=None, repr=False, compare=False)

    def key(self) -> tuple:
        """(first image, its line and column to 1e-3 px): the order of tracks."""
        if self._key is None:
            ref = min(self.members)
            p = self.members[ref]
            self._key = (ref, round(float(p[0]), 3), round(float(p[1]), 3))
        return self._key


def components(n: int, edges: np.ndarray) -> np.ndarray:
    """(n,) the connected component of each of ``n`` nodes joined by ``edges`` (m, 2): its
    smallest node. Union-find over arrays: every edge pulls both ends' labels down to the smaller,
    then each label jumps to its label's label, until nothing changes."""
    label = np.arange(n)
    if not len(edges):
        return label
    u, v = edges[:, 0], edges[:, 1]
    while True:
        low = np.minimum(label[u], label[v])
        new = label.copy()
        np.minimum.at(new, u, low)
        np.minimum.at(new, v, low)
        new = new[new]
        while True:
            jumped = new[new]
            if np.array_equal(jumped, new):
                break
            new = jumped
        if np.array_equal(new, label):
            return label
        label = new


def close_pairs(pos: np.ndarray, radius: float) -> np.ndarray:
    """(m, 2) the index pairs (i < j) of points ``pos`` (n, 2) at most ``radius`` apart: points
    binned in cells of ``radius``, each cell compared with itself and four of its neighbours
    (the other four see it from their side)."""
    cell = np.floor(pos / radius).astype(np.int64)
    cell -= cell.min(axis=0)
    width = int(cell[:, 1].max()) + 3
    key = cell[:, 0] * width + cell[:, 1] + 1
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    out = []
    for dl, dc in ((0, 0), (0, 1), (1, -1), (1, 0), (1, 1)):
        target = key + dl * width + dc
        lo = np.searchsorted(sorted_key, target, side="left")
        hi = np.searchsorted(sorted_key, target, side="right")
        count = hi - lo
        i = np.repeat(np.arange(len(pos)), count)
        j = order[np.repeat(lo - np.cumsum(count) + count, count) + np.arange(int(count.sum()))]
        keep = np.sum((pos[i] - pos[j]) ** 2, axis=1) <= radius * radius
        keep &= (i < j) if (dl, dc) == (0, 0) else np.ones(len(i), dtype=bool)
        out.append(np.column_stack([np.minimum(i, j), np.maximum(i, j)])[keep])
    return np.vstack(out)


def link(pairs, n_images: int, scale: float = 1.0) -> tuple[list[Track], int]:
    """Tracks from the pairwise matches (``PairMatches`` a, b, pa, pb), sorted by
    :meth:`Track.key`, and the number of inconsistent components dropped; ``scale`` multiplies
    the link radius and the largest spread (the decimation features were detected at)."""
    images, positions, edges = [], [], []
    n = 0
    for pm in pairs:
        k = len(pm.pa)
        if not k:
            continue
        images.append(np.full(2 * k, pm.a))
        images[-1][k:] = pm.b
        positions += [pm.pa, pm.pb]
        idx = np.arange(n, n + k)
        edges.append(np.column_stack([idx, idx + k]))
        n += 2 * k
    if not n:
        return [], 0
    img = np.concatenate(images)
    pos = np.vstack(positions).astype(float)
    match_edges = np.vstack(edges)
    near = [match_edges]
    for i in range(n_images):
        sel = np.flatnonzero(img == i)
        if len(sel) > 1:
            pairs_i = close_pairs(pos[sel], LINK_RADIUS_PX * scale)
            if len(pairs_i):
                near.append(sel[pairs_i])
    label = components(n, np.vstack(near))
    support = np.bincount(label[match_edges[:, 0]], minlength=n)
    # groups: the nodes of one component in one image
    order = np.lexsort((img, label))
    key = label[order] * n_images + img[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    sizes = np.diff(np.r_[starts, n])
    mean = np.add.reduceat(pos[order], starts, axis=0) / sizes[:, None]
    spread = np.zeros(len(starts))
    for size in np.unique(sizes[sizes > 1]):  # the groups of each size at once
        g = np.flatnonzero(sizes == size)
        p = pos[order[starts[g][:, None] + np.arange(size)]]  # (groups, size, 2)
        spread[g] = np.max(np.linalg.norm(p - np.median(p, axis=1, keepdims=True), axis=2), axis=1)
    g_label = label[order[starts]]
    g_img = img[order[starts]]
    bad = np.unique(g_label[spread > MAX_SPREAD_PX * scale])
    ok = ~np.isin(g_label, bad)
    comp_starts = np.flatnonzero(np.r_[True, g_label[1:] != g_label[:-1]])
    comp_ends = np.r_[comp_starts[1:], len(starts)]
    made = comp_starts[(comp_ends - comp_starts >= 2) & ok[comp_starts]]
    images_, means = g_img.tolist(), list(mean)
    tracks = []
    # a component's groups are in image order: its first is the reference (Track.key)
    for c0, c1, s, ref, line, col in zip(made.tolist(), comp_ends[np.searchsorted(comp_starts, made)].tolist(), support[g_label[made]].tolist(),
                                          g_img[made].tolist(), mean[made, 0].tolist(), mean[made, 1].tolist(), strict=True):
        tracks.append(Track({images_[g]: means[g] for g in range(c0, c1)}, s, (ref, round(line, 3), round(col, 3))))
    tracks.sort(key=Track.key)
    return tracks, len(bad)


def cell_of(position: np.ndarray, lines: int, columns: int, grid: int) -> tuple[int, int]:
    """The thinning cell (row, column of the grid) of an image position."""
    r = min(max(int(position[0] * grid / lines), 0), grid - 1)
    c = min(max(int(position[1] * grid / columns), 0), grid - 1)
    return r, c


def thin(tracks: list[Track], sizes: list[tuple[int, int]], grid: int, per_cell: int) -> list[Track]:
    """The tracks kept for an even spread (module docstring), in :meth:`Track.key` order."""
    if not tracks:
        return []
    n = len(tracks)
    keys = [t.key() for t in tracks]
    by_key = np.empty(n, np.int64)
    by_key[sorted(range(n), key=keys.__getitem__)] = np.arange(n)  # each track's place in key order
    n_members = np.array([len(t.members) for t in tracks])
    support = np.array([t.support for t in tracks])
    ranked = np.lexsort((by_key, -support, -n_members)).tolist()  # more images, more support, then the key
    # every member's cell (:func:`cell_of`) at once, numbered image by image
    img = np.fromiter((i for t in tracks for i in t.members), np.int64, int(n_members.sum()))
    pos = np.array([p for t in tracks for p in t.members.values()], float).reshape(-1, 2)
    dims = np.array(sizes, float)[img]
    r = np.clip(np.trunc(pos[:, 0] * grid / dims[:, 0]), 0, grid - 1).astype(np.int64)
    c = np.clip(np.trunc(pos[:, 1] * grid / dims[:, 1]), 0, grid - 1).astype(np.int64)
    flat = ((img * grid + r) * grid + c).tolist()
    ends = np.cumsum(n_members).tolist()
    cells = [flat[e - k:e] for e, k in zip(ends, n_members.tolist(), strict=True)]
    counts = [0] * (len(sizes) * grid * grid)
    kept = []
    for k in ranked:
        if any(counts[i] < per_cell for i in cells[k]):
            kept.append(k)
            for i in cells[k]:
                counts[i] += 1
    kept.sort(key=by_key.__getitem__)
    return [tracks[k] for k in kept]
