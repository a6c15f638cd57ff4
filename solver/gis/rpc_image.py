"""The adjusted model of an RPC image (issue 17): the delivered RPC00B plus the adjusted bias,
and the refined RPC that GDAL reads.

An RPC image's adjusted model is (Grodecki & Dial 2003; :class:`solver.geometry.rpc.RpcBias`,
pixel centres)::

    line_obs   = RPC_line(lat, lon, h)   + a0 + a_line * line_obs + a_column * column_obs
    column_obs = RPC_column(lat, lon, h) + b0 + b_line * line_obs + b_column * column_obs

with ``a0 .. b_column`` the report's ``images[i].parameters`` (absent ones 0). Ground to image:
the RPC, then the 2 x 2 linear system (exact). Image to ground at a height: the observed
position minus the bias is what the RPC gives; longitude and latitude by Newton's method on
the RPC (numerical Jacobian, to 1e-9 px), a DEM by iterating the height.

The image's extent: an RPC image has no camera, so its lines and columns are those of the RPC's
normalisation domain, ``line_off +- line_scale`` and ``samp_off +- samp_scale`` (the whole image
for the RPCs we fit, and for vendors' RPCs as a rule), moved by the bias (the observed
coordinates of the domain's corners; first line and column at least 0), unless the size is
known (:meth:`RpcImage.with_size`: ``pba ortho`` takes the raster's).

The refined RPC (:func:`refined_rpc`): without cross terms (``a_column = b_line = 0``) the bias
folds exactly into the offsets and scales (:meth:`RpcBias.fold`); otherwise the two rational
functions would need each other's denominators, so an RPC00B is refitted to the adjusted model
on the same terrain-independent grids as the rigorous models' RPCs (:mod:`solver.gis.rpc_fit`;
the better of two Tikhonov weights on the check grid, :func:`solver.geometry.rpc.fit_rpc_best`),
image positions to the ground at each height by the iteration above. Both are checked against
the adjusted model on the independent check grid (``fit["check_residuals"]``, pixels).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np

from solver.geometry.geodesy import ecef_to_geodetic, geodetic_to_ecef
from solver.geometry.rpc import BIAS_NAMES, CHECK_GRID, FIT_GRID, RPC, GroundGrid, RpcBias, fit_record, fit_rpc_best, heights_of

HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (lon_deg, lat_deg) -> ellipsoidal height m

NEWTON_TOL_PX = 1e-9
STEP_DEG = 1e-6  # finite-difference step of the Jacobian (~0.1 m)


@dataclass
class RpcImage:
    """One adjusted RPC image: its delivered RPC (pixel centres) and the adjusted bias."""

    id: str
    rpc: RPC
    bias: RpcBias
    kind: str  # RPC-SHIFT, RPC-DRIFT or RPC-AFFINE
    report_entry: dict[str, Any] | None = None  # the report's images[i] (covariance of the bias)
    size: tuple[int, int] | None = None  # (lines, columns) when known (a raster's); else from the RPC

    def with_size(self, lines: int, columns: int) -> "RpcImage":
        """The same image with its size known (e.g. its raster's)."""
        return replace(self, size=(int(lines), int(columns)))

    def _extent(self) -> tuple[np.ndarray, np.ndarray]:
        """Observed (line, column) of the corners of the RPC's normalisation domain."""
        r = self.rpc
        rl = r.line_off + r.line_scale * np.array([-1.0, -1.0, 1.0, 1.0])
        rc = r.samp_off + r.samp_scale * np.array([-1.0, 1.0, -1.0, 1.0])
        return self.bias.observed(rl, rc)

    @property
    def line_range(self) -> tuple[float, float]:
        if self.size is not None:
            return 0.0, float(self.size[0] - 1)
        line, _ = self._extent()
        return max(float(line.min()), 0.0), float(line.max())

    @property
    def column_range(self) -> tuple[float, float]:
        if self.size is not None:
            return 0.0, float(self.size[1] - 1)
        _, col = self._extent()
        return max(float(col.min()), 0.0), float(col.max())

    @property
    def lines(self) -> int:
        return self.size[0] if self.size is not None else int(round(self.line_range[1])) + 1

    @property
    def columns(self) -> int:
        return self.size[1] if self.size is not None else int(round(self.column_range[1])) + 1

    @property
    def n_chips(self) -> int:
        return 1

    def chip_range(self, k: int) -> tuple[float, float]:
        return self.column_range

    def ground_to_image(self, ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(line, column, chip 0) of ECEF points (n, 3): the RPC plus the bias."""
        llh = ecef_to_geodetic(np.atleast_2d(np.asarray(ecef, float)))
        line, col = self.bias.observed(*self.rpc.project(llh[:, 0], llh[:, 1], llh[:, 2]))
        ok = np.isfinite(line) & np.isfinite(col)
        return line, col, np.where(ok, 0, -1)

    def _lonlat(self, rl: np.ndarray, rc: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Longitude and latitude where the RPC gives (rl, rc) at height h (Newton)."""
        r = self.rpc
        lon = np.full(rl.shape, r.long_off)
        lat = np.full(rl.shape, r.lat_off)
        for _ in range(30):
            fl, fc = r.project(lon, lat, h)
            el, ec = fl - rl, fc - rc
            if np.all(np.abs(el[np.isfinite(el)]) < NEWTON_TOL_PX) and np.all(np.abs(ec[np.isfinite(ec)]) < NEWTON_TOL_PX):
                break
            lp, cp = r.project(lon + STEP_DEG, lat, h)
            lm, cm = r.project(lon - STEP_DEG, lat, h)
            j11, j21 = (lp - lm) / (2 * STEP_DEG), (cp - cm) / (2 * STEP_DEG)
            lp, cp = r.project(lon, lat + STEP_DEG, h)
            lm, cm = r.project(lon, lat - STEP_DEG, h)
            j12, j22 = (lp - lm) / (2 * STEP_DEG), (cp - cm) / (2 * STEP_DEG)
            det = j11 * j22 - j12 * j21
            lon = lon - (j22 * el - j12 * ec) / det
            lat = lat - (j11 * ec - j21 * el) / det
        return lon, lat

    def image_to_ground(
        self,
        line: np.ndarray,
        column: np.ndarray,
        height_m: np.ndarray | float | None = None,
        height_fn: HeightFn | None = None,
        chip: int | None = None,
    ) -> np.ndarray:
        """ECEF points (n, 3) of image points at the ellipsoidal height ``height_m`` or on the
        surface ``height_fn(lon_deg, lat_deg)`` (a DEM, by iterating the height)."""
        if (height_m is None) == (height_fn is None):
            raise ValueError("give exactly one of height_m and height_fn")
        line = np.atleast_1d(np.asarray(line, float))
        column = np.atleast_1d(np.asarray(column, float))
        rl, rc = self.bias.to_rpc(line, column)
        if height_fn is None:
            h = np.broadcast_to(np.asarray(height_m, float), line.shape).astype(float)
            lon, lat = self._lonlat(rl, rc, h)
        else:
            h = np.full(line.shape, self.rpc.height_off)
            for _ in range(30):
                lon, lat = self._lonlat(rl, rc, h)
                new = np.asarray(height_fn(lon, lat), float)
                done = np.nanmax(np.abs(new - h)) < 1e-4 if np.any(np.isfinite(new)) else True
                h = new
                if done:
                    break
            lon, lat = self._lonlat(rl, rc, h)
        return geodetic_to_ecef(np.column_stack([lon, lat, h]))


def rpc_image(job_image: dict[str, Any], report_image: dict[str, Any] | None) -> RpcImage:
    """The adjusted RPC image of a job's image entry (``rpc``, ``model``) and its report entry
    (``parameters`` [{name, value, ...}], names of :data:`BIAS_NAMES`; no entry: no bias)."""
    values = {}
    for p in (report_image or {}).get("parameters", []):
        if p.get("name") in BIAS_NAMES and p.get("value") is not None:
            values[p["name"]] = float(p["value"])
    model = job_image.get("model") or {}
    kind = model.get("name") if isinstance(model, dict) else str(model)
    return RpcImage(str(job_image["id"]), RPC.from_job(job_image["rpc"]), RpcBias.from_parameters(values), kind or "RPC", report_image)




def _grid(image: RpcImage, heights: np.ndarray, n: tuple[int, int], cell_centres: bool) -> GroundGrid:
    """Image positions of an ``n[0] x n[1]`` grid over the image at each height, and their
    ground points by the adjusted model."""
    def axis(lo: float, hi: float, k: int) -> np.ndarray:
        if cell_centres:
            return lo + (hi - lo) / k * (np.arange(k) + 0.5)
        return np.linspace(lo, hi, k)

    ll, cc = np.meshgrid(axis(*image.line_range, n[0]), axis(*image.column_range, n[1]), indexing="ij")
    ll, cc = ll.ravel(), cc.ravel()
    m = len(heights)
    line, col, h = np.tile(ll, m), np.tile(cc, m), np.repeat(np.asarray(heights, float), ll.size)
    llh = ecef_to_geodetic(image.image_to_ground(line, col, height_m=h))
    return GroundGrid(line, col, llh[:, 0], llh[:, 1], llh[:, 2])


def refined_rpc(image: RpcImage, height_range_m: tuple[float, float]) -> RPC:
    """The RPC00B of the adjusted RPC image: the bias folded in (exact, no cross terms) or an
    RPC refitted to the adjusted model; ``fit`` holds the method and the residuals (pixels)
    against the adjusted model on the fit and check grids."""
    fit_g = _grid(image, heights_of(height_range_m, FIT_GRID[2]), FIT_GRID[:2], False)
    check_g = _grid(image, heights_of(height_range_m, CHECK_GRID[2], True), CHECK_GRID[:2], True)
    if image.bias.is_separable:
        rpc, method = image.bias.fold(image.rpc), "folded"
    else:
        rpc, method = fit_rpc_best(fit_g, check_g), "refit"
    rpc = replace(rpc, err_bias=-1.0, err_rand=-1.0, fit=dict(rpc.fit))
    rpc.fit = fit_record(rpc, fit_g, check_g, height_range_m, image=image.id, chip=None, model=image.kind, method=method, bias=image.bias.as_dict())
    rpc.fit["warnings"] = []
    return rpc
