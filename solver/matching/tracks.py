"""Multi-image tie points from pairwise matches, and their thinning to an even spread.

Linking: every end of a pairwise match is a node (image, line, column); nodes are joined by
their match and by proximity (two nodes of one image within ``LINK_RADIUS_PX`` times the
detection's decimation are the same feature seen from two pairs). A connected component is a track. A track whose nodes in one
image lie further than ``MAX_SPREAD_PX`` apart links two different features (a chain of matches
that went astray somewhere): it is dropped whole, never split by guessing.

Thinning: tracks in order of (more images, more supporting matches, position) are kept while
one of the image cells they fall in (``grid`` x ``grid`` per image) holds fewer than
``per_cell`` tie points: an even spread over every image, multi-image points first.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LINK_RADIUS_PX = 1.5
MAX_SPREAD_PX = 2.0


@dataclass
class Track:
    """One tie point: its images (indices) and (line, column) in each; the number of pairwise
    matches that support it."""

    members: dict[int, np.ndarray]
    support: int

    def key(self) -> tuple:
        ref = min(self.members)
        p = self.members[ref]
        return (ref, round(float(p[0]), 3), round(float(p[1]), 3))


def link(pairs, n_images: int, scale: float = 1.0) -> tuple[list[Track], int]:
    """Tracks from the pairwise matches (``PairMatches`` a, b, pa, pb), sorted by
    :meth:`Track.key`, and the number of inconsistent components dropped; ``scale`` multiplies
    the link radius and the largest spread (the decimation features were detected at)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    images, positions, edges = [], [], []
    n = 0
    for pm in pairs:
        k = len(pm.pa)
        if not k:
            continue
        images += [pm.a] * k + [pm.b] * k
        positions += [pm.pa, pm.pb]
        idx = np.arange(n, n + k)
        edges.append(np.column_stack([idx, idx + k]))
        n += 2 * k
    if not n:
        return [], 0
    img = np.array(images)
    pos = np.vstack(positions)
    match_edges = np.vstack(edges)
    near = [match_edges]
    for i in range(n_images):
        sel = np.flatnonzero(img == i)
        if len(sel) > 1:
            pairs_i = cKDTree(pos[sel]).query_pairs(LINK_RADIUS_PX * scale, output_type="ndarray")
            if len(pairs_i):
                near.append(sel[pairs_i])
    e = np.vstack(near)
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    n_comp, label = connected_components(graph, directed=False)
    support = np.bincount(label[match_edges[:, 0]], minlength=n_comp)
    order = np.argsort(label, kind="stable")
    bounds = np.flatnonzero(np.diff(label[order])) + 1
    tracks, dropped = [], 0
    for group in np.split(order, bounds):
        members: dict[int, np.ndarray] = {}
        consistent = True
        for i in np.unique(img[group]):
            p = pos[group[img[group] == i]]
            centre = np.median(p, axis=0)
            if np.max(np.linalg.norm(p - centre, axis=1)) > MAX_SPREAD_PX * scale:
                consistent = False
                break
            members[int(i)] = p.mean(axis=0)
        if not consistent:
            dropped += 1
            continue
        if len(members) >= 2:
            tracks.append(Track(members, int(support[label[group[0]]])))
    tracks.sort(key=Track.key)
    return tracks, dropped


def cell_of(position: np.ndarray, lines: int, columns: int, grid: int) -> tuple[int, int]:
    """The thinning cell (row, column of the grid) of an image position."""
    r = min(max(int(position[0] * grid / lines), 0), grid - 1)
    c = min(max(int(position[1] * grid / columns), 0), grid - 1)
    return r, c


def thin(tracks: list[Track], sizes: list[tuple[int, int]], grid: int, per_cell: int) -> list[Track]:
    """The tracks kept for an even spread (module docstring), in :meth:`Track.key` order."""
    counts = [np.zeros((grid, grid), int) for _ in sizes]
    ranked = sorted(tracks, key=lambda t: (-len(t.members), -t.support, t.key()))
    kept = []
    for t in ranked:
        cells = {i: cell_of(p, *sizes[i], grid) for i, p in t.members.items()}
        if any(counts[i][c] < per_cell for i, c in cells.items()):
            kept.append(t)
            for i, c in cells.items():
                counts[i][c] += 1
    kept.sort(key=Track.key)
    return kept
