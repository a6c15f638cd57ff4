"""Time scales of vendors' metadata: UTC with the leap seconds of the date, and GPS time.

- ``TAI - UTC`` from 1972 on steps by one second after 23:59:60 UTC of the dates in
  :data:`LEAP_SECOND_DAYS` (IERS Bulletin C; 37 s since 2017-01-01). The table is known to
  hold until :data:`TABLE_VALID_UNTIL`: later instants take its last offset, and an interval
  reaching past it across the end of a June or December (where a leap second could have been
  announced) is refused by :func:`leap_seconds_between`.
- GPS time runs with TAI: ``GPS - UTC = (TAI - UTC) - 19 s`` (18 s since 2017).

Instants are ``datetime`` objects labelled with the zone UTC whatever the scale (Python has
no leap seconds): a GPS instant 2020-08-01T14:32:08 is converted to the UTC instant
2020-08-01T14:31:50.
"""

from __future__ import annotations

from datetime import date, datetime, timedelta, timezone

# Last day (UTC) before each positive leap second: 23:59:60 of these days.
LEAP_SECOND_DAYS = (
    date(1972, 6, 30), date(1972, 12, 31), date(1973, 12, 31), date(1974, 12, 31), date(1975, 12, 31),
    date(1976, 12, 31), date(1977, 12, 31), date(1978, 12, 31), date(1979, 12, 31), date(1981, 6, 30),
    date(1982, 6, 30), date(1983, 6, 30), date(1985, 6, 30), date(1987, 12, 31), date(1989, 12, 31),
    date(1990, 12, 31), date(1992, 6, 30), date(1993, 6, 30), date(1994, 6, 30), date(1995, 12, 31),
    date(1997, 6, 30), date(1998, 12, 31), date(2005, 12, 31), date(2008, 12, 31), date(2012, 6, 30),
    date(2015, 6, 30), date(2016, 12, 31),
)
TAI_MINUS_UTC_1972_S = 10  # TAI - UTC from 1972-01-01 to the first leap second
GPS_MINUS_TAI_S = -19
# IERS Bulletin C 69 (January 2025): no leap second at the end of June 2025. Extend the table
# and this date when a later bulletin is read.
TABLE_VALID_UNTIL = datetime(2025, 6, 30, 23, 59, 59, tzinfo=timezone.utc)


class UnknownLeapSeconds(ValueError):
    """An instant or interval beyond what the leap-second table knows."""


def _edge(day: date) -> datetime:
    """The UTC instant just after the leap second of ``day`` (its next midnight)."""
    return datetime(day.year, day.month, day.day, tzinfo=timezone.utc) + timedelta(days=1)


def tai_minus_utc_s(t_utc: datetime) -> int:
    """TAI - UTC (s) at a UTC instant from 1972 on (after :data:`TABLE_VALID_UNTIL`: its last value)."""
    if t_utc < datetime(1972, 1, 1, tzinfo=timezone.utc):
        raise UnknownLeapSeconds(f"{t_utc.isoformat()}: before 1972, UTC had no whole-second offset from TAI")
    return TAI_MINUS_UTC_1972_S + sum(1 for d in LEAP_SECOND_DAYS if _edge(d) <= t_utc)


def gps_minus_utc_s(t_utc: datetime) -> int:
    """GPS - UTC (s) at a UTC instant (18 s since 2017-01-01)."""
    return tai_minus_utc_s(t_utc) + GPS_MINUS_TAI_S


def gps_to_utc(t_gps: datetime) -> datetime:
    """The UTC instant of a GPS-time instant (both labelled UTC, module docstring)."""
    guess = t_gps - timedelta(seconds=gps_minus_utc_s(t_gps))
    return t_gps - timedelta(seconds=gps_minus_utc_s(guess))


def leap_seconds_between(a: datetime, b: datetime) -> list[datetime]:
    """The leap seconds (the UTC instants just after each) inside ``[a, b]`` (UTC). An interval
    reaching past :data:`TABLE_VALID_UNTIL` across the end of a June or December raises
    :class:`UnknownLeapSeconds`."""
    lo, hi = min(a, b), max(a, b)
    if hi > TABLE_VALID_UNTIL:
        for year in range(max(lo.year, TABLE_VALID_UNTIL.year), hi.year + 1):
            for month, day in ((6, 30), (12, 31)):
                edge = _edge(date(year, month, day))
                if lo < edge <= hi and edge > TABLE_VALID_UNTIL:
                    raise UnknownLeapSeconds(f"{lo.isoformat()} to {hi.isoformat()} spans the end of {year}-{month:02d}, "
                                             "beyond the leap-second table: a leap second there is unknown")
    return [_edge(d) for d in LEAP_SECOND_DAYS if lo < _edge(d) <= hi]
