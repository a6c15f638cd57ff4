"""RPC00B (rational polynomial coefficients) fitted to the adjusted rigorous model.

Terrain-independent fit (Tao & Hu 2001, "A comprehensive study of the rational function model
for photogrammetric processing", PE&RS 67(12)): a 3-D grid of virtual control points is made by
intersecting the rays of a regular grid of image positions with several constant ellipsoidal
heights spanning the job's height range (plus a margin) or a DEM's; the 78 coefficients are
estimated by iteratively reweighted, Tikhonov-regularised linear least squares (the linearised
form ``N(X) - r D(X) = 0`` weighted by ``1 / D(X)`` of the previous iteration). The fit is
assessed on an independent check grid (image positions half-way between the fit grid's, heights
between its layers), reported as residuals in pixels.

RPC00B conventions (NITF STDI-0002, GDAL): normalised ``X = (lon - LONG_OFF) / LONG_SCALE``,
``Y`` latitude and ``Z`` height likewise (degrees, ellipsoidal metres on WGS 84); the 20 terms
of each cubic in the RPC00B order :data:`TERMS`; line and sample are normalised the same way.
Image coordinates of an RPC are those of the **centre** of the top-left pixel at (0, 0), the
solver's convention; GDAL's transformer adds half a pixel (pixel corners), see
:mod:`solver.gis.rpc_io`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solver.geometry.geodesy import ecef_to_geodetic, geodetic_to_ecef

# RPC00B term order: 1, L, P, H, LP, LH, PH, L^2, P^2, H^2, PLH, L^3, LP^2, LH^2, L^2P, P^3,
# PH^2, L^2H, P^2H, H^3 with L longitude, P latitude, H height (normalised)
TERMS = "1 L P H LP LH PH LL PP HH PLH LLL LPP LHH LLP PPP PHH LLH PPH HHH".split()

FIT_GRID = (21, 21, 7)  # lines x columns x heights of the fit grid
CHECK_GRID = (20, 20, 6)  # check grid: cells' centres of the fit grid, heights between its layers
HEIGHT_MARGIN_M = 100.0
REGULARISATION = 1e-8  # Tikhonov weight on the normalised coefficients (relative to unit weights)


def monomials(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(n, 20) RPC00B terms of normalised longitude ``x``, latitude ``y`` and height ``z``."""
    one = np.ones_like(x)
    return np.column_stack([
        one, x, y, z, x * y, x * z, y * z, x * x, y * y, z * z, x * y * z, x**3, x * y * y, x * z * z,
        x * x * y, y**3, y * z * z, x * x * z, y * y * z, z**3,
    ])


@dataclass
class RPC:
    """One RPC00B model; image coordinates with the origin at the centre of the top-left pixel."""

    line_off: float
    samp_off: float
    lat_off: float
    long_off: float
    height_off: float
    line_scale: float
    samp_scale: float
    lat_scale: float
    long_scale: float
    height_scale: float
    line_num: np.ndarray
    line_den: np.ndarray
    samp_num: np.ndarray
    samp_den: np.ndarray
    err_bias: float = -1.0  # metres, -1: unknown (RPC00B)
    err_rand: float = -1.0
    fit: dict[str, Any] = field(default_factory=dict)  # fit and check residuals (px), grid sizes

    def project(self, lon: np.ndarray, lat: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(line, sample) of geodetic points (degrees, ellipsoidal metres), pixel centres."""
        t = monomials((np.asarray(lon, float) - self.long_off) / self.long_scale, (np.asarray(lat, float) - self.lat_off) / self.lat_scale, (np.asarray(h, float) - self.height_off) / self.height_scale)
        line = t @ self.line_num / (t @ self.line_den)
        samp = t @ self.samp_num / (t @ self.samp_den)
        return line * self.line_scale + self.line_off, samp * self.samp_scale + self.samp_off

    def to_gdal(self) -> dict[str, str]:
        """GDAL's RPC metadata domain (keys of GDAL's RPC reader, values as text)."""

        def coeffs(v: np.ndarray) -> str:
            return " ".join(f"{x:.15e}" for x in v)

        return {
            "ERR_BIAS": f"{self.err_bias:.6f}", "ERR_RAND": f"{self.err_rand:.6f}",
            "LINE_OFF": f"{self.line_off:.10f}", "SAMP_OFF": f"{self.samp_off:.10f}",
            "LAT_OFF": f"{self.lat_off:.12f}", "LONG_OFF": f"{self.long_off:.12f}", "HEIGHT_OFF": f"{self.height_off:.6f}",
            "LINE_SCALE": f"{self.line_scale:.10f}", "SAMP_SCALE": f"{self.samp_scale:.10f}",
            "LAT_SCALE": f"{self.lat_scale:.12f}", "LONG_SCALE": f"{self.long_scale:.12f}", "HEIGHT_SCALE": f"{self.height_scale:.6f}",
            "LINE_NUM_COEFF": coeffs(self.line_num), "LINE_DEN_COEFF": coeffs(self.line_den),
            "SAMP_NUM_COEFF": coeffs(self.samp_num), "SAMP_DEN_COEFF": coeffs(self.samp_den),
        }

    @classmethod
    def from_gdal(cls, md: dict[str, str]) -> "RPC":
        f = {k.upper(): v for k, v in md.items()}

        def num(key: str, default: float | None = None) -> float:
            if key not in f:
                if default is None:
                    raise KeyError(key)
                return default
            return float(str(f[key]).split()[0])

        def coeffs(key: str) -> np.ndarray:
            v = np.array([float(x) for x in str(f[key]).split()])
            if v.shape != (20,):
                raise ValueError(f"{key}: 20 coefficients expected, got {v.size}")
            return v

        return cls(
            num("LINE_OFF"), num("SAMP_OFF"), num("LAT_OFF"), num("LONG_OFF"), num("HEIGHT_OFF"),
            num("LINE_SCALE"), num("SAMP_SCALE"), num("LAT_SCALE"), num("LONG_SCALE"), num("HEIGHT_SCALE"),
            coeffs("LINE_NUM_COEFF"), coeffs("LINE_DEN_COEFF"), coeffs("SAMP_NUM_COEFF"), coeffs("SAMP_DEN_COEFF"),
            num("ERR_BIAS", -1.0), num("ERR_RAND", -1.0),
        )


def _fit_ratio(t: np.ndarray, r: np.ndarray, iterations: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Numerator (20) and denominator (20, first = 1) of ``r ~ t @ num / t @ den`` by
    iteratively reweighted regularised least squares (normalised ``t`` and ``r``)."""
    n = len(r)
    a = np.hstack([t, -r[:, None] * t[:, 1:]])  # unknowns: num (20), den[1:] (19)
    w = np.ones(n)
    reg = np.sqrt(REGULARISATION * n) * np.eye(39)
    num = np.zeros(20)
    den = np.zeros(20)
    den[0] = 1.0
    for _ in range(iterations):
        aw = a * w[:, None]
        x = np.linalg.lstsq(np.vstack([aw, reg]), np.concatenate([r * w, np.zeros(39)]), rcond=None)[0]
        num, den = x[:20], np.concatenate([[1.0], x[20:]])
        d = t @ den
        w = 1.0 / np.abs(d)
    return num, den


@dataclass
class GroundGrid:
    """Virtual control points: image positions (pixel centres) and geodetic coordinates."""

    line: np.ndarray
    column: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    h: np.ndarray


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


def fit_rpc(grid: GroundGrid) -> RPC:
    """RPC00B least-squares fit to a ground grid (normalisation from the grid's extent)."""
    ok = np.isfinite(grid.lon) & np.isfinite(grid.lat)

    def norm(v: np.ndarray) -> tuple[float, float]:
        lo, hi = float(np.min(v[ok])), float(np.max(v[ok]))
        return (lo + hi) / 2.0, max((hi - lo) / 2.0, 1e-9)

    (lo_off, lo_sc), (la_off, la_sc), (h_off, h_sc) = norm(grid.lon), norm(grid.lat), norm(grid.h)
    (l_off, l_sc), (s_off, s_sc) = norm(grid.line), norm(grid.column)
    h_sc = max(h_sc, 1.0)
    t = monomials((grid.lon[ok] - lo_off) / lo_sc, (grid.lat[ok] - la_off) / la_sc, (grid.h[ok] - h_off) / h_sc)
    ln, ld = _fit_ratio(t, (grid.line[ok] - l_off) / l_sc)
    sn, sd = _fit_ratio(t, (grid.column[ok] - s_off) / s_sc)
    return RPC(l_off, s_off, la_off, lo_off, h_off, l_sc, s_sc, la_sc, lo_sc, h_sc, ln, ld, sn, sd)


def residuals_px(rpc: RPC, grid: GroundGrid) -> dict[str, float]:
    """RMS and maximum of the RPC's image error on a grid (pixels: line, column, total)."""
    line, col = rpc.project(grid.lon, grid.lat, grid.h)
    dl, dc = line - grid.line, col - grid.column
    ok = np.isfinite(dl) & np.isfinite(dc)
    dl, dc = dl[ok], dc[ok]
    tot = np.hypot(dl, dc)
    return {
        "n": int(ok.sum()),
        "rms_line_px": float(np.sqrt(np.mean(dl**2))), "rms_column_px": float(np.sqrt(np.mean(dc**2))),
        "rms_px": float(np.sqrt(np.mean(tot**2))), "max_px": float(np.max(tot)),
    }


def heights_of(height_range_m: tuple[float, float], k: int, between: bool = False) -> np.ndarray:
    lo, hi = height_range_m
    if between:
        step = (hi - lo) / k
        return lo + step * (np.arange(k) + 0.5)
    return np.linspace(lo, hi, k)


MULTI_CHIP_WARNING_PX = 0.05


def fit_image_rpc(image, height_range_m: tuple[float, float], chip: int | None = None) -> RPC:
    """RPC of one adjusted image (:class:`solver.gis.model.AdjustedImage`), of the whole image
    or of one chip's columns (``chip``), with its fit and check-grid residuals in ``fit``."""
    lines = (0.0, float(image.lines - 1))
    columns = image.chip_range(chip) if chip is not None else (0.0, float(image.columns - 1))
    fit_g = ground_grid(image, lines, columns, heights_of(height_range_m, FIT_GRID[2]), FIT_GRID[:2], chip)
    rpc = fit_rpc(fit_g)
    check_g = ground_grid(image, lines, columns, heights_of(height_range_m, CHECK_GRID[2], True), CHECK_GRID[:2], chip, cell_centres=True)
    rpc.fit = {
        "image": image.id,
        "chip": None if chip is None else (image.image.camera.chips[chip].id if image.image.camera.chips else "1"),
        "model": image.kind,
        "height_range_m": list(height_range_m),
        "fit_grid": list(FIT_GRID),
        "check_grid": list(CHECK_GRID),
        "fit_residuals": residuals_px(rpc, fit_g),
        "check_residuals": residuals_px(rpc, check_g),
        "warnings": [],
    }
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
