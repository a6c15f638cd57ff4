"""numba kernel of ``pba ortho --method rigorous``: per output pixel, the image position
interpolated between the projected grid nodes (bilinear; linear in height between two grids)
and the raster sampled bilinearly (pixel centres at integer positions). ~10-20 ns a pixel."""

from __future__ import annotations

import numpy as np
from numba import njit

import solver.kernels.cache  # noqa: F401  (cache keyed on the kernel sources: before any @njit)


@njit(cache=True, nogil=True, error_model="numpy")
def sample_block(data, gl0, gc0, gl1, gc1, step, n_rows, n_cols, row0, heights, h0, h1, rounding, out):
    """Fill ``out`` (rows row0.. of the orthoimage, (k, n_cols)): ``gl*``/``gc*`` image line and
    column at the grid nodes (every ``step`` pixels, last node at n-1) at heights h0 and h1;
    ``heights`` (k, n_cols) the pixels' heights (ignored when h1 == h0); 0 outside the image;
    ``rounding`` 0.5 for integer rasters (round to nearest), 0 for float ones."""
    nr, nc = gl0.shape
    lines, cols = data.shape
    k = out.shape[0]
    two = h1 != h0
    for a in range(k):
        r = row0 + a
        i = min(r // step, nr - 2) if nr > 1 else 0
        r_lo = i * step
        r_hi = min((i + 1) * step, n_rows - 1)
        fr = (r - r_lo) / (r_hi - r_lo) if r_hi > r_lo else 0.0
        i1 = min(i + 1, nr - 1)
        for c in range(n_cols):
            j = min(c // step, nc - 2) if nc > 1 else 0
            c_lo = j * step
            c_hi = min((j + 1) * step, n_cols - 1)
            fc = (c - c_lo) / (c_hi - c_lo) if c_hi > c_lo else 0.0
            j1 = min(j + 1, nc - 1)
            w00, w01, w10, w11 = (1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc
            ln = gl0[i, j] * w00 + gl0[i, j1] * w01 + gl0[i1, j] * w10 + gl0[i1, j1] * w11
            cl = gc0[i, j] * w00 + gc0[i, j1] * w01 + gc0[i1, j] * w10 + gc0[i1, j1] * w11
            if two:
                h = heights[a, c]
                if not np.isfinite(h):
                    out[a, c] = 0
                    continue
                t = (h - h0) / (h1 - h0)
                l1 = gl1[i, j] * w00 + gl1[i, j1] * w01 + gl1[i1, j] * w10 + gl1[i1, j1] * w11
                c1 = gc1[i, j] * w00 + gc1[i, j1] * w01 + gc1[i1, j] * w10 + gc1[i1, j1] * w11
                ln = ln + t * (l1 - ln)
                cl = cl + t * (c1 - cl)
            if not (ln >= -0.5 and ln <= lines - 0.5 and cl >= -0.5 and cl <= cols - 0.5):
                out[a, c] = 0
                continue
            y0 = min(max(int(np.floor(ln)), 0), lines - 1)
            x0 = min(max(int(np.floor(cl)), 0), cols - 1)
            y1 = min(y0 + 1, lines - 1)
            x1 = min(x0 + 1, cols - 1)
            fy = min(max(ln - y0, 0.0), 1.0)
            fx = min(max(cl - x0, 0.0), 1.0)
            v = (data[y0, x0] * (1 - fy) * (1 - fx) + data[y0, x1] * (1 - fy) * fx + data[y1, x0] * fy * (1 - fx) + data[y1, x1] * fy * fx)
            out[a, c] = v + rounding
