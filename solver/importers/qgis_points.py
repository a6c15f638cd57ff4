"""Image measurements from QGIS Georeferencer ``.points`` files (and back).

What QGIS writes (Georeferencer, "Save GCP points as..."; QGIS 3.26 and later)::

    #CRS: GEOGCRS["WGS 84",DATUM[...],...]          <- the map coordinates' CRS, WKT on one line
    mapX,mapY,sourceX,sourceY,enable,dX,dY,residual
    -51.19460470574567,-21.99814443123678,13482.59,-482.32,1,0,0,0

Older versions write ``pixelX,pixelY`` for ``sourceX,sourceY`` and no ``#CRS:`` line (then the
caller names the map CRS). Conventions, converted once here:

- ``sourceX, sourceY`` are the raster's own coordinates as QGIS shows an image without
  georeferencing, GDAL's default geotransform ``(0, 1, 0, 0, 0, -1)``: x = column, y = **minus**
  the row, measured from the top-left **corner** of the top-left pixel. The centre of that
  pixel is (0.5, -0.5). Ours (:mod:`solver.schema.job`) is origin at its centre, line down:
  ``column = sourceX - 0.5``, ``line = -sourceY - 0.5``. A file with positive ``sourceY``
  everywhere (not negated) is refused rather than mirrored silently.
- ``mapX, mapY``: the point's coordinates in the ``#CRS`` (x/y order, as pyproj's
  ``always_xy``: longitude, latitude for a geographic CRS). A ``.points`` file has no point
  ids: each row is matched to the ground point of the survey nearest to its map position
  (horizontally, in metres, through ECEF), which must lie within ``tolerance_m`` (default 1 m)
  and be the only one that close.
- ``enable``: 0 rows are skipped, each with a note (QGIS keeps disabled points in the file).
- ``dX, dY, residual``: QGIS's own fit residuals, ignored.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from solver.geometry.geodesy import UnknownCRSError, from_ecef, parse_crs, to_ecef
from solver.importers.errors import SourceError, SourceProblem, fail
from solver.importers.tabular import collect, decode, fmt, number, read_table

ALIASES: dict[str, tuple[str, ...]] = {
    "mapx": ("map_x",),
    "mapy": ("map_y",),
    "sourcex": ("pixelx", "source_x", "pixel_x"),
    "sourcey": ("pixely", "source_y", "pixel_y"),
    "enable": ("enabled",),
}
DEFAULT_TOLERANCE_M = 1.0
PIXEL_CENTRE = 0.5  # QGIS/GDAL pixel (0, 0) centre is at (0.5, -0.5) in source coordinates


def crs_line(data: bytes | str, file: str) -> str | None:
    """The WKT (or other CRS text) of a ``#CRS:`` line; None without one (or an empty one)."""
    for line in decode(data, file).splitlines():
        s = line.strip()
        if s.upper().startswith("#CRS:"):
            return s[5:].strip() or None
        if s and not s.startswith("#"):
            return None
    return None


def source_to_ours(source_x: float, source_y: float) -> tuple[float, float]:
    """(line, column) in our convention of a QGIS (sourceX, sourceY)."""
    return -source_y - PIXEL_CENTRE, source_x - PIXEL_CENTRE


def ours_to_source(line: float, column: float) -> tuple[float, float]:
    """QGIS (sourceX, sourceY) of our (line, column)."""
    return column + PIXEL_CENTRE, -(line + PIXEL_CENTRE)


def read_qgis_points(
    data: bytes | str,
    file: str,
    image: str,
    points: Sequence[dict[str, Any]],
    points_crs: str,
    map_crs: str | None = None,
    sigma_px: float = 0.5,
    tolerance_m: float = DEFAULT_TOLERANCE_M,
) -> tuple[list[dict[str, Any]], list[str]]:
    """(observations of ``image``, notes) from a ``.points`` file, each row matched to the
    nearest of ``points`` (ground points with coordinates in ``points_crs``, or their own
    ``crs``). ``map_crs`` is used only when the file has no ``#CRS:`` line."""
    file_crs = crs_line(data, file) or map_crs
    if file_crs is None:
        raise fail(file, 1, "", "no #CRS: line: name the CRS of the map coordinates")
    try:
        parse_crs(file_crs)
    except UnknownCRSError as exc:
        raise fail(file, 1, "#CRS", str(exc)) from None
    table = read_table(data, file, ALIASES, ["mapx", "mapy", "sourcex", "sourcey"])
    candidates = [p for p in points if p.get("coordinates") is not None]
    if not candidates:
        raise fail(file, 0, "", "a .points file has no point ids: give the survey (control and check points) to match its rows to")
    try:
        ecef = np.vstack([to_ecef(np.array([p["coordinates"]]), p.get("crs") or points_crs) for p in candidates])
        in_map = from_ecef(ecef, file_crs)
    except UnknownCRSError as exc:
        raise fail(file, 0, "", f"the survey points cannot be brought into the file's CRS: {exc}") from None
    geographic = parse_crs(file_crs).is_geographic
    notes: list[str] = []
    problems: list[SourceProblem] = []
    out: list[dict[str, Any]] = []
    matched: dict[str, int] = {}
    for line, fields in table.rows:
        try:
            enable = number(table, line, fields, "enable", default=1.0)
            if enable == 0:
                notes.append(f"{file}, line {line}: disabled in QGIS (enable = 0), skipped")
                continue
            mx, my = number(table, line, fields, "mapx"), number(table, line, fields, "mapy")
            sx, sy = number(table, line, fields, "sourcex"), number(table, line, fields, "sourcey")
            if sy > 0:
                raise fail(
                    file, line, table.column_name(table.header.index("sourcey")),
                    f"{sy!r} is positive: QGIS writes the image row negated (sourceY = -row), so this file "
                    "was not written by the Georeferencer",
                )
            k = _nearest(mx, my, in_map, ecef, file_crs, geographic, tolerance_m, file, line, candidates)
        except SourceError as exc:
            problems += exc.source_problems
            continue
        pid = candidates[k]["id"]
        if pid in matched:
            problems.append(SourceProblem(file, line, "mapX", f"matches point {pid!r} as line {matched[pid]} does"))
            continue
        matched[pid] = line
        ln, col = source_to_ours(sx, sy)
        out.append({"image": image, "point": pid, "line": ln, "column": col, "sigma_px": sigma_px})
    collect(problems)
    return out, notes


def _nearest(
    mx: float, my: float, in_map: np.ndarray, ecef: np.ndarray, crs: str, geographic: bool,
    tolerance_m: float, file: str, line: int, candidates: Sequence[dict[str, Any]],
) -> int:
    """Index of the one candidate within ``tolerance_m`` (horizontal metres) of (mx, my)."""
    row = np.column_stack([np.full(len(in_map), mx), np.full(len(in_map), my), in_map[:, 2]])
    try:
        row_ecef = to_ecef(row, crs)
    except UnknownCRSError:
        raise fail(file, line, "mapX", f"({mx!r}, {my!r}) cannot be transformed from the file's CRS") from None
    d = np.linalg.norm(row_ecef - ecef, axis=1)
    close = np.flatnonzero(d <= tolerance_m)
    if len(close) == 1:
        return int(close[0])
    if len(close) > 1:
        names = ", ".join(repr(candidates[i]["id"]) for i in close[:4])
        raise fail(file, line, "mapX", f"points {names} are all within {tolerance_m:g} m: cannot tell which")
    k = int(np.argmin(d))
    hint = " (longitude and latitude swapped?)" if geographic and math.isfinite(d[k]) and d[k] > 1e4 else ""
    raise fail(
        file, line, "mapX",
        f"no survey point within {tolerance_m:g} m of ({mx!r}, {my!r}); the nearest is "
        f"{candidates[k]['id']!r} at {d[k]:.3f} m{hint}",
        "unmatched_point",
    )


def write_qgis_points(
    observations: Sequence[dict[str, Any]], points: Sequence[dict[str, Any]], points_crs: str, map_crs: str | None = None
) -> tuple[str, list[str]]:
    """(``.points`` text, notes) of one image's observations: map coordinates of each ground
    point in ``map_crs`` (default ``points_crs``) with a ``#CRS:`` WKT line, as QGIS writes it.
    Observations of points without coordinates (tie points) have no place there: skipped, noted."""
    map_crs = map_crs or points_crs
    by_id = {p["id"]: p for p in points}
    lines = [f"#CRS: {parse_crs(map_crs).to_wkt()}", "mapX,mapY,sourceX,sourceY,enable,dX,dY,residual"]
    notes: list[str] = []
    for o in observations:
        p = by_id.get(o["point"])
        if p is None or p.get("coordinates") is None:
            notes.append(f"point {o['point']!r} has no ground coordinates: not written")
            continue
        xyz = np.array([p["coordinates"]], dtype=float)
        crs = p.get("crs") or points_crs
        if crs != map_crs:
            xyz = from_ecef(to_ecef(xyz, crs), map_crs)
        sx, sy = ours_to_source(o["line"], o["column"])
        lines.append(",".join([fmt(float(xyz[0, 0])), fmt(float(xyz[0, 1])), fmt(sx), fmt(sy), "1", "0", "0", "0"]))
    return "\n".join(lines) + "\n", notes

