"""The self-check table of docs/sensor-metadata.md: per public metadata file, the agreement of the
exact model and of the job form with each reference the file states (its corners and centres,
its RPC) and of the job form with the exact model (solver/sensors/self_check.py).

    python scripts/sensor_table.py            # print the table of the files in tests/data/vendor
    python scripts/sensor_table.py --write    # and write it between the markers of the docs page
    python scripts/sensor_table.py FILE...    # the table of other files (not written)

tests/solver/sensors/test_self_check.py checks that the page's table is this script's output.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DOC = ROOT / "docs" / "sensor-metadata.md"
BEGIN, END = "<!-- self-check table: begin -->", "<!-- self-check table: end -->"
VENDOR = ROOT / "tests" / "data" / "vendor"
FILES = [
    "stereopipeline/wv_test1.xml", "stereopipeline/wv_test2.xml", "stereopipeline/wv_mvp_1.xml", "stereopipeline/wv_mvp_2.xml",
    "stereopipeline/spot_example1.xml", "pyrugged/DIM_PHR1A_P_201202250025599_SEN_PRG_FC_5847-001.XML",
    "shareloc/PHRDIMAP_P1BP--2018122638935449CP.XML", "cbers-2-stac/CBERS_4_MUX_20170528_090_084_L2_BAND6.xml",
    "cbers-2-stac/CBERS_4_PAN5M_20161009_219_050_L2_BAND1.xml", "cbers-2-stac/CBERS_4A_MUX_20220810_222_116_L4_BAND6.xml",
    "cbers-2-stac/CBERS_4A_WFI_20200801_221_156_L4_BAND13.xml#left", "cbers-2-stac/CBERS_4A_WFI_20200801_221_156_L4_BAND13.xml#right",
]
HEADER = ("| File | Reference | Model | Points | RMS px | max px | max m | Limit px |\n"
          "|---|---|---|---|---|---|---|---|")


def rows(paths: list[str]) -> list[str]:
    """The table's rows for ``paths`` (a ``#left``/``#right`` suffix names a camera)."""
    from solver.sensors.formats import read_product
    from solver.sensors.self_check import self_check

    out = []
    for shown in paths:
        check = self_check(read_product(shown))
        name = Path(shown).name
        for r in check.rows:
            m = "" if r.max_m is None else f"{r.max_m:.3f}"
            out.append(f"| {name} | {r.reference} | {r.model} | {r.points} | {r.rms_px:.3f} | {r.max_px:.3f} | {m} | {r.limit_px:g} |")
        for n in check.notes:
            if n.startswith("no job form"):
                out.append(f"| {name} | {n} | | | | | | |")
    return out


def table(paths: list[str]) -> str:
    return HEADER + "\n" + "\n".join(rows(paths))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("files", nargs="*", help="metadata files (default: the public files in tests/data/vendor)")
    p.add_argument("--write", action="store_true", help="write the table of the default files into docs/sensor-metadata.md")
    args = p.parse_args()
    paths = args.files or [str(VENDOR / f) for f in FILES]
    text = table(paths)
    print(text)
    if args.write:
        if args.files:
            p.error("--write writes the table of the default files only")
        doc = DOC.read_text()
        start, end = doc.index(BEGIN) + len(BEGIN), doc.index(END)
        DOC.write_text(doc[:start] + "\n" + text + "\n" + doc[end:])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
