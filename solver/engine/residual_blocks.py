"""The residual blocks of the image observations, laid out once for both evaluation paths
(:mod:`solver.engine.backend`: compiled callbacks or Python cost functions).

* a **point block** holds every observation of one estimated ground point (tie point, weighted
  control point), or at most three of them in large least-squares blocks (:func:`point_blocks`'s
  ``max_rays``); its parameter blocks are the point, then the images it is seen in (first
  appearance), the cameras with free interior orientation, the passes of pass-propagated images;
* a **fixed block** holds the observations of fixed ground points in one image (a resection
  block), with the same parameter order minus the point.

Everything is computed in vectorised passes over all observations (no per-observation Python
loop): the slots of each record (the position of its image, camera and pass block among its
residual block's parameter blocks) and the records themselves (:func:`records`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solver.engine.packed_tables import records
from solver.state import AdjustmentState


@dataclass
class ResidualBlocks:
    """Residual blocks of one kind: block b holds the records ``rec[start[b]:start[b + 1]]``
    (observation rows ``rows[...]``); ``owner[b]`` is its point (point blocks) or image (fixed
    blocks); ``params[b]`` its parameter arrays in Ceres' order (without the point)."""

    rows: np.ndarray
    start: np.ndarray
    owner: np.ndarray
    rec: np.ndarray
    params: list[list[np.ndarray]]
    sizes: np.ndarray  # (blocks, most parameter blocks) sizes of params[b], 0-padded
    n_params: np.ndarray  # len(params[b])

    def __len__(self) -> int:
        return len(self.owner)

    def records_of(self, b: int) -> np.ndarray:
        return self.rec[self.start[b] : self.start[b + 1]]

    def param_sizes(self) -> list[list[int]]:
        """The sizes of ``params[b]`` for every block, as Python lists (read from ``sizes``)."""
        return [row[:n] for row, n in zip(self.sizes.tolist(), self.n_params.tolist())]


def first_appearance_ranks(block: np.ndarray, key: np.ndarray, n_blocks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For rows grouped by ``block`` (non-decreasing) with ``key`` (-1: none): each row's rank
    among its block's distinct keys in order of first appearance (-1 where key < 0), the number of
    distinct keys per block, and the distinct keys of all blocks in (block, rank) order."""
    ranks = -np.ones(len(block), dtype=np.int64)
    idx = np.flatnonzero(key >= 0)
    if len(idx) == 0:
        return ranks, np.zeros(n_blocks, dtype=np.int64), np.zeros(0, dtype=np.int64)
    b = block[idx].astype(np.int64)
    k = key[idx].astype(np.int64)
    span = int(k.max()) + 1
    uniq, first, inverse = np.unique(b * span + k, return_index=True, return_inverse=True)
    ublock = uniq // span
    order = np.lexsort((first, ublock))
    counts = np.bincount(ublock, minlength=n_blocks).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank_of_pair = np.empty(len(uniq), dtype=np.int64)
    rank_of_pair[order] = np.arange(len(uniq)) - starts[ublock[order]]
    ranks[idx] = rank_of_pair[inverse.ravel()]
    return ranks, counts, (uniq % span)[order]


def _parameter_keys(problem: AdjustmentState, rows: np.ndarray):
    """Per row: the key of its image's platform block (images may share one: its index among
    the ``image`` kind's blocks), of its camera's free interior orientation (-1: none) and of
    its pass (-1: none); and the platform blocks' arrays by key."""
    obs = problem.obs
    image_key = np.array([img.platform.index for img in problem.images], dtype=np.int64)  # per image, not per observation
    image_arrays = [block.params for block in problem.blocks["image"]]
    camera_free = np.array([c.nfree > 0 for c in problem.cameras] + [False], dtype=bool)  # [-1]: RPC images
    pass_of_image = np.array([img.pass_index for img in problem.images] + [-1], dtype=np.int64)
    img = obs.img[rows]
    cam = obs.cam[rows]
    cam_key = np.where(camera_free[cam], cam, -1)
    pass_key = pass_of_image[img]
    return image_key[img], cam_key, pass_key, image_arrays


def layout(problem: AdjustmentState, rows: np.ndarray, block: np.ndarray, owner: np.ndarray) -> ResidualBlocks:
    """The blocks of ``rows`` grouped by ``block`` (0..len(owner)-1, non-decreasing)."""
    n_blocks = len(owner)
    img_key, cam_key, pass_key, image_arrays = _parameter_keys(problem, rows)
    img_rank, n_img, img_keys = first_appearance_ranks(block, img_key, n_blocks)
    cam_rank, n_cam, cam_keys = first_appearance_ranks(block, cam_key, n_blocks)
    pass_rank, n_pass, pass_keys = first_appearance_ranks(block, pass_key, n_blocks)
    img_slot = img_rank
    cam_slot = np.where(cam_rank >= 0, cam_rank + n_img[block], -1)
    pass_slot = np.where(pass_rank >= 0, pass_rank + n_img[block] + n_cam[block], -1)
    rec = records(problem, rows, img_slot, cam_slot, pass_slot)
    start = np.searchsorted(block, np.arange(n_blocks + 1)).astype(np.int64)
    ci = np.concatenate([[0], np.cumsum(n_img)])
    cc = np.concatenate([[0], np.cumsum(n_cam)])
    cp = np.concatenate([[0], np.cumsum(n_pass)])
    cameras, passes = problem.cameras, problem.passes
    # one key space over every parameter array: images' blocks, then cameras', then passes'
    arrays = image_arrays + [c.params for c in cameras] + [q.params for q in passes]
    n_params = n_img + n_cam + n_pass
    width = int(n_params.max()) if n_blocks else 0
    sizes = np.zeros((n_blocks, width), dtype=np.int64)
    keys = -np.ones((n_blocks, width), dtype=np.int64)
    parts = (
        (0, img_keys, n_img, ci, np.zeros(n_blocks, dtype=np.int64)),
        (len(image_arrays), cam_keys, n_cam, cc, n_img),
        (len(image_arrays) + len(cameras), pass_keys, n_pass, cp, n_img + n_cam),
    )
    key_size = np.array([len(a) for a in arrays], dtype=np.int64)
    for key_offset, part_keys, count, offsets, first_column in parts:
        if len(part_keys):
            blk = np.repeat(np.arange(n_blocks), count)
            col = np.arange(len(part_keys)) - np.repeat(offsets[:-1], count) + first_column[blk]
            keys[blk, col] = part_keys + key_offset
            sizes[blk, col] = key_size[part_keys + key_offset]
    params = [[arrays[k] for k in row if k >= 0] for row in keys.tolist()]
    return ResidualBlocks(rows, start, np.asarray(owner, dtype=np.int64), rec, params, sizes, n_params)


def point_blocks(problem: AdjustmentState, max_rays: int | None = None) -> ResidualBlocks:
    """One block per estimated point that has adjusted observations (points in index order);
    ``max_rays``: a point seen in more images is split into consecutive blocks of at most that
    many observations, as even as they go (7 -> 3 + 2 + 2), so ``owner`` may repeat a point.

    The split is the same sum of squares in blocks whose Jacobian cells are smaller: Ceres
    stores each image's cell of a block over all of the block's rows, so a point seen in k
    images costs 2k x (3 + n k) Jacobian entries as one block (n: the image's parameters) and
    about 2k x (3 + 3 n) split in threes. A robust loss would act on each block's own sum, so
    only plain least squares may be split (:func:`solver.engine.backend.split_rays`)."""
    obs = problem.obs
    estimated = np.array([p.estimated for p in problem.points], dtype=bool)
    rows = np.flatnonzero(problem.adjusted_mask & estimated[obs.pt] if len(obs.pt) else np.zeros(0, dtype=bool))
    rows = rows[np.argsort(obs.pt[rows], kind="stable")]
    owner, block = np.unique(obs.pt[rows], return_inverse=True)
    block = block.ravel()
    if max_rays is not None and len(rows):
        count = np.bincount(block)
        first = np.concatenate([[0], np.cumsum(count)[:-1]])
        rank = np.arange(len(rows)) - first[block]  # the observation's place among its point's
        chunks = -(-count // max_rays)  # per point: ceil(count / max_rays)
        chunk = rank * chunks[block] // count[block]  # even lengths, in the observations' order
        new = np.ones(len(rows), dtype=bool)
        new[1:] = (block[1:] != block[:-1]) | (chunk[1:] != chunk[:-1])
        owner = obs.pt[rows][new]
        block = np.cumsum(new) - 1
    return layout(problem, rows, block, owner)


def fixed_blocks(problem: AdjustmentState) -> ResidualBlocks:
    """One block per image with adjusted observations of fixed ground points (images in index order)."""
    obs = problem.obs
    estimated = np.array([p.estimated for p in problem.points], dtype=bool)
    rows = np.flatnonzero(problem.adjusted_mask & ~estimated[obs.pt] if len(obs.pt) else np.zeros(0, dtype=bool))
    rows = rows[np.argsort(obs.img[rows], kind="stable")]
    owner, block = np.unique(obs.img[rows], return_inverse=True)
    return layout(problem, rows, block.ravel(), owner)


def fixed_points(problem: AdjustmentState, blocks: ResidualBlocks) -> np.ndarray:
    """The ground points (LGS m) of a fixed layout's records, (n, 3) C-contiguous."""
    xyz = np.array([p.xyz for p in problem.points], dtype=float).reshape(-1, 3)
    return np.ascontiguousarray(xyz[problem.obs.pt[blocks.rows]])
