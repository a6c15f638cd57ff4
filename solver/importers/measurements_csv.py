"""Image measurements from a CSV table with a header.

Format: ``image,point,line,column[,sigma_px][,chip]``, one measurement a row (comments,
delimiters: :mod:`solver.importers.tabular`).

- ``line, column``: pixels in **our** convention (:mod:`solver.schema.job`): the origin is the
  *centre* of the top-left pixel, the line grows downwards (with acquisition time), the column
  to the right. A tool that counts from the pixel's corner (QGIS, GDAL) is 0.5 px off: use its
  own importer (:mod:`solver.importers.qgis_points`) or convert first.
- ``row`` and ``sample``/``col`` are accepted for line and column; ``x``/``y`` are not (which
  is which differs between tools).
- ``sigma_px``: the measurement's standard deviation in pixels (on line and column); empty or
  absent: the caller's default (0.5 px, as the job schema).
- ``image``: the job's image id; may be absent when the caller says which image the whole
  file is of (``pba job --image N=N_points.csv``). A row naming another image is an error then.
- ``chip``: optional chip id for columns where chips overlap.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from solver.importers.errors import SourceError, SourceProblem, fail
from solver.importers.tabular import Table, collect, number, read_table, text_field, write_rows

ALIASES: dict[str, tuple[str, ...]] = {
    "image": ("image_id", "scene", "img"),
    "point": ("id", "point_id", "name", "label"),
    "line": ("row", "l", "line_px", "row_px"),
    "column": ("col", "sample", "c", "column_px", "col_px"),
    "sigma_px": ("sigma", "sd_px", "std_px", "s_px"),
    "chip": ("ccd", "chip_id"),
}
DEFAULT_SIGMA_PX = 0.5


def read_measurements(
    data: bytes | str,
    file: str,
    image: str | None = None,
    columns: Mapping[str, str] | None = None,
    sigma_px: float = DEFAULT_SIGMA_PX,
) -> list[dict[str, Any]]:
    """Image observations (:class:`solver.schema.job.ImageObservation` dicts) of a table."""
    table = read_table(data, file, ALIASES, ["point", "line", "column"] + ([] if image else ["image"]), columns)
    problems: list[SourceProblem] = []
    out: list[dict[str, Any]] = []
    seen: dict[tuple[str, str], int] = {}
    for line, fields in table.rows:
        try:
            obs = _observation(table, line, fields, image, sigma_px)
        except SourceError as exc:
            problems += exc.source_problems
            continue
        key = (obs["image"], obs["point"])
        if key in seen:
            problems.append(
                SourceProblem(file, line, "point", f"point {key[1]!r} of image {key[0]!r} is already on line {seen[key]}")
            )
        seen[key] = line
        out.append(obs)
    collect(problems)
    return out


def _observation(table: Table, line: int, fields: list[str], image: str | None, sigma_px: float) -> dict[str, Any]:
    named = text_field(table, line, fields, "image", image or "")
    if image and named != image:
        raise fail(table.file, line, "image", f"the row is of image {named!r} but the file was given as image {image!r}")
    obs: dict[str, Any] = {
        "image": named,
        "point": text_field(table, line, fields, "point"),
        "line": number(table, line, fields, "line"),
        "column": number(table, line, fields, "column"),
        "sigma_px": number(table, line, fields, "sigma_px", default=sigma_px),
    }
    if obs["sigma_px"] <= 0:
        raise fail(table.file, line, "sigma_px", f"standard deviation {obs['sigma_px']!r} must be positive (pixels)")
    chip = text_field(table, line, fields, "chip", "")
    if chip:
        obs["chip"] = chip
    return obs


def write_measurements(observations: list[dict[str, Any]], with_image: bool = True) -> str:
    """A measurements table of job observations (``image,point,line,column,sigma_px``; the
    ``chip`` column only when some observation names its chip)."""
    chips = any(o.get("chip") for o in observations)
    header = (["image"] if with_image else []) + ["point", "line", "column", "sigma_px"] + (["chip"] if chips else [])
    rows = []
    for o in observations:
        r = ([o["image"]] if with_image else []) + [o["point"], o["line"], o["column"], o.get("sigma_px", DEFAULT_SIGMA_PX)]
        rows.append(r + ([o.get("chip")] if chips else []))
    return write_rows(header, rows)
