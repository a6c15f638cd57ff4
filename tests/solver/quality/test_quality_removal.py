"""Reinstatement, lost control points and check-point blunders of data snooping
(solver/procedures/snooping.py ``snooping_adjustment``, solver/quality/removal.py, docs/quality.md), against
independent evidence: the w-test of the same observation inside the adjustment (the linear
theory says the test of an observation outside the adjustment equals it), injected blunders."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from tolerances import SAME_NUMBER_REL
from utils.scenes import block_job

from solver.adjust import adjust_once
from solver.api import run
from solver.quality.outlier_tests import predicted_test, snoop
from solver.quality.removal import INFLATE, Candidate, with_candidates
from solver.schema.job import BlunderDetection, load_job

# the predicted w of a removed observation vs the test inside the adjustment: the nonlinearity of
# a 6-px error (the statistics are evaluated at solutions 6 px apart); a cofactor without the
# parameters' covariance (I instead of I + J Q_xx J^T) is off by 1 / sqrt(r) ~ 20-40 %
PREDICTED_W_REL = 0.02
BLUNDER_ESTIMATE_PX = 1.5  # the estimate of a 6-px error: 0.5 px noise over redundancy ~0.5
ATTITUDE_ESTIMATE_DEG = 0.006  # three sigmas of a sample (0.002 deg) over its redundancy (~0.9)
STATE_ESTIMATE_M = 3.0  # ECEF m: 1.5 sigma of a state sample over its redundancy (~0.4-0.7)
SAMPLE_TIME_S = 1e-6  # a rejected sample's epoch as the report writes it back

DEFAULTS = BlunderDetection()


@pytest.fixture(scope="module")
def block():
    return block_job(model="P1", n_tie=30, n_gcp=14, n_check=6, seed=3, gcp_sigma_m=0.5)


def test_test_outside_the_adjustment_equals_the_w_test_inside(block) -> None:
    """An image point with a 6-px error: its w inside the adjustment, and the test of its
    predicted residual against the adjustment without it (put back with inflated sigmas), are
    the same statistic in linear theory; so are the estimated errors (the predicted residual
    is the error estimate Q^-1 v of the inside test)."""
    job, _truth = copy.deepcopy(block)
    ties = [i for i, o in enumerate(job["observations"]) if "-T" in o["point"]]
    k = ties[7]
    job["observations"][k]["column"] += 6.0
    full = load_job(copy.deepcopy(job))
    problem = adjust_once(full).problem
    inside = next(t for t in snoop(problem, DEFAULTS).tests if t.group.removal == ("observation", k))
    without = full.model_copy(update={"observations": [o for i, o in enumerate(full.observations) if i != k]})
    item = Candidate("image_point", full.observations[k], full.observations[k].point)
    aug_problem = adjust_once(with_candidates(without, full, [item])).problem
    sn = snoop(aug_problem, DEFAULTS)
    n = len(without.observations)
    t = next(t for t in sn.tests if t.group.removal == ("observation", n))
    out = predicted_test(sn, t, INFLATE)
    assert out["w"] == pytest.approx(inside.w, rel=PREDICTED_W_REL)
    assert out["critical"] == pytest.approx(inside.critical, rel=SAME_NUMBER_REL)
    np.testing.assert_allclose(out["estimated_error"], inside.error, atol=PREDICTED_W_REL * 6.0)
    assert out["estimated_error"][1] == pytest.approx(6.0, abs=BLUNDER_ESTIMATE_PX)


def test_a_check_point_image_blunder_is_named(block) -> None:
    """A check point's image point moved 20 px: the check point is not in the adjustment (no
    snooping test sees it), its normalised discrepancy does; the report names it, and only it
    (the clean run names none)."""
    job, _truth = copy.deepcopy(block)
    job["options"] = {"blunder_detection": {}}
    clean = run(copy.deepcopy(job))
    assert clean["quality"]["check_point_outliers"] == []
    checks = {p["id"] for p in job["points"] if p["role"] == "check"}
    k = next(i for i, o in enumerate(job["observations"]) if o["point"] in checks)
    job["observations"][k]["column"] += 20.0
    rep = run(job)
    named = [o["point"] for o in rep["quality"]["check_point_outliers"]]
    assert named == [job["observations"][k]["point"]]
    assert any(job["observations"][k]["point"] in w and "discrepancy test" in w for w in rep["warnings"])
    # nothing in the adjustment was touched: the blunder is outside it
    assert rep["quality"]["rejected"] == [] and rep["quality"]["not_identifiable"] == []


def test_a_moved_fixed_control_point_is_tested_through_its_rays(block) -> None:
    """``control: fixed``: a control point moved 20 m north has no survey prior to test; the
    bias of its known coordinates maps to its rays through the point Jacobian, and its 3-D test
    (kind control_point, fixed: true) finds it, estimates the move, and its removal (the point
    becomes a tie point) leaves nothing failing. The clean run rejects nothing."""
    job, _truth = copy.deepcopy(block)
    job["options"] = {"control": "fixed", "blunder_detection": {"action": "report"}}
    clean = run(copy.deepcopy(job))
    assert clean["quality"]["rejected"] == [] and clean["quality"]["not_identifiable"] == []
    gcp = [p for p in job["points"] if p["role"] == "gcp"][3]
    assert sum(o["point"] == gcp["id"] for o in job["observations"]) == 3
    gcp["coordinates"][1] += 20.0 / 110540.0
    job["options"]["blunder_detection"] = {}
    rep = run(job)
    q = rep["quality"]
    assert q["not_identifiable"] == []
    (r,) = q["rejected"]
    assert (r["kind"], r["point"], r["fixed"], r["removed"]) == ("control_point", gcp["id"], True, True)
    # metres east, north, up of the known coordinates; about 3 sigma of the estimate: 1.5 m in
    # plan (0.5 px of a ~2.5-m GSD over three rays, and the orientation's share), 4 m in height
    # (the triplet's base-to-height ratio); measured (-0.6, 21.0, -1.0) without a robust start,
    # (0.5, 19.6, -1.7) with it (rejected in an adjustment without some other rays, put back later)
    err = np.asarray(r["estimated_error"])
    assert np.all(np.abs(err - [0.0, 20.0, 0.0]) <= [1.5, 1.5, 4.0]), err
    assert rep["adjustment"]["chi2"]["passed"]
    assert q["lost_control"]["points"] == [gcp["id"]]
    assert any(gcp["id"] in w and "removed control point" in w for w in rep["warnings"])


def test_a_fixed_control_point_in_one_image_is_not_identifiable() -> None:
    """One image: a fixed control point's single ray cannot tell a moved point from a wrong image
    point (the test spaces coincide): one non-identifiable group of the two, removed."""
    from utils.scenes import single_image_job

    job, _ = single_image_job(model="K2", n_gcp=14, n_check=4, seed=5, gcp_sigma_m=0.5)
    job["options"] = {"control": "fixed", "blunder_detection": {}}
    gcp = [p for p in job["points"] if p["role"] == "gcp"][2]
    gcp["coordinates"][0] += 30.0 / (111320.0 * np.cos(np.radians(gcp["coordinates"][1])))
    q = run(job)["quality"]
    groups = [{(m["kind"], m["point"]) for m in g["members"]} for g in q["not_identifiable"]]
    assert {("control_point", gcp["id"]), ("image_point", gcp["id"])} in groups
    assert q["rejected"] == []


def test_a_line_image_point_blunder_is_found_and_removed() -> None:
    """Rigorous lines: one measured point of a line image moved 10 px in column is rejected and
    removed (its test fails, its estimated error is the move's component across the line), the
    clean run rejects nothing."""
    from utils.line_scenes import lines_job

    job, _ = lines_job(seed=2)
    job["options"] = {"blunder_detection": {}}
    clean = run(copy.deepcopy(job))
    assert clean["quality"]["rejected"] == [] and clean["quality"]["not_identifiable"] == []
    gl = job["lines"][3]
    lo = gl["observations"][0]
    lo["points"][4]["column"] += 10.0
    rep = run(job)
    (r,) = rep["quality"]["rejected"]
    assert (r["kind"], r["line"], r["image"], r["point"], r["removed"]) == ("line_point", gl["id"], lo["image"], 4, True)
    assert r["w"] > r["critical"]
    # the perpendicular distance sees the column move times |sin| of the line's angle to the
    # columns axis: between 1 and 10 px whatever the line's direction (>= 6 deg here)
    assert 1.0 < abs(r["estimated_error"][0]) <= 10.5
    assert rep["adjustment"]["chi2"]["passed"]
    assert rep["quality"]["not_identifiable"] == []
    # flagged in the lines section with its measured pixels (the index shifts with removals)
    assert r["measured"] == {"line": lo["points"][4]["line"], "column": lo["points"][4]["column"]}
    flagged = {it["id"]: it["rejected"] for it in rep["lines"]["items"]}
    assert flagged[gl["id"]] == [{"image": lo["image"], **r["measured"]}]
    assert all(v == [] for k, v in flagged.items() if k != gl["id"])


def test_an_attitude_sample_blunder_is_found_and_removed() -> None:
    """Measured attitude (sigma 0.002 deg): one sample's pitch moved 0.02 deg (10 sigma) is
    rejected and removed with its estimated error; the clean run rejects nothing."""
    import json
    from pathlib import Path

    job = json.loads((Path(__file__).resolve().parents[3] / "examples" / "prism-triplet-direct.json").read_text())
    job["options"]["blunder_detection"] = {}
    clean = run(copy.deepcopy(job))
    assert clean["quality"]["rejected"] == [] and clean["quality"]["not_identifiable"] == []
    n_before = sum(len(im["attitude"]) for im in job["images"])
    sample = job["images"][1]["attitude"][2]
    sample["pitch_deg"] += 0.02
    rep = run(job)
    (r,) = rep["quality"]["rejected"]
    assert (r["kind"], r["time_s"], r["removed"]) == ("attitude_sample", sample["time_s"], True)
    np.testing.assert_allclose(r["estimated_error"], [0.0, 0.02, 0.0], atol=ATTITUDE_ESTIMATE_DEG)
    # flagged in the attitude section: the block of that image lists the removed epoch
    blocks = {tuple(b["images"]): b["rejected_samples_s"] for b in rep["attitude"]}
    assert [v for k, v in blocks.items() if job["images"][1]["id"] in k] == [[sample["time_s"]]]
    assert sum(len(v) for v in blocks.values()) == 1
    # the adjustment after removal has one sample fewer (samples shared by images count once)
    assert sum(a["n_samples"] for a in rep["attitude"]) == sum(a["n_samples"] for a in clean["attitude"]) - 1
    assert n_before > 0


def test_a_point_removed_whole_is_tested_against_the_final_orientation() -> None:
    """One image: a control point's ray and survey removed together (a non-identifiable group)
    leave nothing of the point; put back together (inflated), the test of the ray against the
    final orientation and the survey equals, in linear theory, its w-test inside the adjustment
    with both (the point estimated from its own ray and survey, the orientation from the rest)."""
    from utils.scenes import single_image_job

    from solver.quality.removal import remove, whole_points

    job, _ = single_image_job(model="K2", n_gcp=14, n_check=0, seed=5, gcp_sigma_m=0.5)
    gcp = [p for p in job["points"] if p["role"] == "gcp"][4]
    k = next(i for i, o in enumerate(job["observations"]) if o["point"] == gcp["id"])
    job["observations"][k]["column"] += 3.0  # w ~ 6 inside
    full = load_job(copy.deepcopy(job))
    problem = adjust_once(full).problem
    inside = next(t for t in snoop(problem, DEFAULTS).tests if t.group.removal == ("observation", k))
    p_idx = next(i for i, p in enumerate(full.points) if p.id == gcp["id"])
    without, _collateral = remove(full, [("observation", k), ("control", p_idx)])
    assert gcp["id"] not in {p.id for p in without.points}
    items = [Candidate("image_point", full.observations[k], gcp["id"]), Candidate("control_point", None, gcp["id"])]
    assert whole_points(without, items) == {gcp["id"]}
    aug = adjust_once(with_candidates(without, full, items)).problem
    sn = snoop(aug, DEFAULTS)
    t = next(t for t in sn.tests if t.group.kind == "image_point" and t.group.label["point"] == gcp["id"])
    out = predicted_test(sn, t, INFLATE, whole=True)
    # 2 %: nonlinearity over a 3-px error; the formula for a point determined by the rest
    # (whole=False) gives w = 0.02 here: the inflated survey leaves the ray nothing to test
    assert out["dof"] == inside.dof
    assert out["w"] == pytest.approx(inside.w, rel=PREDICTED_W_REL)


@pytest.fixture(scope="module")
def single_with_blunders() -> tuple[set[str], dict[bool, dict]]:
    """prism-single (the independent simulator), seed 4, as bench/bench_snooping.py blunders
    --seeds 4: four image blunders and a control point moved; the injected points and the
    reports without and with reinstatement."""
    from utils.blunder_scenes import prism_single_with_blunders

    job, injected = prism_single_with_blunders(seed=4)
    reports = {}
    for flag in (False, True):
        j = copy.deepcopy(job)
        j.setdefault("options", {})["blunder_detection"] = {"reinstate": flag, "max_rejections": 50}
        reports[flag] = run(j)
    return injected, reports


def test_reinstatement_puts_back_a_clean_group_removed_along_the_way(single_with_blunders) -> None:
    """prism-single (the independent simulator), seed 4, four image blunders and a control
    point moved: one at a time, snooping also removes a clean {image point, survey} group on the
    way (its test failed while the blunders were in); tested against the final solution it
    passes and is put back. Every reinstated observation passed its predicted test, none of them
    is a blunder, and nothing removed in the end is clean."""
    injected, full = single_with_blunders
    reports = {flag: rep["quality"] for flag, rep in full.items()}

    def removed_points(q):
        out = {r["point"] for r in q["rejected"] if r["removed"]}
        return out | {m["point"] for g in q["not_identifiable"] for m in g["members"] if m["removed"]}

    back = reports[True]["reinstated"]
    assert back, "this scene removes a clean group on the way (measured); nothing was reinstated"
    assert all(r["predicted"]["passed"] and r["predicted"]["w"] <= r["predicted"]["critical"] for r in back)
    assert {r["point"] for r in back} <= removed_points(reports[False]) - injected
    assert removed_points(reports[True]) <= injected


def test_an_ephemeris_sample_blunder_is_found_and_removed() -> None:
    """A pass (PASS-J2) with the ephemeris weighted (sigma 2 m): the sample at one epoch moved
    50 m in x (in every image that carries it) is rejected, estimated ~50 m in x, removed from the
    images, and the others stay; the clean run rejects nothing."""
    import json
    from pathlib import Path

    job = json.loads((Path(__file__).resolve().parents[3] / "examples" / "prism-triplet-direct.json").read_text())
    job["options"]["ephemeris"]["sigma_position_m"] = 2.0
    job["options"]["blunder_detection"] = {}
    clean = run(copy.deepcopy(job))
    assert clean["quality"]["rejected"] == [] and clean["quality"]["not_identifiable"] == []
    epochs = sorted({g["time_s"] for g in clean["quality"]["reliability"]["groups"] if g["kind"] == "ephemeris_sample"})
    assert len(epochs) == 3
    t = epochs[1]
    for im in job["images"]:
        for s in im["ephemeris"]:
            if abs(s["time_s"] - t) < SAMPLE_TIME_S:
                s["position_ecef_m"][0] += 50.0
    rep = run(job)
    (r,) = rep["quality"]["rejected"]
    assert (r["kind"], r["time_s"], r["removed"]) == ("ephemeris_sample", t, True)
    np.testing.assert_allclose(r["estimated_error"][:3], [50.0, 0.0, 0.0], atol=STATE_ESTIMATE_M)
    assert rep["adjustment"]["chi2"]["passed"]
    # flagged in the ephemeris section of every image that carried the sample
    carried = {im["id"] for im in job["images"] if any(abs(s["time_s"] - t) < SAMPLE_TIME_S for s in im["ephemeris"])}
    flagged = {e["image"]: e["rejected_samples_s"] for e in rep["ephemeris"]["images"]}
    assert carried and {k for k, v in flagged.items() if v} == carried
    assert all(v == [pytest.approx(t, abs=SAMPLE_TIME_S)] for k, v in flagged.items() if k in carried)
    assert rep["ephemeris"]["rejected_states"] == []


def test_a_weighted_line_0_state_blunder_is_found_and_removed() -> None:
    """OA-J2 (one orbit state per image, weighted from the interpolated ephemeris, sigma 2 m):
    one image's ephemeris moved 250 m in x (about three times the state's MDB, ~80 m in the
    clean run) makes its line-0 state fail; it is removed (the state stays as the unweighted
    approximate state) and flagged in the ephemeris section; the clean run rejects nothing."""
    import json
    from pathlib import Path

    job = json.loads((Path(__file__).resolve().parents[3] / "examples" / "prism-triplet-direct.json").read_text())
    for im in job["images"]:
        im["model"] = {"name": "OA-J2"}
    job["options"]["ephemeris"]["sigma_position_m"] = 2.0
    job["options"]["blunder_detection"] = {}
    clean = run(copy.deepcopy(job))
    assert clean["quality"]["rejected"] == [] and clean["quality"]["not_identifiable"] == []
    target = job["images"][1]["id"]
    for s in job["images"][1]["ephemeris"]:
        s["position_ecef_m"][0] += 250.0
    rep = run(job)
    q = rep["quality"]
    states = [r for r in q["rejected"] if r["kind"] == "ephemeris_sample"]
    assert [(r["image"], r["time_s"], r["removed"]) for r in states] == [(target, None, True)], q["rejected"]
    # m (ECEF x, y, z): the interpolated state moved 250 m in x. The estimate's sigma per
    # component is sigma / sqrt(r) = MDB / sqrt(lambda0(d)) (d = 6, position and velocity; from
    # the clean run's MDBs of this state, much of a position error being taken up by the
    # attitude): within 3 of them (measured 250.8, 9.6, -21.2)
    (g,) = [g for g in clean["quality"]["reliability"]["groups"] if g["kind"] == "ephemeris_sample" and g["image"] == target]
    sigma_est = np.asarray(g["mdb"][:3]) / np.sqrt(clean["quality"]["reliability"]["lambda0"][str(len(g["mdb"]))])
    assert np.all(np.abs(np.asarray(states[0]["estimated_error"][:3]) - [250.0, 0.0, 0.0]) <= 3 * sigma_est), sigma_est
    # flagged in the ephemeris section; the image no longer has an ephemeris there (its state is
    # the unweighted approximate state now), the others keep theirs, weighted
    assert rep["ephemeris"]["rejected_states"] == [target]
    eph = {e["image"]: e for e in rep["ephemeris"]["images"]}
    assert set(eph) == {im["id"] for im in job["images"]} - {target}
    assert all(e["used_as"] == "weighted_observation" for e in eph.values())
    assert rep["adjustment"]["chi2"]["passed"]



def test_rejected_csv_lists_reinstated_observations_and_lost_control(single_with_blunders) -> None:
    """rejected.csv (service.report_csv) of the same scene: one row per failed test or group
    member with its status, the reinstated observations with their predicted test, and one
    row per control point the removals took away; nothing listed twice."""
    from service.report_csv import table_rows, to_csv

    _injected, full = single_with_blunders
    q = full[True]["quality"]
    rows = table_rows(full[True], "rejected")
    by_status: dict[str, list] = {}
    for r in rows:
        by_status.setdefault(r["status"], []).append(r)
    n_members = sum(len(g["members"]) for g in q["not_identifiable"])
    n_single_back = sum(1 for r in q["reinstated"] if not any(
        (m["kind"], m["image"], m["point"]) == (r["kind"], r["image"], r["point"]) for g in q["not_identifiable"] for m in g["members"]))
    assert len(rows) == len(q["rejected"]) + n_members + n_single_back + len(q["lost_control"]["points"])
    assert len(by_status["reinstated"]) == len(q["reinstated"]) > 0
    assert all(r["predicted_passed"] is True and r["predicted_w"] <= r["predicted_critical"] for r in by_status["reinstated"])
    assert sorted(r["point"] for r in by_status["lost_control"]) == sorted(q["lost_control"]["points"])
    assert all(r["predicted_check_rmse_m_after"] == q["lost_control"]["predicted_check_rmse_m"]["after"] for r in by_status["lost_control"])
    assert all(float(r["w"]) > float(r["critical"]) for r in by_status["removed"])
    text = to_csv(rows)
    assert text.splitlines()[0].startswith("status,group,kind")
