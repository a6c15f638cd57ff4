"""CSV tables of a report: observations, check points, parameters, rejected observations (no computation, only
flattening of the report's own numbers; docs/report-contract.md names the fields).

A model comparison gives the same tables with a leading ``model`` column. Text cells are
escaped against formula injection (:func:`csv_cell`), numbers are written as numbers.
"""

from __future__ import annotations

import csv
import io
import re
from typing import Any, Iterable

TABLES = ("observations", "checkpoints", "parameters", "rejected")
ENU = ("e", "n", "u")
# OWASP "CSV injection": a spreadsheet runs a cell beginning with one of these as a formula
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")
# a plain decimal number, or a ';'-joined list of them: no letters to call a function with
_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
PLAIN_NUMBERS = re.compile(rf"{_NUMBER}(?:;{_NUMBER})*")


def csv_cell(value: Any) -> Any:
    """A cell value safe to open in a spreadsheet: text beginning with ``= + - @`` TAB or CR
    gets a leading single quote, unless it is a plain number (``-1.5``, ``-1;2``); numbers,
    booleans and None are returned unchanged."""
    if not isinstance(value, str) or not value.startswith(FORMULA_START):
        return value
    if PLAIN_NUMBERS.fullmatch(value):
        return value
    return "'" + value


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
    if table == "rejected":
        return _rejected_rows(report.get("quality") or {})
    raise KeyError(table)


def _status(entry: dict[str, Any]) -> str:
    if entry.get("reinstated"):
        return "reinstated"
    return "removed" if entry.get("removed") else "kept"


def _where(entry: dict[str, Any]) -> tuple:
    return tuple(entry.get(k) for k in ("kind", "image", "point", "line", "pass", "time_s"))


def _rejected_rows(quality: dict[str, Any]) -> list[dict[str, Any]]:
    """Data snooping (docs/quality.md): the failed tests (``status`` removed, or kept when not
    removed), the members of the non-identifiable groups (``group`` their number), the
    observations put back after the test against the final solution (``status`` reinstated,
    with the ``predicted_*`` test), and the control points the removals took away (``status``
    lost_control, with the predicted check-point RMSE before and after)."""
    back = {_where(r): r for r in quality.get("reinstated") or []}
    rows = [_flatten({"status": _status(r), "group": None, **r}) for r in quality.get("rejected") or []]
    for k, g in enumerate(quality.get("not_identifiable") or [], start=1):
        for m in g.get("members") or []:
            # a member put back is listed with its group, with its predicted test
            extra = {"predicted": back.pop(_where(m))["predicted"]} if m.get("reinstated") and _where(m) in back else {}
            rows.append(_flatten({"status": _status(m), "group": k, **m, **extra}))
    rows += [_flatten({"status": "reinstated", "group": None, **r}) for r in back.values()]
    lost = quality.get("lost_control") or {}
    for pid in lost.get("points") or []:
        rows.append(_flatten({"status": "lost_control", "group": None, "kind": "control_point", "point": pid,
                              "predicted_check_rmse_m": lost.get("predicted_check_rmse_m")}))
    return rows


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
    writer = csv.writer(buf, lineterminator="\r\n")  # RFC 4180; a CR or LF in a cell is quoted
    writer.writerow([csv_cell(k) for k in columns])
    for r in rows:
        writer.writerow([csv_cell("" if r.get(k) is None else r[k]) for k in columns])
    return buf.getvalue()
