"""RPC00B (rational polynomial coefficients) fitted to the adjusted rigorous model.

Terrain-independent fit (Tao & Hu 2001, "A comprehensive study of the rational function model
for photogrammetric processing", PE&RS 67(12)): a 3-D grid of virtual control points is made by
intersecting the rays of a regular grid of image positions with several constant ellipsoidal
heights spanning the job's height range (plus a margin) or a DEM's; the 78 coefficients are
estimated by iteratively reweighted, Tikhonov-regularised linear least squares (the linearised
form ``N(X) - r D(X) = 0`` weighted by ``1 / D(X)`` of the previous iteration), with the better
on the check grid of two weights (1e-12: ~1e-7 px for a smooth geometry; 1e-8: steadier where
the geometry jumps, the whole image of a multi-chip camera; :func:`solver.geometry.rpc.fit_rpc_best`). The fit is
assessed on an independent check grid (image positions half-way between the fit grid's, heights
between its layers), reported as residuals in pixels.

RPC00B conventions (NITF STDI-0002, GDAL): normalised ``X = (lon - LONG_OFF) / LONG_SCALE``,
``Y`` latitude and ``Z`` height likewise (degrees, ellipsoidal metres on WGS 84); the 20 terms
of each cubic in the RPC00B order :data:`TERMS`; line and sample are normalised the same way.
Image coordinates of an RPC are those of the **centre** of the top-left pixel at (0, 0), the
solver's convention; GDAL's transformer adds half a pixel (pixel corners), see
:mod:`solver.gis.rpc_io`. The RPC model, the fit and the residuals are in the low-layer
:mod:`solver.geometry.rpc` (shared with the simulator); this module builds the grids from the
adjusted model.
"""

from __future__ import annotations

import numpy as np

from solver.geometry.geodesy import ecef_to_geodetic, geodetic_to_ecef
from solver.geometry.rpc import (  # noqa: F401  (re-exported: the GIS modules and tests import them from here)
    CHECK_GRID,
    FIT_GRID,
    REGULARISATION,
    RPC,
    TERMS,
    GroundGrid,
    fit_ratio,
    fit_record,
    fit_rpc,
    fit_rpc_best,
    heights_of,
    monomials,
    residuals_px,
)

HEIGHT_MARGIN_M = 100.0


def ground_grid(image, lines: tuple[float, float], columns: tuple[float, float], heights: np.ndarray, n: tuple[int, int], chip: int | None = None, cell_centres: bool = False) -> GroundGrid:
    """Rays of an ``n[0] x n[1]`` grid of image positions (pixel centres, corners included, or
    the cells' centres) intersected with each height (metres, ellipsoidal)."""
    def axis(lo: float, hi: float, k: int) -> np.ndarray:
        if cell_centres:
            step = (hi - lo) / k
            return lo + step * (np.arange(k) + 0.5)
        return np.linspace(lo, hi, k)

    ll, cc = np.meshgrid(axis(*lines, n[0]), axis(*columns, n[1]), indexing="ij")
    ll, cc = ll.ravel(), cc.ravel()
    s, d = image.rays(ll, cc, chip)
    from solver.gis.model import intersect_height

    out = []
    for h in heights:
        llh = ecef_to_geodetic(intersect_height(s, d, float(h), None))
        out.append(llh)
    llh = np.vstack(out)
    m = len(heights)
    return GroundGrid(np.tile(ll, m), np.tile(cc, m), llh[:, 0], llh[:, 1], llh[:, 2])


MULTI_CHIP_WARNING_PX = 0.05


def fit_image_rpc(image, height_range_m: tuple[float, float], chip: int | None = None) -> RPC:
    """RPC of one adjusted image (:class:`solver.gis.model.AdjustedImage`), of the whole image
    or of one chip's columns (``chip``), with its fit and check-grid residuals in ``fit``."""
    lines = (0.0, float(image.lines - 1))
    columns = image.chip_range(chip) if chip is not None else (0.0, float(image.columns - 1))
    fit_g = ground_grid(image, lines, columns, heights_of(height_range_m, FIT_GRID[2]), FIT_GRID[:2], chip)
    check_g = ground_grid(image, lines, columns, heights_of(height_range_m, CHECK_GRID[2], True), CHECK_GRID[:2], chip, cell_centres=True)
    rpc = fit_rpc_best(fit_g, check_g)
    chip_id = None if chip is None else (image.image.camera.chips[chip].id if image.image.camera.chips else "1")
    rpc.fit = fit_record(rpc, fit_g, check_g, height_range_m, image=image.id, chip=chip_id, model=image.kind)
    rpc.fit["warnings"] = []
    if chip is None and image.n_chips > 1:
        res = rpc.fit["check_residuals"]
        if res["rms_px"] > MULTI_CHIP_WARNING_PX:
            rpc.fit["warnings"].append(
                f"image {image.id!r} has {image.n_chips} CCD chips whose offsets make its raw geometry jump at the chip "
                f"boundaries: one RPC for the whole image is off by {res['rms_px']:.3g} px RMS ({res['max_px']:.3g} px max) "
                "on the check grid. Use `pba export-rpc --per-chip` (one RPC per chip) or `pba resample` (ideal single-array image)."
            )
    return rpc


def ground_points(lon: np.ndarray, lat: np.ndarray, h: np.ndarray) -> np.ndarray:
    """ECEF of geodetic points (helper for callers that verify an RPC against the rigorous model)."""
    return geodetic_to_ecef(np.column_stack([lon, lat, h]))
