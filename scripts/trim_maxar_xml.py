"""Trim a Maxar/DigitalGlobe support-data XML's ephemeris and attitude lists to the imaging
window (plus a margin), for small test files: every other element is kept byte for byte.

    python scripts/trim_maxar_xml.py IN.xml OUT.xml [--margin-s 2]

The kept samples are renumbered from 1 and ``STARTTIME`` / ``NUMPOINTS`` of the EPH and ATT
blocks are updated, so the result is a valid support-data file of the same image.
"""

from __future__ import annotations

import argparse
import re
from datetime import datetime, timedelta
from pathlib import Path


def _time(text: str) -> datetime:
    return datetime.strptime(text.strip().rstrip("Z"), "%Y-%m-%dT%H:%M:%S.%f")


def _value(block: str, tag: str) -> str:
    m = re.search(rf"<{tag}>([^<]*)</{tag}>", block)
    if m is None:
        raise SystemExit(f"no <{tag}>")
    return m.group(1)


def _trim(block: str, item: str, t_lo: datetime, t_hi: datetime) -> str:
    start = _time(_value(block, "STARTTIME"))
    dt = float(_value(block, "TIMEINTERVAL"))
    rows = re.findall(rf"[ \t]*<{item}>[^<]*</{item}>\n", block)
    kept = []
    for row in rows:
        fields = re.search(rf"<{item}>([^<]*)</{item}>", row).group(1).split()
        t = start + timedelta(seconds=(float(fields[0]) - 1.0) * dt)
        if t_lo <= t <= t_hi:
            kept.append((t, row, fields))
    first_t = kept[0][0]
    out_rows = []
    for k, (_, row, fields) in enumerate(kept, start=1):
        out_rows.append(row.replace(fields[0], f"{float(k):.15e}", 1))
    body = block[: block.index(rows[0])] + "".join(out_rows) + block[block.index(rows[-1]) + len(rows[-1]):]
    body = body.replace(f"<STARTTIME>{_value(block, 'STARTTIME')}</STARTTIME>",
                        f"<STARTTIME>{first_t.strftime('%Y-%m-%dT%H:%M:%S.%f')}Z</STARTTIME>", 1)
    return body.replace(f"<NUMPOINTS>{_value(block, 'NUMPOINTS')}</NUMPOINTS>", f"<NUMPOINTS>{len(kept)}</NUMPOINTS>", 1)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--margin-s", type=float, default=2.0)
    a = ap.parse_args()
    text = a.src.read_text()
    first = _time(_value(text, "FIRSTLINETIME"))
    duration = int(_value(text, "NUMROWS")) / float(_value(text, "AVGLINERATE"))
    t_lo = first - timedelta(seconds=a.margin_s)
    t_hi = first + timedelta(seconds=duration + a.margin_s)
    for tag, item in (("EPH", "EPHEMLIST"), ("ATT", "ATTLIST")):
        i, j = text.index(f"<{tag}>"), text.index(f"</{tag}>")
        text = text[:i] + _trim(text[i:j], item, t_lo, t_hi) + text[j:]
    a.dst.write_text(text)


if __name__ == "__main__":
    main()
