"""Recall of the approximate descriptor search (FLANN) against the exact one, on real crops.

``pba match`` finds each a feature's nearest b descriptors with OpenCV's FLANN (randomised
KD-trees) when a tile holds more than ``EXACT_PAIRS`` descriptor pairs
(:func:`solver.matching.features._nearest`), exactly below. This runs the matching of the real
Pleiades pairs in tests/data/matching with every tile's :func:`band_matches` computed twice,
with FLANN (whatever the tile's size) and exactly (every distance), and prints, per pair: the
tiles ``pba match`` itself searches with FLANN, the matches the exact search accepts (ratio
test and mutual check), the share of them the FLANN search accepts too (its recall), and the
matches only the FLANN search accepts.

Usage: ``python bench/bench_match_recall.py``
"""

from __future__ import annotations

import sys
import tempfile
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DATA = ROOT / "tests" / "data" / "matching"
PAIRS = {"ventoux": ("ventoux_left", "ventoux_right", ["--heights", "400,700"]), "gizeh": ("gizeh_img1", "gizeh_img2", [])}


def main() -> None:
    import solver.matching.features as F
    from solver.cli import main as cli

    warnings.simplefilter("ignore")
    approximate = F.band_matches
    tally: dict[str, int] = {}

    def both(da, db, kb, s0, s1, s, counts):
        limit = F.EXACT_PAIRS
        if len(da) * len(db) > limit:
            tally["flann_tiles"] = tally.get("flann_tiles", 0) + 1
        try:
            F.EXACT_PAIRS = 0
            got = approximate(da, db, kb, s0, s1, s, counts)
            F.EXACT_PAIRS = 10**12
            ref = approximate(da, db, kb, s0, s1, s, {})
        finally:
            F.EXACT_PAIRS = limit
        a, e = set(zip(*map(list, got), strict=True)), set(zip(*map(list, ref), strict=True))
        tally["exact"] = tally.get("exact", 0) + len(e)
        tally["both"] = tally.get("both", 0) + len(a & e)
        tally["only_approximate"] = tally.get("only_approximate", 0) + len(a - e)
        tally["tiles"] = tally.get("tiles", 0) + 1
        return got

    F.band_matches = both
    for name, (a, b, opts) in PAIRS.items():
        tally.clear()
        with tempfile.TemporaryDirectory() as tmp:
            cli(["match", str(DATA / f"{a}.tif"), str(DATA / f"{b}.tif"), "-o", str(Path(tmp) / "t.csv"), "-q", *opts])
        recall = tally.get("both", 0) / max(tally.get("exact", 0), 1)
        print(f"{name}: {tally.get('flann_tiles', 0)} of {tally.get('tiles', 0)} tiles searched with FLANN; exact search accepts "
              f"{tally.get('exact', 0)} matches, the approximate one {recall:.1%} of them (recall) and {tally.get('only_approximate', 0)} others")


if __name__ == "__main__":
    main()
