"""Drop the raw gyro and on-board telemetry blocks (``FOG_Inertial_Data``, ``Other_LVC_Data``)
of a Pleiades ground-segment metadata file (root ``PHR_Dimap_Document``), for small test files:
nothing the reader uses is in them, and every other element is kept byte for byte.

    python scripts/trim_phr_dimap.py IN.XML OUT.XML
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

DROPPED = ("FOG_Inertial_Data", "Other_LVC_Data")


def trim(text: str) -> str:
    for tag in DROPPED:
        text = re.sub(rf"\n[ \t]*<{tag}>.*?</{tag}>", "", text, flags=re.S)
    return text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path)
    ap.add_argument("target", type=Path)
    args = ap.parse_args()
    text = args.source.read_text(encoding="utf-8")
    out = trim(text)
    args.target.write_text(out, encoding="utf-8")
    print(f"{args.target}: {len(out)} of {len(text)} characters kept")


if __name__ == "__main__":
    main()
