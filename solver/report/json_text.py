"""The report as JSON text: one serialiser for the CLI (``pba run -o``, ``pba compare -o``,
``pba preanalysis -o``) and the server (the stored report, problem documents).

JSON has no NaN or infinity: a non-finite float (an undefined statistic, an infinite
condition number) is written as ``null`` everywhere, so every written report is strict JSON
(RFC 8259) that any client parses, and a report reads the same from a file and from the
server. numpy scalars and arrays become plain numbers and lists.
"""

from __future__ import annotations

import json
import math
from typing import Any


def json_ready(x: Any) -> Any:
    """``x`` in plain JSON types: dict keys as strings, tuples as lists, numpy scalars and
    arrays converted, non-finite floats as None; any other object as its ``str``."""
    if isinstance(x, dict):
        return {str(k): json_ready(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_ready(v) for v in x]
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return x
    if isinstance(x, int):
        return int(x)
    if isinstance(x, float):
        return float(x) if math.isfinite(x) else None
    tolist = getattr(x, "tolist", None)  # numpy scalars and arrays
    if callable(tolist):
        return json_ready(tolist())
    return str(x)


def report_json(report: dict[str, Any], indent: int | None = None) -> str:
    """``report`` as strict JSON text (compact unless ``indent`` is given)."""
    separators = (",", ":") if indent is None else (",", ": ")
    return json.dumps(json_ready(report), allow_nan=False, indent=indent, separators=separators)
