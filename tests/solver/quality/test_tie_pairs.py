"""``quality.tie_pairs``: tie points per image pair found, kept and removed by data snooping.

The counts are checked on the example PRISM triplet (40 tie points, each in the three images)
against removals chosen by hand, and end to end: a blunder planted in one image point is
removed by snooping and counted in exactly the two pairs that image forms.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

from solver import api
from solver.commands import summary_text
from solver.quality.tie_pairs import tie_pairs
from solver.schema.job import load_job

JOB = json.loads((Path(__file__).parents[3] / "examples" / "prism-triplet.json").read_text())
B, N, F = "prism-backward", "prism-nadir", "prism-forward"
N_TIES = 40
BLUNDER_PX = 8.0  # far beyond the example's 0.5 px noise: snooping must remove it


def _rows(report_observations: list[dict]) -> dict[tuple[str, str], tuple[int, int, int]]:
    return {tuple(r["images"]): (r["found"], r["kept"], r["removed"]) for r in tie_pairs(load_job(JOB), report_observations)}


def test_counts_without_removals():
    assert _rows([]) == {(B, N): (N_TIES, N_TIES, 0), (B, F): (N_TIES, N_TIES, 0), (N, F): (N_TIES, N_TIES, 0)}


def test_counts_with_removals():
    rejected = [
        {"image": F, "point": "T0001", "rejected": True},  # one image point: the two pairs with F
        {"image": B, "point": "T0002", "rejected": True},  # two image points of one tie point: every pair
        {"image": N, "point": "T0002", "rejected": True},
        {"image": B, "point": "T0003", "rejected": False},  # kept
    ]
    assert _rows(rejected) == {(B, N): (N_TIES, N_TIES - 1, 1), (B, F): (N_TIES, N_TIES - 2, 2), (N, F): (N_TIES, N_TIES - 2, 2)}


def test_snooping_report_counts_the_removed_tie_point():
    job = copy.deepcopy(JOB)
    obs = next(o for o in job["observations"] if o["point"] == "T0007" and o["image"] == N)
    obs["line"] += BLUNDER_PX
    job["options"] = {**job.get("options", {}), "blunder_detection": {}}
    report = api.run(job)
    rows = {tuple(r["images"]): r for r in report["quality"]["tie_pairs"]}
    removed = {(o["image"], o["point"]) for o in report["observations"] if o.get("rejected")}
    assert (N, "T0007") in removed
    assert all(r["found"] == N_TIES and r["kept"] + r["removed"] == r["found"] for r in rows.values())
    assert rows[(B, N)]["removed"] >= 1 and rows[(N, F)]["removed"] >= 1
    assert "tie points per image pair" in summary_text(report)
