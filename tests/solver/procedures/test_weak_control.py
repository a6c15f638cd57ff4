"""The weak-control rule of the default procedure (solver.procedures.weak_control), against an
independent simulated PRISM triplet (solver.simulate: cameras pitched +-23.8 degrees, truth
attitude with bias and rates) with four control points in the first fifth of the strip, the
ephemeris weighted (2 m, 0.01 m/s) and no attitude samples, the layout of the issue."""

from __future__ import annotations

import copy
import json

import pytest

from solver.api import run
from solver.cli import main
from solver.procedures.weak_control import BAND_FRACTION, _band_warning, _narrow, control_extent
from solver.schema.job import load_job

# measured on seed 1 (docs/quality.md, the weak-control rule): PASS-J2 131 m without the rule,
# 6.0 m with it, 2.5 m with full control; the rule's aim, 2x full control, is reached on one
# seed of three (the truth's attitude rates, held, move the far check points)
WITHOUT_RULE_M = 50.0  # the default before the rule: tens to hundreds of metres
WITH_RULE_OVER_FULL = 3.0  # check RMSE with the rule / with full control, PASS-J2 (measured 2.4, 4.1, 1.4 on seeds 1-3)


@pytest.fixture(scope="module")
def triplet(tmp_path_factory):
    out = tmp_path_factory.mktemp("weak") / "tri.json"
    assert main(["simulate", "prism-triplet", "-o", str(out), "--seed", "1", "--model", "PASS-J2",
                 "--weight-ephemeris", "2,0.01", "--gcps", "30", "--checks", "20", "--tie-points", "60"]) == 0
    job = json.loads(out.read_text())
    for im in job["images"]:
        im["attitude"] = []
    job["options"].pop("attitude", None)
    return job


def _weak(job: dict) -> dict:
    """Four control points in the first fifth of the nadir image's lines, every other control point a check."""
    j = copy.deepcopy(job)
    lines = next(c["lines"] for c in j["cameras"] if "nadir" in c["id"])
    line_of = {o["point"]: o["line"] for o in j["observations"] if "nadir" in o["image"]}
    early = sorted((p for p in j["points"] if p["role"] in ("gcp", "check") and line_of.get(p["id"], 1e9) < 0.2 * lines),
                   key=lambda p: line_of[p["id"]])
    keep = {p["id"] for p in early[:: max(1, len(early) // 4)][:4]}
    assert len(keep) == 4
    for p in j["points"]:
        if p["role"] in ("gcp", "check"):
            p["role"] = "gcp" if p["id"] in keep else "check"
    return j


def test_control_extent_names_the_band(triplet) -> None:
    extent = control_extent(load_job(_weak(triplet)))
    nadir = next(v for k, v in extent.items() if "nadir" in k)
    assert nadir.fraction < 0.2 < BAND_FRACTION
    full = control_extent(load_job(triplet))
    assert all(e.fraction > BAND_FRACTION for e in full.values())


def test_the_default_acts_on_undetermined_attitude_and_says_so(triplet) -> None:
    weak = _weak(triplet)
    full_rmse = run(triplet)["checkpoints"]["rmse_m"]["3d"]

    warned = copy.deepcopy(weak)
    warned["options"]["weak_control"] = "warn"
    warned["options"]["datum"] = {"undetermined": "report"}
    before = run(warned)
    assert before["checkpoints"]["rmse_m"]["3d"] > WITHOUT_RULE_M
    assert "weak_control" not in before["quality"]
    # the datum analysis sees the weakness: the tie points' tilts are far less determined than
    # with full control (measured, seed 1: 78 and 77 m at the solution, 105 and 111 m at the
    # initial values, against 1.4 m with full control)
    tilts = {d["direction"]: d["sigma_m"] for d in before["quality"]["datum"]["directions"]}
    full_tilts = {d["direction"]: d["sigma_m"] for d in run(copy.deepcopy(triplet))["quality"]["datum"]["directions"]}
    assert min(tilts["tilt_east"], tilts["tilt_north"]) > 5 * max(full_tilts["tilt_east"], full_tilts["tilt_north"])

    rep = run(weak)
    wc = rep["quality"]["weak_control"]
    flagged = {f["image"] for f in wc["undetermined"]}
    assert flagged and all("nadir" not in i for i in flagged)  # the oblique images' roll and yaw
    assert wc["check_rmse_3d_m_before"] == pytest.approx(before["checkpoints"]["rmse_m"]["3d"], rel=1e-6)
    for image in flagged:
        assert set(wc["orders"][image].values()) == {0}  # held at the constants
    after = rep["checkpoints"]["rmse_m"]["3d"]
    assert after == pytest.approx(wc["check_rmse_3d_m_after"])
    assert after < WITH_RULE_OVER_FULL * full_rmse, (after, full_rmse)
    # the report says what it did and that the control is a band
    assert rep["warnings"][0].startswith("weak control: the control did not determine")
    assert any("spans a band" in w for w in rep["warnings"])
    assert not [w for w in rep["quality"]["warnings"] if w["kind"] == "implausible_sigma"] or wc["still_undetermined"]


def _without_control_in(job: dict, image_part: str) -> dict:
    """``job`` with the control-point observations of the image whose id contains ``image_part``
    dropped: that image keeps only tie (and check) points."""
    j = copy.deepcopy(job)
    gcps = {p["id"] for p in j["points"] if p["role"] == "gcp"}
    j["observations"] = [o for o in j["observations"] if not (image_part in o["image"] and o["point"] in gcps)]
    return j


def test_an_image_with_only_tie_points_is_not_control_in_a_band(triplet) -> None:
    """An image without any control point has no band of control: its orientation comes from the
    other images through the tie points. Counting it as "control in a band" (the rule's
    condition) would hold its attitude and warn of a band it does not have; today's other jobs
    have control in every image, so only this test sees the difference."""
    job = load_job(_without_control_in(triplet, "forward"))
    extent = control_extent(job)
    forward = next(k for k in extent if "forward" in k)
    assert extent[forward].lines is None and extent[forward].fraction == 0.0
    assert forward not in _narrow(extent)
    assert all(e.fraction > BAND_FRACTION for k, e in extent.items() if k != forward)
    _, band = _band_warning(job)
    assert band is None  # the other images' control spans their lines: no band anywhere

    # with a band in the other images, the warning names them, not the forward image
    weak = load_job(_without_control_in(_weak(triplet), "forward"))
    extent = control_extent(weak)
    narrow = set(_narrow(extent))
    assert any("nadir" in k for k in narrow) and forward not in narrow
    _, band = _band_warning(weak)
    assert band is not None and "nadir" in band and "forward" not in band
