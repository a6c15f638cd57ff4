"""RPC00B (rational polynomial coefficients): the model, its least-squares fit and its files' fields.

The pure mathematics shared by the simulator (:mod:`solver.simulate.rpc`, RPCs fitted to the
true geometry) and the GIS outputs (:mod:`solver.gis.rpc_fit`, RPCs fitted to the adjusted
model; :mod:`solver.importers.rpc`, RPCs read through GDAL): no adjustment import.

RPC00B conventions (NITF STDI-0002, GDAL): normalised ``X = (lon - LONG_OFF) / LONG_SCALE``,
``Y`` latitude and ``Z`` height likewise (degrees, ellipsoidal metres on WGS 84); the 20 terms
of each cubic in the RPC00B order :data:`TERMS`; line and sample are normalised the same way.

Pixel convention. Image coordinates of an :class:`RPC` are those of the **centre** of the
top-left pixel at (0, 0): the solver's convention and RPC00B's (what the files hold). GDAL's
RPC transformer works with the top-left pixel's **corner** at (0, 0) and adds half a pixel to
what the polynomials give: GDAL's (line, column) = ours + 0.5 (tests/solver/gis/test_gis_rpc.py checks
this through GDAL). The job's ``images[].rpc`` object (:meth:`RPC.to_job`, :meth:`RPC.from_job`)
says which convention its offsets are in (``pixel_convention``: ``"center"``, the default, or
``"gdal"``, where ``line_off`` and ``samp_off`` are half a pixel larger); :meth:`RPC.from_job`
converts to ours once.

The fit (Tao & Hu 2001, PE&RS 67(12)): the 78 coefficients by iteratively reweighted,
Tikhonov-regularised linear least squares of ``N(X) - r D(X) = 0`` weighted by ``1 / D(X)``
of the previous iteration, from a grid of virtual control points (image position, geodetic
position) spanning the image and a height range.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

# RPC00B term order: 1, L, P, H, LP, LH, PH, L^2, P^2, H^2, PLH, L^3, LP^2, LH^2, L^2P, P^3,
# PH^2, L^2H, P^2H, H^3 with L longitude, P latitude, H height (normalised)
TERMS = "1 L P H LP LH PH LL PP HH PLH LLL LPP LHH LLP PPP PHH LLH PPH HHH".split()

REGULARISATION = 1e-8  # Tikhonov weight on the normalised coefficients (relative to unit weights)
# A lighter weight for smooth geometries: the 1e-8 weight alone costs ~1e-4 px on a 2400-line
# image and ~8e-4 px on a 16000-line one (the fit of an RPC to a grid made by an RPC is then
# 8e-4 px instead of 2e-10); 1e-12 leaves ~1e-7 px on simulated PRISM images and the GIS test
# scenes, ~3e-6 px on CBERS. Where the geometry is not smooth (a raw multi-chip image's jumps)
# the light weight lets the denominators wander (poles between the grid nodes: 9 px RMS on the
# check grid instead of 0.9 px): :func:`fit_rpc_best` tries both and keeps the better on a
# check grid.
FINE_REGULARISATION = 1e-12
PIXEL_CONVENTIONS = ("center", "gdal")
GDAL_SHIFT_PX = 0.5  # GDAL's transformer coordinates = ours + 0.5 px (pixel corner at (0, 0))


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
        """From GDAL's RPC metadata domain (keys in any case; rasterio's ``RPC.to_gdal()``)."""
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

    def to_job(self, pixel_convention: str = "center") -> dict[str, Any]:
        """The job's ``images[].rpc`` object: GDAL's field names in lower case, 20 coefficients
        each, ``pixel_convention`` ``"center"`` (ours, the default) or ``"gdal"`` (``line_off``
        and ``samp_off`` half a pixel larger, what GDAL's transformer gives)."""
        if pixel_convention not in PIXEL_CONVENTIONS:
            raise ValueError(f"pixel_convention must be one of {', '.join(PIXEL_CONVENTIONS)}, not {pixel_convention!r}")
        shift = GDAL_SHIFT_PX if pixel_convention == "gdal" else 0.0
        out: dict[str, Any] = {
            "line_off": float(self.line_off) + shift, "samp_off": float(self.samp_off) + shift,
            "lat_off": float(self.lat_off), "long_off": float(self.long_off), "height_off": float(self.height_off),
            "line_scale": float(self.line_scale), "samp_scale": float(self.samp_scale),
            "lat_scale": float(self.lat_scale), "long_scale": float(self.long_scale), "height_scale": float(self.height_scale),
            "line_num_coeff": [float(v) for v in self.line_num], "line_den_coeff": [float(v) for v in self.line_den],
            "samp_num_coeff": [float(v) for v in self.samp_num], "samp_den_coeff": [float(v) for v in self.samp_den],
            "err_bias": float(self.err_bias), "err_rand": float(self.err_rand),
            "pixel_convention": pixel_convention,
        }
        return out

    @classmethod
    def from_job(cls, obj: dict[str, Any]) -> "RPC":
        """From the job's ``images[].rpc`` object, converted to our pixel convention (pixel
        centres) when ``pixel_convention`` is ``"gdal"``. Raises ``KeyError`` for a missing
        field and ``ValueError`` for a bad one (the schema validates jobs before this)."""
        conv = obj.get("pixel_convention", "center")
        if conv not in PIXEL_CONVENTIONS:
            raise ValueError(f"pixel_convention must be one of {', '.join(PIXEL_CONVENTIONS)}, not {conv!r}")
        shift = GDAL_SHIFT_PX if conv == "gdal" else 0.0

        def coeffs(key: str) -> np.ndarray:
            v = np.asarray(obj[key], dtype=float)
            if v.shape != (20,):
                raise ValueError(f"{key}: 20 coefficients expected, got {v.size}")
            return v

        return cls(
            float(obj["line_off"]) - shift, float(obj["samp_off"]) - shift,
            float(obj["lat_off"]), float(obj["long_off"]), float(obj["height_off"]),
            float(obj["line_scale"]), float(obj["samp_scale"]),
            float(obj["lat_scale"]), float(obj["long_scale"]), float(obj["height_scale"]),
            coeffs("line_num_coeff"), coeffs("line_den_coeff"), coeffs("samp_num_coeff"), coeffs("samp_den_coeff"),
            float(obj.get("err_bias", -1.0)), float(obj.get("err_rand", -1.0)),
        )


def fit_ratio(t: np.ndarray, r: np.ndarray, iterations: int = 6, regularisation: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Numerator (20) and denominator (20, first = 1) of ``r ~ t @ num / t @ den`` by
    iteratively reweighted regularised least squares (normalised ``t`` and ``r``; Tikhonov
    weight ``regularisation``, default :data:`REGULARISATION`)."""
    n = len(r)
    a = np.hstack([t, -r[:, None] * t[:, 1:]])  # unknowns: num (20), den[1:] (19)
    w = np.ones(n)
    reg = np.sqrt((REGULARISATION if regularisation is None else regularisation) * n) * np.eye(39)
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


def fit_rpc(grid: GroundGrid, regularisation: float | None = None) -> RPC:
    """RPC00B least-squares fit to a ground grid (normalisation from the grid's extent; points
    with a non-finite longitude or latitude are left out; Tikhonov weight ``regularisation``,
    default :data:`REGULARISATION`)."""
    ok = np.isfinite(grid.lon) & np.isfinite(grid.lat)

    def norm(v: np.ndarray) -> tuple[float, float]:
        lo, hi = float(np.min(v[ok])), float(np.max(v[ok]))
        return (lo + hi) / 2.0, max((hi - lo) / 2.0, 1e-9)

    (lo_off, lo_sc), (la_off, la_sc), (h_off, h_sc) = norm(grid.lon), norm(grid.lat), norm(grid.h)
    (l_off, l_sc), (s_off, s_sc) = norm(grid.line), norm(grid.column)
    h_sc = max(h_sc, 1.0)
    t = monomials((grid.lon[ok] - lo_off) / lo_sc, (grid.lat[ok] - la_off) / la_sc, (grid.h[ok] - h_off) / h_sc)
    ln, ld = fit_ratio(t, (grid.line[ok] - l_off) / l_sc, regularisation=regularisation)
    sn, sd = fit_ratio(t, (grid.column[ok] - s_off) / s_sc, regularisation=regularisation)
    return RPC(l_off, s_off, la_off, lo_off, h_off, l_sc, s_sc, la_sc, lo_sc, h_sc, ln, ld, sn, sd)


def fit_rpc_best(grid: GroundGrid, check: GroundGrid) -> RPC:
    """The better (RMS on ``check``) of the fits with :data:`FINE_REGULARISATION` and
    :data:`REGULARISATION`; ``fit["regularisation"]`` says which."""
    best = None
    for reg in (FINE_REGULARISATION, REGULARISATION):
        rpc = fit_rpc(grid, reg)
        rms = residuals_px(rpc, check)["rms_px"]
        if best is None or rms < best[0]:
            best = (rms, rpc, reg)
    rpc = best[1]
    rpc.fit = {"regularisation": best[2]}
    return rpc


FIT_GRID = (21, 21, 7)  # lines x columns x heights of the fit grid
CHECK_GRID = (20, 20, 6)  # check grid: cells' centres of the fit grid, heights between its layers


def fit_record(rpc: RPC, fit_grid: GroundGrid, check_grid: GroundGrid, height_range_m: tuple[float, float], **fields: Any) -> dict[str, Any]:
    """``rpc.fit`` extended with ``fields``, the height range (m), the grid sizes and the
    residuals (pixels) on the fit and check grids: the record every RPC fit reports."""
    return {
        **rpc.fit,
        **fields,
        "height_range_m": list(height_range_m),
        "fit_grid": list(FIT_GRID),
        "check_grid": list(CHECK_GRID),
        "fit_residuals": residuals_px(rpc, fit_grid),
        "check_residuals": residuals_px(rpc, check_grid),
    }


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
    """``k`` heights spanning the range (metres), or the ``k`` centres of its equal cells (``between``)."""
    lo, hi = height_range_m
    if between:
        step = (hi - lo) / k
        return lo + step * (np.arange(k) + 0.5)
    return np.linspace(lo, hi, k)


BIAS_NAMES = ("a0", "a_line", "a_column", "b0", "b_line", "b_column")
# the parameters each RPC bias model estimates (the others are 0)
BIAS_MODELS = {
    "RPC-SHIFT": ("a0", "b0"),
    "RPC-DRIFT": ("a0", "a_line", "b0", "b_line"),
    "RPC-AFFINE": BIAS_NAMES,
}


@dataclass(frozen=True)
class RpcBias:
    """Image-space bias of an RPC (Grodecki & Dial 2003), evaluated at the **observed**
    coordinates, our pixel convention (pixels; ``a_line`` etc. pixels per pixel)::

        line_obs   = RPC_line(lat, lon, h)   + a0 + a_line * line_obs + a_column * column_obs
        column_obs = RPC_column(lat, lon, h) + b0 + b_line * line_obs + b_column * column_obs
    """

    a0: float = 0.0
    a_line: float = 0.0
    a_column: float = 0.0
    b0: float = 0.0
    b_line: float = 0.0
    b_column: float = 0.0

    @classmethod
    def from_parameters(cls, values: dict[str, float]) -> "RpcBias":
        """From ``{name: value}`` (names of :data:`BIAS_NAMES`; absent ones are 0)."""
        unknown = sorted(set(values) - set(BIAS_NAMES))
        if unknown:
            raise ValueError(f"unknown RPC bias parameter(s) {', '.join(unknown)} (known: {', '.join(BIAS_NAMES)})")
        return cls(**{k: float(v) for k, v in values.items()})

    def as_dict(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in BIAS_NAMES}

    @property
    def is_separable(self) -> bool:
        """No cross terms: the bias folds exactly into the RPC's offsets and scales."""
        return self.a_column == 0.0 and self.b_line == 0.0

    def to_rpc(self, line_obs: np.ndarray, column_obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What the RPC gives at observed image coordinates: observed minus the bias."""
        lo, co = np.asarray(line_obs, float), np.asarray(column_obs, float)
        return (
            lo - (self.a0 + self.a_line * lo + self.a_column * co),
            co - (self.b0 + self.b_line * lo + self.b_column * co),
        )

    def observed(self, rpc_line: np.ndarray, rpc_column: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Observed image coordinates of what the RPC gives (the 2 x 2 linear system solved)."""
        rl = np.asarray(rpc_line, float) + self.a0
        rc = np.asarray(rpc_column, float) + self.b0
        m11, m12, m21, m22 = 1.0 - self.a_line, -self.a_column, -self.b_line, 1.0 - self.b_column
        det = m11 * m22 - m12 * m21
        return (m22 * rl - m12 * rc) / det, (m11 * rc - m21 * rl) / det

    def fold(self, rpc: "RPC") -> "RPC":
        """The RPC with this bias folded in (exact; only without cross terms, :attr:`is_separable`):
        ``line_obs = (RPC_line + a0) / (1 - a_line)``, so ``line_off`` becomes
        ``(line_off + a0) / (1 - a_line)`` and ``line_scale`` ``line_scale / (1 - a_line)``;
        columns likewise with ``b0``, ``b_column``."""
        if not self.is_separable:
            raise ValueError("a bias with cross terms (a_column, b_line) does not fold into one RPC: refit it")
        kl, kc = 1.0 - self.a_line, 1.0 - self.b_column
        return replace(
            rpc,
            line_off=(rpc.line_off + self.a0) / kl, line_scale=rpc.line_scale / kl,
            samp_off=(rpc.samp_off + self.b0) / kc, samp_scale=rpc.samp_scale / kc,
            fit=dict(rpc.fit),
        )
