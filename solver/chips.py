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
chip explicitly, which overrides the rule (:mod:`solver.problem`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


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
