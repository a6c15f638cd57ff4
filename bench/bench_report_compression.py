"""How much the store's zlib compression (service.store.payloads) saves on a big report.

Usage: ``python bench/bench_report_compression.py REPORT.json [DOCUMENT.json ...]``, e.g. with
a report of ``pba simulate strip --triplets 12 --tie-points 24000 -o strip.json`` then
``pba run strip.json -o report.json``. Prints, per file and zlib level, the stored size and
the time to compress and to decompress (one run each; a measurement, not a test).
"""

from __future__ import annotations

import sys
import time
import zlib
from pathlib import Path

from service.store.payloads import LEVEL


def main(paths: list[str]) -> int:
    for path in paths:
        raw = Path(path).read_text(encoding="utf-8").encode("utf-8")
        print(f"{path}: {len(raw) / 1e6:.1f} MB of JSON")
        for level in sorted({1, LEVEL, 9}):
            t0 = time.perf_counter()
            packed = zlib.compress(raw, level)
            t1 = time.perf_counter()
            zlib.decompress(packed)
            t2 = time.perf_counter()
            mark = " (the store's)" if level == LEVEL else ""
            print(
                f"  level {level}{mark}: {len(packed) / 1e6:.2f} MB, ratio "
                f"{len(raw) / len(packed):.1f}, compress {t1 - t0:.2f} s, "
                f"decompress {t2 - t1:.2f} s"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
