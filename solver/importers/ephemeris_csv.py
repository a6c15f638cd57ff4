"""Ephemeris (platform state vectors) and the image's header state from CSV (and back).

Format: ``time_s,x,y,z,vx,vy,vz``, one state a row (comments, delimiters:
:mod:`solver.importers.tabular`):

- ``time_s``: seconds on a time scale the file must **state**, in a comment
  ``# time_scale: GPS`` (or UTC, TAI, TT, ...; the composer's ``--time-scale`` flag names it
  for files without one). Every time of one image (ephemeris, attitude, first line) must be on
  the same scale: a GPS ephemeris against a UTC first-line time is an 18 s error (about 130 km
  along the orbit) that the adjustment would report as a blunder, so the composer refuses a
  mix. The epoch (seconds since what) is the user's, shared by all the image's files.
- ``x, y, z``: position in ECEF (WGS 84 / ITRF), metres; ``vx, vy, vz`` velocity in the same
  Earth-fixed frame, m/s (not inertial: a TOD/J2000 state is not Earth-fixed and is refused
  by the schema's checks only when far off, so convert first). Accepted spellings:
  ``position_x``/``px``, ``velocity_x``/``vel_x``, ``t``/``time``/``gps_time``.

The **header state** of an image (its approximate perspective-centre state at the first
line, ``approx_state``, and ``first_line_time_s``) is the same format with exactly one row:
its time is the first line's time.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from solver.importers.errors import SourceError, SourceProblem, fail
from solver.importers.tabular import Table, collect, number, read_table, write_rows

ALIASES: dict[str, tuple[str, ...]] = {
    "time_s": ("time", "t", "epoch", "seconds", "gps_time", "utc_time"),
    "x": ("position_x", "px", "x_m", "pos_x"),
    "y": ("position_y", "py", "y_m", "pos_y"),
    "z": ("position_z", "pz", "z_m", "pos_z"),
    "vx": ("velocity_x", "vel_x", "vx_m_s"),
    "vy": ("velocity_y", "vel_y", "vy_m_s"),
    "vz": ("velocity_z", "vel_z", "vz_m_s"),
}
COLUMNS = ["time_s", "x", "y", "z", "vx", "vy", "vz"]


def time_scale_of(table: Table, stated: str | None) -> str:
    """The time scale a table states (``# time_scale:``), else ``stated``; a located error
    when neither says, or when the two disagree."""
    own = table.metadata.get("time_scale")
    if own and stated and own.upper() != stated.upper():
        raise fail(table.file, 1, "time_scale", f"the file says {own!r} but {stated!r} was given", "time_scale_mismatch")
    scale = own or stated
    if not scale:
        raise fail(
            table.file, 1, "time_scale",
            "the time scale is not stated: add a '# time_scale: GPS' (or UTC, ...) line or give it",
            "time_scale_missing",
        )
    return scale.upper()


def read_ephemeris(
    data: bytes | str, file: str, time_scale: str | None = None, columns: Mapping[str, str] | None = None
) -> tuple[list[dict[str, Any]], str]:
    """(state vectors as :class:`solver.schema.job.StateVector` dicts, time scale)."""
    table = read_table(data, file, ALIASES, COLUMNS, columns)
    scale = time_scale_of(table, time_scale)
    problems: list[SourceProblem] = []
    out: list[dict[str, Any]] = []
    last: tuple[float, int] | None = None
    for line, fields in table.rows:
        try:
            v = [number(table, line, fields, c) for c in COLUMNS]
        except SourceError as exc:
            problems += exc.source_problems
            continue
        if last is not None and v[0] <= last[0]:
            problems.append(SourceProblem(file, line, "time_s", f"time {v[0]!r} is not after line {last[1]}'s {last[0]!r}"))
        last = (v[0], line)
        out.append({"time_s": v[0], "position_ecef_m": v[1:4], "velocity_ecef_m_s": v[4:7]})
    collect(problems)
    return out, scale


def read_state(
    data: bytes | str, file: str, time_scale: str | None = None, columns: Mapping[str, str] | None = None
) -> tuple[float, dict[str, Any], str]:
    """(first line time, ``approx_state`` dict, time scale) of a one-row header state file."""
    states, scale = read_ephemeris(data, file, time_scale, columns)
    if len(states) != 1:
        raise fail(file, 0, "", f"a header state file has one row (the state at the first line); it has {len(states)}")
    s = states[0]
    return s["time_s"], {"position_ecef_m": s["position_ecef_m"], "velocity_ecef_m_s": s["velocity_ecef_m_s"]}, scale


def write_ephemeris(states: list[dict[str, Any]], time_scale: str) -> str:
    """An ephemeris table (``# time_scale:`` line, then ``time_s,x,y,z,vx,vy,vz``)."""
    rows = [[s["time_s"], *s["position_ecef_m"], *s["velocity_ecef_m_s"]] for s in states]
    return write_rows(COLUMNS, rows, [f"time_scale: {time_scale}", "ECEF (WGS 84 / ITRF) metres and m/s"])


def write_state(first_line_time_s: float, approx_state: dict[str, Any], time_scale: str) -> str:
    """A header state table: the state at the first line."""
    return write_ephemeris([{"time_s": first_line_time_s, **approx_state}], time_scale)
