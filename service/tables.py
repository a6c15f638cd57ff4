"""CSV tables of a report: observations, check points, parameters (no computation, only
flattening of the report's own numbers; docs/report-contract.md names the fields).

A model comparison gives the same tables with a leading ``model`` column.
"""

from __future__ import annotations

import csv
import io
from typing import Any, Iterable

TABLES = ("observations", "checkpoints", "parameters")
ENU = ("e", "n", "u")


def _flatten(row: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dicts as ``a_b`` columns; ``*_m`` triples as ``_e/_n/_u``; other lists joined."""
    out: dict[str, Any] = {}
    for key, value in row.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, f"{name}_"))
        elif isinstance(value, (list, tuple)):
            if (
                len(value) == 3
                and name.endswith("_m")
                and all(isinstance(v, (int, float)) or v is None for v in value)
            ):
                for axis, v in zip(ENU, value, strict=False):
                    out[f"{name}_{axis}"] = v
            else:
                out[name] = ";".join("" if v is None else str(v) for v in value)
        else:
            out[name] = value
    return out


def _rows_of(report: dict[str, Any], table: str) -> list[dict[str, Any]]:
    if table == "observations":
        return [_flatten(o) for o in report.get("observations") or []]
    if table == "checkpoints":
        cps = report.get("checkpoints") or {}
        return [_flatten(p) for p in cps.get("points") or []]
    if table == "parameters":
        rows = []
        for image in report.get("images") or []:
            for p in image.get("parameters") or []:
                rows.append(
                    _flatten(
                        {
                            "image": image.get("id"),
                            "camera": image.get("camera"),
                            "model": image.get("model"),
                            **p,
                        }
                    )
                )
        for ps in report.get("passes") or []:  # pass-propagated models: the shared orbit state
            for p in ps.get("parameters") or []:
                rows.append(_flatten({"image": None, "camera": None, "model": ps.get("model"), "pass": ps.get("id"), **p}))
        return rows
    raise KeyError(table)


def table_rows(report: dict[str, Any], table: str) -> list[dict[str, Any]]:
    """Rows of ``table`` (KeyError for an unknown table)."""
    if table not in TABLES:
        raise KeyError(table)
    if report.get("kind") == "comparison":
        rows = []
        for model, sub in (report.get("reports") or {}).items():
            if isinstance(sub, dict) and "error" not in sub:
                rows += [{"model": model, **r} for r in _rows_of(sub, table)]
        return rows
    return _rows_of(report, table)


def to_csv(rows: Iterable[dict[str, Any]]) -> str:
    """CSV text with a header of every column seen, in first-seen order."""
    rows = list(rows)
    columns: dict[str, None] = {}
    for r in rows:
        for k in r:
            columns.setdefault(k, None)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ("" if v is None else v) for k, v in r.items()})
    return buf.getvalue()
