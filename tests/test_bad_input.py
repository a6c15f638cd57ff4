"""Bad input gets a clear error that names the problem and where it is (nothing is lost)."""

from __future__ import annotations

import copy
import json

import pytest
from pydantic import ValidationError
from utils.scenes import block_job, single_image_job

from solver import api
from solver.errors import JobError, RankDeficientError
from solver.schema.job import load_job


@pytest.fixture(scope="module")
def base() -> dict:
    return single_image_job("P2", seed=1)[0]


def codes(exc: JobError) -> set[str]:
    return {p.code for p in exc.problems}


def run(doc):
    return api.run(copy.deepcopy(doc))


def test_fewer_observations_than_unknowns(base):
    doc = copy.deepcopy(base)
    keep = {o["point"] for o in doc["observations"][:5]}
    doc["points"] = [p for p in doc["points"] if p["id"] in keep]
    doc["observations"] = doc["observations"][:5]
    with pytest.raises(JobError) as e:
        run(doc)
    assert "insufficient_observations" in codes(e.value)
    assert "10 observations for 14 unknowns" in str(e.value)


def test_unknown_references_all_reported(base):
    doc = copy.deepcopy(base)
    doc["observations"][0]["image"] = "nope"
    doc["observations"][1]["point"] = "ghost"
    doc["images"][0]["camera"] = "no-camera"
    with pytest.raises(JobError) as e:
        run(doc)
    locs = {tuple(p.location) for p in e.value.problems}
    assert ("observations", 0, "image") in locs
    assert ("observations", 1, "point") in locs
    assert ("images", 0, "camera") in locs


@pytest.mark.parametrize("bad", ["NaN", "Infinity", "-Infinity"])
def test_non_finite_numbers_rejected_by_the_schema(base, bad):
    text = json.dumps(base).replace(json.dumps(base["observations"][3]["line"]), bad, 1)
    with pytest.raises(ValidationError) as e:
        load_job(text)
    assert any(err["loc"][:2] == ("observations", 3) for err in e.value.errors())


def test_unknown_crs(base):
    doc = copy.deepcopy(base)
    doc["points"][2]["crs"] = "EPSG:999999"
    r = api.validate(doc)
    assert not r["valid"]
    assert r["problems"][0]["code"] == "unknown_crs"
    assert r["problems"][0]["location"] == ["points", 2, "crs"]


def test_unknown_model(base):
    doc = copy.deepcopy(base)
    doc["images"][0]["model"]["name"] = "K9"
    with pytest.raises(JobError) as e:
        run(doc)
    assert "unknown_model" in codes(e.value)
    assert "known: K1, K2" in str(e.value)


def test_rank_deficient_control_geometry_names_parameters():
    """Control points clustered on one across-track line of the image: enough observations,
    but the along-track variation of the platform (rates, accelerations) is not observable."""
    doc, truth = single_image_job("P2", seed=2, n_gcp=16, n_check=0)
    # keep the geometry but move every control point onto the ground line seen at one epoch:
    # copy one point's coordinates and line to all, keep their columns (across-track spread)
    first = doc["points"][0]["coordinates"]
    line0 = doc["observations"][0]["line"]
    for p, o in zip(doc["points"], doc["observations"]):
        p["coordinates"] = list(first)
        o["line"] = line0
    with pytest.raises(RankDeficientError) as e:
        run(doc)
    p = e.value.problems[-1]
    assert p.code == "rank_deficient"
    assert p.detail["parameters"], p.detail
    assert "undetermined" in p.message and "img-1/" in p.message
    json.dumps(e.value.to_dict(), allow_nan=False)  # strict JSON even when exactly singular


def test_exactly_singular_geometry_reports_strict_json():
    """One control point on the simulated triplet: the normal matrix may be exactly singular
    (condition infinite); the problem detail then says null, never Infinity."""
    from solver.simulate import presets
    from solver.simulate.scene import SceneSettings

    job = presets.prism_triplet(SceneSettings(preset="prism-triplet", seed=2008)).job()
    for p in [p for p in job["points"] if p["role"] == "gcp"][1:]:
        p["role"] = "tie"
    with pytest.raises(RankDeficientError) as e:
        run(job)
    detail = e.value.problems[-1].detail
    assert detail["condition"] is None or detail["condition"] < float("inf")
    json.dumps(e.value.to_dict(), allow_nan=False)


def test_observation_outside_image(base):
    doc = copy.deepcopy(base)
    doc["observations"][4]["column"] = 20000.0
    doc["observations"][5]["line"] = -3.0
    with pytest.raises(JobError) as e:
        run(doc)
    locs = {tuple(p.location) for p in e.value.problems if p.code == "outside_image"}
    assert locs == {("observations", 4, "column"), ("observations", 5, "line")}


def test_tie_point_seen_once_and_duplicates():
    doc, _ = block_job("P2", n_triplets=1, n_tie=4, n_gcp=8, n_check=1, seed=1)
    tie = next(p["id"] for p in doc["points"] if p["role"] == "tie")
    doc["observations"] = [o for o in doc["observations"] if not (o["point"] == tie and o["image"] != "T00-nadir")]
    doc["points"].append(copy.deepcopy(doc["points"][0]))
    with pytest.raises(JobError) as e:
        run(doc)
    assert {"tie_point_underdetermined", "duplicate_id"} <= codes(e.value)


def test_missing_initial_position(base):
    doc = copy.deepcopy(base)
    del doc["images"][0]["approx_state"]
    with pytest.raises(JobError) as e:
        run(doc)
    assert "no_initial_position" in codes(e.value)


def test_validate_reports_degrees_of_freedom(base):
    r = api.validate(base)
    assert r["valid"] and r["n_observations"] == 28 and r["n_unknowns"] == 14 and r["dof"] == 14


# -- issue 13: every malformed input is refused with its location, never an exception -----------
from bad_job_cases import CASES, bad_job  # noqa: E402 (tests/ is on sys.path)


def refused_at(doc: dict, fn) -> set[tuple]:
    """Locations named when ``fn`` (api.validate or api.run) refuses ``doc``; fails the test
    when it is accepted or raises anything but a schema or job error."""
    try:
        result = fn(copy.deepcopy(doc))
    except ValidationError as exc:
        return {tuple(e["loc"]) for e in exc.errors()}
    except JobError as exc:
        return {tuple(p.location) for p in exc.problems}
    assert fn is api.validate and not result["valid"], "accepted"
    return {tuple(p["location"]) for p in result["problems"]}


@pytest.mark.parametrize("case", sorted(CASES))
def test_malformed_job_is_refused_with_its_location(case):
    doc, where = bad_job(case), CASES[case][1]
    assert where in refused_at(doc, api.validate)
    if case != "models_500_times":  # refused by the schema before any solve either way
        assert where in refused_at(doc, api.run)


def test_lines_only_job_without_points_solves():
    """A job with control lines and "points": [] (once a numba typing error: the empty point
    array had shape (0,) instead of (0, 3))."""
    from utils.line_scenes import lines_job

    doc, _ = lines_job("P2", n_check=0, n_gcp=0)
    doc["points"] = []
    assert api.validate(doc)["valid"]
    assert api.run(doc)["adjustment"]["converged"]


def test_numerical_failure_of_the_solve_is_a_job_error(monkeypatch):
    """The last line of defence: linear-algebra, arithmetic and PROJ failures escaping the
    checks are the document's numbers' fault (JobError at the root); other exceptions are bugs
    and propagate (the service answers those 500)."""
    import numpy as np

    import solver.adjust

    doc = bad_job("lines_as_float")
    doc["cameras"][0]["lines"] = 16000

    def fails(exc):
        def adjust_job(*args, **kwargs):
            raise exc

        return adjust_job

    monkeypatch.setattr(solver.adjust, "adjust_job", fails(np.linalg.LinAlgError("SVD did not converge")))
    with pytest.raises(JobError) as e:
        api.run(copy.deepcopy(doc))
    assert e.value.problems[0].code == "unusable_values" and e.value.problems[0].location == ()
    monkeypatch.setattr(solver.adjust, "adjust_job", fails(OverflowError("overflow")))
    with pytest.raises(JobError):
        api.run(copy.deepcopy(doc))
    monkeypatch.setattr(solver.adjust, "adjust_job", fails(KeyError("a bug")))
    with pytest.raises(KeyError):
        api.run(copy.deepcopy(doc))
