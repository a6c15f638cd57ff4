"""Control, check and tie points from a CSV table with a header.

Format: ``id,x,y,z[,sx,sy,sz][,role]``, one point a row, in any CRS the caller names
(``--crs``: an EPSG code or a PROJ string); comments ``#``, delimiter ``,``, ``;`` or tab
(:mod:`solver.importers.tabular`).

- ``x, y`` are in the CRS's (x, y) order as pyproj's ``always_xy``: easting, northing for a
  projected CRS, **longitude, latitude** (degrees) for a geographic one, whatever the EPSG
  axis order says. A header that names them ``lon``/``lat``, ``longitude``/``latitude`` or
  ``easting``/``northing`` is read by name, so a ``lat,lon`` column order cannot swap them.
- ``z``: height in metres, ellipsoidal unless the CRS says otherwise (as the job document).
- ``sx, sy, sz``: survey standard deviations along local east, north, up, metres (all three
  or none; empty fields mean none for that row).
- ``role``: ``gcp`` (also ``control``, ``c``), ``check`` (``chk``), ``tie`` (``t``). Without
  the column every row takes the caller's role (``--gcps`` files: gcp). A tie point may
  leave x, y, z empty.

Column names are configurable: ``columns={"E": "x", "N": "y", "H": "z"}`` maps the file's
names onto these. The rows become :class:`solver.schema.job.GroundPoint` dicts; the CRS is
set by the composer (the job's default CRS, or each point's ``crs``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from solver.importers.errors import SourceError, SourceProblem, fail
from solver.importers.tabular import Table, collect, number, read_table, text_field, write_rows

ALIASES: dict[str, tuple[str, ...]] = {
    "id": ("point", "point_id", "name", "label"),
    "x": ("easting", "east", "e", "lon", "longitude", "long"),
    "y": ("northing", "north", "n", "lat", "latitude"),
    "z": ("height", "h", "elevation", "alt", "altitude", "ellipsoidal_height"),
    "sx": ("sigma_x", "sigma_e", "se", "sigma_east", "std_x"),
    "sy": ("sigma_y", "sigma_n", "sn", "sigma_north", "std_y"),
    "sz": ("sigma_z", "sigma_u", "su", "sigma_h", "sigma_up", "std_z"),
    "role": ("type", "kind", "use"),
}
ROLES = {"gcp": "gcp", "control": "gcp", "c": "gcp", "check": "check", "chk": "check", "tie": "tie", "t": "tie"}


def read_points(
    data: bytes | str, file: str, role: str | None = None, columns: Mapping[str, str] | None = None
) -> list[dict[str, Any]]:
    """Ground points of a points table (``role`` for rows without a role column)."""
    required = ["id"] + ([] if role == "tie" else ["x", "y", "z"])
    table = read_table(data, file, ALIASES, required, columns)
    if role is None and "role" not in table.header:
        raise fail(file, table.header_line, "role", "no role column: give the file's role (gcp, check or tie)")
    problems: list[SourceProblem] = []
    points: list[dict[str, Any]] = []
    seen: dict[str, int] = {}
    for line, fields in table.rows:
        try:
            points.append(_point(table, line, fields, role))
        except SourceError as exc:
            problems += exc.source_problems
            continue
        pid = points[-1]["id"]
        if pid in seen:
            problems.append(SourceProblem(file, line, "id", f"point {pid!r} is already on line {seen[pid]}"))
        seen[pid] = line
    collect(problems)
    return points


def _point(table: Table, line: int, fields: list[str], default_role: str | None) -> dict[str, Any]:
    pid = text_field(table, line, fields, "id")
    raw_role = text_field(table, line, fields, "role", default_role or "")
    role = ROLES.get(raw_role.lower())
    if role is None:
        raise fail(table.file, line, "role", f"unknown role {raw_role!r} (gcp, check or tie)")
    point: dict[str, Any] = {"id": pid, "role": role}
    coords = [fields[table.header.index(k)] if k in table.header else "" for k in ("x", "y", "z")]
    if role != "tie" or any(coords):
        point["coordinates"] = [number(table, line, fields, k) for k in ("x", "y", "z")]
    sig = [fields[table.header.index(k)] if k in table.header else "" for k in ("sx", "sy", "sz")]
    if any(sig):
        point["sigma_m"] = [number(table, line, fields, k) for k in ("sx", "sy", "sz")]
        for k, v in zip(("sx", "sy", "sz"), point["sigma_m"], strict=True):
            if v <= 0:
                        raise fail(table.file, line, k, f"standard deviation {v!r} must be positive (metres)")
    return point


def write_points(points: list[dict[str, Any]], crs: str | None = None, with_role: bool = True) -> str:
    """A points table of job points (``id,x,y,z,sx,sy,sz,role``; the CRS in a comment);
    ``with_role=False``: without the role column (a file given as ``--gcps`` or ``--checks``)."""
    rows = []
    for p in points:
        xyz = p.get("coordinates") or [None, None, None]
        s = p.get("sigma_m") or [None, None, None]
        rows.append([p["id"], *xyz, *s] + ([p["role"]] if with_role else []))
    comments = [f"crs: {crs}"] if crs else []
    return write_rows(["id", "x", "y", "z", "sx", "sy", "sz"] + (["role"] if with_role else []), rows, comments)
