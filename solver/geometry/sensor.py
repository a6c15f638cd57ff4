"""Which CCD chip an image column belongs to: the one rule shared by the solver and the simulator.

Butted CCD chips overlap (PRISM: 32 columns between neighbours) and the outer chips may start
before column 0 and end after the last delivered column. A column (pixels, origin at the centre
of the first delivered pixel) is covered by chip k when
``first_k - 0.5 <= C <= first_k + n_k - 0.5`` (each pixel extends half a pixel either side).
Where several chips cover it, it belongs to **the covering chip whose centre column
``first_k + (n_k - 1)/2`` is nearest**; a tie (a column exactly half-way between two centres)
goes to the chip with the larger centre column (so a column on the boundary of two chips that
touch, ``first_k + n_k - 0.5``, starts the next chip, as rounding half up would). For neighbouring chips of equal width this splits each overlap in
the middle: with 32 overlapping columns, 16 go to either chip. An observation may also name its
chip explicitly, which overrides the rule (:func:`camera_chip`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # annotations only: the job schema is not needed to run these
    from solver.schema.job import Camera


def covers(first_column: float, columns: float, column: np.ndarray | float) -> np.ndarray:
    """True where ``column`` lies on the chip's pixels (half a pixel beyond its end pixels)."""
    c = np.asarray(column, dtype=float)
    return (c >= first_column - 0.5) & (c <= first_column + columns - 0.5)


def chip_index_of_column(
    first_columns: Sequence[float], widths: Sequence[int], column: np.ndarray | float
) -> np.ndarray:
    """Index of the chip that column(s) ``column`` belong to by the rule above; -1 where no chip
    covers the column. ``first_columns``/``widths`` list the chips in the camera's order."""
    c = np.atleast_1d(np.asarray(column, dtype=float))
    best = np.full(c.shape, -1, dtype=np.int64)
    best_dist = np.full(c.shape, np.inf)
    centres = [first + (n - 1) / 2.0 for first, n in zip(first_columns, widths, strict=True)]
    for k in sorted(range(len(centres)), key=lambda j: centres[j]):
        dist = np.abs(c - centres[k])
        take = covers(first_columns[k], widths[k], c) & (dist <= best_dist)  # ties: the later centre
        best[take] = k
        best_dist[take] = dist[take]
    return best.reshape(np.shape(column))


def chip_seams(first_columns: Sequence[float], widths: Sequence[int], image_columns: int) -> np.ndarray:
    """Columns (half-integers) inside the delivered image ``0 .. image_columns - 1`` where the
    rule passes from one chip to another (or to a gap), for keeping points clear of them."""
    k = chip_index_of_column(first_columns, widths, np.arange(image_columns, dtype=float))
    return np.flatnonzero(k[1:] != k[:-1]) + 0.5


def in_image_columns(camera: Camera, column: float) -> bool:
    """True if ``column`` lies in the delivered image (``-0.5 .. columns - 0.5``)."""
    return -0.5 <= column <= (camera.columns or 0) - 0.5


def camera_chip(camera: Camera, column: float, chip: str | None = None) -> tuple[str, float, float, float]:
    """(chip id, dx_mm, dy_mm, centre column) of the chip of image column ``column``.

    ``chip`` names the chip (its id); without it the chip follows the rule of
    :mod:`solver.geometry.sensor` (the covering chip whose centre column is nearest). KeyError if the column
    is outside the delivered image, on no chip, or not on the named chip. A camera without chips
    is one chip "1" centred on the principal point.
    """
    if not in_image_columns(camera, column):
        raise KeyError(column)
    if not camera.chips:
        if chip not in (None, "1"):
            raise KeyError(chip)
        return "1", 0.0, 0.0, ((camera.columns or 0) - 1) / 2.0
    if chip is None:
        k = int(chip_index_of_column([c.first_column for c in camera.chips], [c.columns for c in camera.chips], column))
        if k < 0:
            raise KeyError(column)
    else:
        ids = [c.id for c in camera.chips]
        if chip not in ids:
            raise KeyError(chip)
        k = ids.index(chip)
        if not covers(camera.chips[k].first_column, camera.chips[k].columns, column):
            raise KeyError(column)
    c = camera.chips[k]
    return c.id, c.dx_mm, c.dy_mm, c.first_column + (c.columns - 1) / 2.0


def chip_indices(camera: Camera, columns: np.ndarray, chips: Sequence[str | None]) -> np.ndarray:
    """:func:`camera_chip` for many observations of one camera at once: the index of each
    observation's chip in ``camera.chips`` (0 for a camera without chips), -1 where
    :func:`camera_chip` raises KeyError (column outside the delivered image, on no chip, not on
    the named chip, or an unknown chip name). ``chips`` are the names given (None: the rule)."""
    c = np.asarray(columns, dtype=float)
    inside = (c >= -0.5) & (c <= (camera.columns or 0) - 0.5)
    named = np.array([ch is not None for ch in chips], dtype=bool)
    if not camera.chips:
        known = np.array([ch in (None, "1") for ch in chips], dtype=bool)
        return np.where(inside & known, 0, -1).astype(np.int64)
    firsts = [ch.first_column for ch in camera.chips]
    widths = [ch.columns for ch in camera.chips]
    k = np.asarray(chip_index_of_column(firsts, widths, c), dtype=np.int64).reshape(c.shape)
    if named.any():
        ids = {ch.id: i for i, ch in enumerate(camera.chips)}
        given = np.array([ids.get(ch, -1) if ch is not None else -1 for ch in chips], dtype=np.int64)
        ok = given >= 0
        on_chip = np.zeros(c.shape, dtype=bool)
        if ok.any():
            f = np.asarray(firsts, dtype=float)[given[ok]]
            w = np.asarray(widths, dtype=float)[given[ok]]
            on_chip[ok] = (c[ok] >= f - 0.5) & (c[ok] <= f + w - 0.5)
        k = np.where(named, np.where(on_chip, given, -1), k)
    return np.where(inside, k, -1).astype(np.int64)


def chip_of_index(camera: Camera, k: int) -> tuple[str, float, float, float]:
    """(chip id, dx_mm, dy_mm, centre column) of chip ``k`` of :func:`chip_indices`."""
    if not camera.chips:
        return "1", 0.0, 0.0, ((camera.columns or 0) - 1) / 2.0
    c = camera.chips[k]
    return c.id, c.dx_mm, c.dy_mm, c.first_column + (c.columns - 1) / 2.0
