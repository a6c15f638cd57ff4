"""Measured attitude (star tracker / AOCS telemetry) from CSV (and back).

Format: ``time_s,roll_deg,pitch_deg,yaw_deg``, one sample a row (comments, delimiters:
:mod:`solver.importers.tabular`), with the time scale stated as for the ephemeris
(``# time_scale: GPS``, :mod:`solver.importers.ephemeris_csv`; the composer refuses an image
whose files state different scales).

- angles in **degrees**, of the platform body relative to the orbital frame of the
  orbit-attitude models (x along track, z radial up; M = Ry(mounting) Rx(roll) Ry(pitch)
  Rz(yaw) R_orbit, docs/models.md section 10), as the job's ``attitude`` samples. Telemetry in
  quaternions or in radians must be converted first; a column named ``roll_rad`` is refused by
  name rather than read as degrees.
- accepted spellings: ``roll``/``pitch``/``yaw`` (degrees), ``t``/``time``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from solver.importers.ephemeris_csv import time_scale_of
from solver.importers.errors import SourceError, SourceProblem, fail
from solver.importers.tabular import collect, number, read_table, write_rows

ALIASES: dict[str, tuple[str, ...]] = {
    "time_s": ("time", "t", "epoch", "seconds", "gps_time", "utc_time"),
    "roll_deg": ("roll",),
    "pitch_deg": ("pitch",),
    "yaw_deg": ("yaw",),
}
COLUMNS = ["time_s", "roll_deg", "pitch_deg", "yaw_deg"]


def read_attitude(
    data: bytes | str, file: str, time_scale: str | None = None, columns: Mapping[str, str] | None = None
) -> tuple[list[dict[str, Any]], str]:
    """(attitude samples as :class:`solver.schema.job.AttitudeSample` dicts, time scale)."""
    table = read_table(data, file, ALIASES, ["time_s"], columns)
    for i, name in enumerate(table.header):
        if name.endswith("_rad"):
            raise fail(file, table.header_line, table.column_name(i), "angles in radians: give degrees (roll_deg, pitch_deg, yaw_deg)")
    missing = [c for c in COLUMNS if c not in table.header]
    if missing:
        raise fail(file, table.header_line, "", f"the header has no column for {', '.join(missing)}", "unrecognised_header")
    scale = time_scale_of(table, time_scale)
    problems: list[SourceProblem] = []
    out: list[dict[str, Any]] = []
    last: tuple[float, int] | None = None
    for line, fields in table.rows:
        try:
            t, r, p, y = (number(table, line, fields, c) for c in COLUMNS)
        except SourceError as exc:
            problems += exc.source_problems
            continue
        for name, v in (("roll_deg", r), ("pitch_deg", p), ("yaw_deg", y)):
            if abs(v) > 360:
                problems.append(SourceProblem(file, line, name, f"{v!r} degrees is beyond 360"))
        if last is not None and t <= last[0]:
            problems.append(SourceProblem(file, line, "time_s", f"time {t!r} is not after line {last[1]}'s {last[0]!r}"))
        last = (t, line)
        out.append({"time_s": t, "roll_deg": r, "pitch_deg": p, "yaw_deg": y})
    collect(problems)
    return out, scale


def write_attitude(samples: list[dict[str, Any]], time_scale: str) -> str:
    """An attitude table (``# time_scale:`` line, then ``time_s,roll_deg,pitch_deg,yaw_deg``)."""
    rows = [[s["time_s"], s["roll_deg"], s["pitch_deg"], s["yaw_deg"]] for s in samples]
    return write_rows(COLUMNS, rows, [f"time_scale: {time_scale}", "roll, pitch, yaw of the body in the orbital frame, degrees"])
