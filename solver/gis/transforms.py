"""Ground <-> image transforms of tables of points with the adjusted rigorous model.

Tables are lists of rows (dicts of column name -> text or number), as read from CSV.

- ground to image: the ground columns are the CRS's axes (EPSG:4979, the default: ``lon``,
  ``lat``, ``height`` in degrees and ellipsoidal metres; another CRS: its axis abbreviations,
  lower case, e.g. ``e``, ``n`` for UTM, plus ``height`` (ellipsoidal metres) when the CRS is
  2-D); ``line``, ``column`` are added (pixels, origin at the centre of the top-left pixel).
- image to ground: ``line``, ``column`` and ``height`` (ellipsoidal metres; or a DEM) give the
  CRS's columns.

Optional propagated standard deviations: the image's own parameter covariance from the report
(``images[].covariance``, a-posteriori) carried through the transform by central differences;
the covariance of cameras (self-calibration) and passes is not included. Ground to image adds
``sigma_line_px``, ``sigma_column_px``; image to ground adds ``sigma_east_m``, ``sigma_north_m``
(horizontal, on the given height surface).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable

import numpy as np

from solver.geometry.geodesy import GEODETIC_CRS, ecef_to_geodetic, enu_rotation, from_ecef, parse_crs, to_ecef
from solver.geometry.rpc import BIAS_NAMES
from solver.gis.model import AdjustedImage, HeightFn
from solver.gis.rpc_image import RpcImage

_ABBREV = {"lon": "lon", "long": "lon", "lat": "lat", "h": "height"}


class TableError(ValueError):
    """A row or column of the input table is unusable (the message names the row and column)."""


def ground_columns(crs: str = GEODETIC_CRS) -> list[str]:
    """Column names of ground coordinates in ``crs``, x/y order (then height)."""
    c = parse_crs(crs)
    if c.is_geocentric:
        return ["x", "y", "z"]
    axes = c.axis_info
    names = [_ABBREV.get(a.abbrev.lower(), a.abbrev.lower()) for a in axes]
    # traditional GIS order (always_xy): longitude/easting first
    if len(names) >= 2 and axes[0].direction in ("north", "south"):
        names[0], names[1] = names[1], names[0]
    if len(names) == 2:
        names.append("height")
    return names


def _column(rows: list[dict[str, Any]], name: str) -> np.ndarray:
    out = np.empty(len(rows))
    for i, r in enumerate(rows):
        if name not in r or r[name] in (None, ""):
            raise TableError(f"row {i + 1}: column {name!r} missing (columns needed: see the header)")
        try:
            out[i] = float(r[name])
        except (TypeError, ValueError):
            raise TableError(f"row {i + 1}, column {name!r}: {r[name]!r} is not a number") from None
        if not np.isfinite(out[i]):
            raise TableError(f"row {i + 1}, column {name!r}: not a finite number")
    return out


def _with_parameters(image: AdjustedImage, delta: np.ndarray, fn: Callable[[], np.ndarray]) -> np.ndarray:
    """``fn()`` evaluated with the image's free parameters moved by ``delta`` (internal units)."""
    img = image.image
    model = image.model
    keep = img.params.copy()
    base = img.base.copy()
    try:
        img.params[:] = keep + delta
        img.base[img.free_idx] = img.params
        model.refresh_tables()
        return fn()
    finally:
        img.params[:] = keep
        img.base[:] = base
        model.refresh_tables()


def _propagate_rpc(image: RpcImage, entry: dict[str, Any], fn: Callable[[], np.ndarray]) -> np.ndarray | None:
    """:func:`_propagate` for an RPC image: the covariance of its bias parameters (px, px/px)."""
    cov = np.asarray(entry["covariance"]["matrix"], float)
    names = entry["covariance"]["names"]
    if not set(names) <= set(BIAS_NAMES):
        return None
    sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    keep = image.bias
    cols = []
    try:
        for j, name in enumerate(names):
            step = 1e-3 * sig[j]
            if step == 0.0:
                cols.append(None)
                continue
            image.bias = replace(keep, **{name: getattr(keep, name) + step})
            plus = fn()
            image.bias = replace(keep, **{name: getattr(keep, name) - step})
            minus = fn()
            cols.append((plus - minus) / (2.0 * step))
    finally:
        image.bias = keep
    base = fn()
    jac = np.stack([c if c is not None else np.zeros_like(base) for c in cols], axis=-1)
    return np.einsum("nkp,pq,nlq->nkl", jac, cov, jac)


def _propagate(image: AdjustedImage | RpcImage, fn: Callable[[], np.ndarray]) -> np.ndarray | None:
    """Covariance (n, k, k) of ``fn()``'s (n, k) output from the image's parameter covariance
    (report units), by central differences with steps of 1e-3 sigma; None without covariance."""
    if isinstance(image, RpcImage):
        entry = image.report_entry
    else:
        entry = next((e for e in image.model.report.get("images", []) if e["id"] == image.id), None)
    if not entry or not entry.get("covariance"):
        return None
    if isinstance(image, RpcImage):
        return _propagate_rpc(image, entry, fn)
    cov = np.asarray(entry["covariance"]["matrix"], float)
    specs = image.image.model.parameters(image.image.options)
    names = entry["covariance"]["names"]
    if [s.name for s in specs] != names:
        return None
    sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    cols = []
    for j, s in enumerate(specs):
        step = 1e-3 * sig[j] if sig[j] > 0 else 0.0
        if step == 0.0:
            cols.append(None)
            continue
        pos = list(image.image.free_idx).index(s.index)
        d = np.zeros(image.image.nfree)
        d[pos] = step / s.to_report
        plus = _with_parameters(image, d, fn)
        minus = _with_parameters(image, -d, fn)
        cols.append((plus - minus) / (2.0 * step))
    base = fn()
    jac = np.stack([c if c is not None else np.zeros_like(base) for c in cols], axis=-1)  # (n, k, p)
    return np.einsum("nkp,pq,nlq->nkl", jac, cov, jac)


def ground_to_image_table(image: AdjustedImage, rows: list[dict[str, Any]], crs: str = GEODETIC_CRS, sigmas: bool = False) -> list[dict[str, Any]]:
    """Rows with ``line``, ``column`` added (``chip`` too for multi-chip cameras)."""
    names = ground_columns(crs)
    xyz = np.column_stack([_column(rows, n) for n in names])
    ecef = to_ecef(xyz, crs)
    line, col, chip = image.ground_to_image(ecef)
    out = []
    cov = None
    if sigmas:
        def fn() -> np.ndarray:
            l2, c2, _ = image.ground_to_image(ecef)
            return np.column_stack([l2, c2])

        cov = _propagate(image, fn)
    chip_ids = [] if isinstance(image, RpcImage) else [c.id for c in image.image.camera.chips]
    for i, r in enumerate(rows):
        o = dict(r)
        o["line"] = float(line[i]) if np.isfinite(line[i]) else None
        o["column"] = float(col[i]) if np.isfinite(col[i]) else None
        if chip_ids:
            o["chip"] = chip_ids[chip[i]] if chip[i] >= 0 else None
        if sigmas:
            o["sigma_line_px"] = None if cov is None else float(np.sqrt(max(cov[i, 0, 0], 0.0)))
            o["sigma_column_px"] = None if cov is None else float(np.sqrt(max(cov[i, 1, 1], 0.0)))
        out.append(o)
    return out


def image_to_ground_table(
    image: AdjustedImage,
    rows: list[dict[str, Any]],
    crs: str = GEODETIC_CRS,
    height_fn: HeightFn | None = None,
    sigmas: bool = False,
) -> list[dict[str, Any]]:
    """Rows (``line``, ``column`` and ``height`` unless ``height_fn`` is a DEM) with the
    ground coordinates in ``crs`` added."""
    line = _column(rows, "line")
    col = _column(rows, "column")
    h = None if height_fn is not None else _column(rows, "height")
    ecef = image.image_to_ground(line, col, h, height_fn)
    names = ground_columns(crs)
    xyz = np.full((len(rows), 3), np.nan)
    good = np.all(np.isfinite(ecef), axis=1)
    if good.any():
        xyz[good] = from_ecef(ecef[good], crs)
    cov = None
    if sigmas and good.any():
        llh = ecef_to_geodetic(ecef[good][:1])[0]
        rot = enu_rotation(np.radians(llh[0]), np.radians(llh[1]))

        def fn() -> np.ndarray:
            e2 = image.image_to_ground(line[good], col[good], None if h is None else h[good], height_fn)
            return e2 @ rot.T

        cov = _propagate(image, fn)
    out = []
    k = 0
    for i, r in enumerate(rows):
        o = dict(r)
        for j, n in enumerate(names):
            if n == "height" and h is not None:
                continue
            o[n] = float(xyz[i, j]) if good[i] else None
        if sigmas:
            c = cov[k] if (cov is not None and good[i]) else None
            o["sigma_east_m"] = None if c is None else float(np.sqrt(max(c[0, 0], 0.0)))
            o["sigma_north_m"] = None if c is None else float(np.sqrt(max(c[1, 1], 0.0)))
        if good[i]:
            k += 1
        out.append(o)
    return out
