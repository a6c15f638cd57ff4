"""Pre-analysis (issue 15, item 6): the precision predicted from planned coordinates and the
approximate orientation, before any measurement, against the precision the adjustment of the
measured data then reports (independent evidence: the measured observations, noise and all,
and an adjustment that starts from the header states, not from the planned geometry)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from utils.scenes import block_job

from solver.adjust import adjust_job
from solver.api import preanalyse
from solver.commands import preanalysis_text
from solver.errors import JobError
from solver.schema.job import load_job

# pre-analysis of a plan vs the adjustment of the same scene, a-posteriori scale taken out: the
# geometry of the linearisation point differs (truth vs solution); a wrong cofactor is a factor
PLAN_VS_ADJUSTMENT_REL = 0.03
PLANNED_LINES_REL = 0.25  # pre-analysis with planned lines vs the adjustment with them: nominal vs measured line geometry

# the acceptance: within 25%. Measured 1-3% here (the adjusted report scales by its
# sigma0 a posteriori, about 1 +- 0.1 with 150 degrees of freedom; the pre-analysis by the
# a-priori 1), so 10% catches a missing term (the orientation part is most of the sigma)
RTOL = 0.10


def _planned(job: dict, report: dict) -> dict:
    """The job as planned: no observations; tie points at the positions the block will have."""
    plan = json.loads(json.dumps(job))
    plan["observations"] = []
    ties = {t["id"]: t for t in report["tie_points"]}
    for p in plan["points"]:
        if p["role"] == "tie":
            t = ties[p["id"]]
            p["coordinates"] = [t["lon_deg"], t["lat_deg"], t["height_m"]]
    return plan


@pytest.mark.parametrize("n_gcp", [8, 4])
def test_preanalysis_predicts_the_adjusted_precision(n_gcp):
    job = block_job("K2", n_triplets=1, n_tie=20, n_gcp=n_gcp, n_check=8, seed=31, noise_seed=3,
                    gcp_sigma_m=0.5, state_sigma=(20.0, 0.05))[0]
    rep = adjust_job(load_job(job))
    pre = preanalyse(_planned(job, rep))
    assert pre["kind"] == "preanalysis"
    # the same observations are planned as were measured (every point inside all three images)
    assert pre["adjustment"]["n_planned_image_points"] == len(job["observations"])
    assert pre["adjustment"]["n_unknowns"] == rep["adjustment"]["n_unknowns"]
    want = {p["id"]: p["sigma_m"] for p in rep["checkpoints"]["points"]}
    got = {p["id"]: p["sigma_m"] for p in pre["checkpoints"]["points"]}
    assert set(got) == set(want)
    for pid in want:
        for a in "enu":
            assert got[pid][a] == pytest.approx(want[pid][a], rel=RTOL), (pid, a)
    s0 = rep["adjustment"]["sigma0_aposteriori"]
    for a in "enu":
        # the RMS over the check points, with the a-posteriori scale taken out
        assert pre["checkpoints"]["predicted_rmse_m"][a] == pytest.approx(rep["checkpoints"]["predicted_rmse_m"][a] / s0, rel=PLAN_VS_ADJUSTMENT_REL)
    ties = {p["id"]: p for p in rep["tie_points"]}
    for p in pre["points"]:
        if p["role"] == "tie":
            np.testing.assert_allclose(p["sigma_m"]["u"], ties[p["id"]]["sigma_m"][2], rtol=RTOL)
    assert "check points (8)" in preanalysis_text(pre)


def test_fewer_control_points_predict_a_worse_block():
    sig = []
    for n_gcp in (8, 3):
        job = block_job("K2", n_triplets=1, n_tie=20, n_gcp=n_gcp, n_check=8, seed=31, noise_seed=3,
                        gcp_sigma_m=0.5, state_sigma=(20.0, 0.05))[0]
        rep = adjust_job(load_job(job))
        sig.append(preanalyse(_planned(job, rep))["checkpoints"]["predicted_rmse_m"]["3d"])
    assert sig[1] > 1.05 * sig[0], sig


def test_planned_points_need_coordinates():
    job = block_job("K2", n_triplets=1, n_tie=3, n_gcp=4, n_check=2, seed=31)[0]
    job["observations"] = []
    with pytest.raises(JobError) as err:
        preanalyse(job)
    assert err.value.problems[0].code == "planned_point_without_coordinates"
    assert err.value.problems[0].location[0] == "points"


@pytest.mark.parametrize("seed", [1, 2])
def test_planned_control_lines_improve_the_prediction_and_match_the_adjustment(seed: int) -> None:
    """One PRISM image, P2, 10 control points, 8 mono check points, and 12 planned control
    lines: the lines' planned image points (8 per line between the endpoints, as the measured
    ones) enter the pre-analysis, lower the predicted check-point sigmas, and the prediction
    matches what the adjustment of the measured lines and points (tests/utils/line_scenes.py: noise
    0.5 px, started from a header state 20 m off) then reports within the issue's 25 %
    (measured 4-7 %: that adjustment's sigma0 1.04-1.08; without the lines the pre-analysis
    predicts 1.6-2.4 times worse)."""
    from utils.line_scenes import lines_job

    job, _truth = lines_job(model="P2", n_lines=12, points_per_line=8, n_gcp=10, n_check=8, seed=seed)
    plan = json.loads(json.dumps(job))
    plan["observations"] = []
    for gl in plan["lines"]:
        gl["observations"] = []
    no_lines = {**json.loads(json.dumps(plan)), "lines": []}
    with_lines = preanalyse(plan)
    without = preanalyse(no_lines)
    assert with_lines["adjustment"]["n_planned_line_points"] == 12 * 8
    assert all(ln["images"] == ["img-1"] and ln["n_points"] == 8 for ln in with_lines["lines"])
    adjusted = adjust_job(load_job(job))
    a, b, c = (r["checkpoints"]["predicted_rmse_m"] for r in (with_lines, without, adjusted))
    for k in ("e", "n"):  # mono check points: east, north
        # planned lines add information: at least 20 % better (measured 1.6-2.4x)
        assert a[k] < 0.8 * b[k], (a, b)
        assert a[k] == pytest.approx(c[k], rel=PLANNED_LINES_REL), (a, c)
