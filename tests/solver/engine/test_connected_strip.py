"""The connected strip of the scale benchmark (tests/utils/scenes.py ``connected_strip_job``):
neighbouring scenes share points, so the images of the whole strip are linked as in a real strip
(a banded reduced camera system), and the observations are the model's own (the adjustment
recovers its truth)."""

from __future__ import annotations

import collections

import numpy as np
from utils.scenes import connected_strip_job

from solver.api import run

SIGMA0_BAND = (0.85, 1.15)  # sigma0 of ~2,500 residual pairs drawn with the declared 0.5 px noise
POINT_ABS_M = 6.0  # check points (exact coordinates) against the adjustment: ~2-3 m sigma at 2.5 m ground pixels


def test_neighbouring_scenes_share_points_and_only_they() -> None:
    job, _truth = connected_strip_job("P2", n_triplets=4, points_per_triplet=150, n_gcp=4, n_check=2, seed=3)
    scenes_of = collections.defaultdict(set)
    images_of = collections.Counter()
    for o in job["observations"]:
        scenes_of[o["point"]].add(int(o["image"][1:3]))
        images_of[o["point"]] += 1
    assert set(images_of.values()) <= {3, 4, 5, 6} and {3, 6} <= set(images_of.values())
    pairs = collections.Counter(tuple(sorted(s)) for s in scenes_of.values() if len(s) > 1)
    assert set(pairs) == {(0, 1), (1, 2), (2, 3)}  # every neighbour linked, nothing farther (banded)
    assert all(n >= 20 for n in pairs.values()), pairs
    roles = collections.Counter(p["role"] for p in job["points"])
    assert roles["gcp"] == 4 and roles["check"] == 2


def test_the_adjustment_recovers_the_strip_it_was_generated_from() -> None:
    job, _truth = connected_strip_job("P2", n_triplets=3, points_per_triplet=150, n_gcp=3, n_check=3, seed=5)
    report = run(job)
    adj = report["adjustment"]
    assert adj["converged"], adj["message"]
    assert SIGMA0_BAND[0] < adj["sigma0_aposteriori"] < SIGMA0_BAND[1]
    rms = report["checkpoints"]["rmse_m"]
    assert max(rms["e"], rms["n"]) < POINT_ABS_M, rms
    assert np.isfinite([rms["e"], rms["n"], rms["u"]]).all()
