"""Line models on the simulated CBERS scene (scripts/experiments_seed002.py): the corrected
equivalent planes model beats the uncorrected one, the rigorous model is at least as accurate as
the corrected one; the script rewrites only its own section of docs/experiments.md."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from solver.api import run

SCRIPT = Path(__file__).resolve().parents[3] / "scripts" / "experiments_seed002.py"


@pytest.fixture(scope="module")
def exp():
    spec = importlib.util.spec_from_file_location("experiments_seed002", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def cbers_job(exp):
    """The simulated scene's job with error-free twins of the 8 check points (orientation error)."""
    return exp.base_job(exp.simulate(7))


@pytest.mark.parametrize("model,config,gain", [("MT12", "A", 0.5), ("MT8", "C", 0.9)])
def test_corrected_planes_beat_uncorrected_and_rigorous_is_at_least_as_accurate(exp, cbers_job, model, config, gain):
    """Lines alone (50 roads with the 12-parameter model, 30 with MT8), check-point RMSE with
    error-free check measurements (the orientation error alone; with the measured check points
    their own 0.5 px noise, ~10 m per axis, would hide it).

    The correction removes the Earth-rotation skew (4x on the 12-parameter model; MT8's own model
    error of ~6 m makes its gain smaller). At its fixed point the corrected model and the rigorous
    one are the same estimator up to linearisation, so "at least as accurate" is asserted with a
    5 % allowance (over seeds 7-9 they differ by 1-2 % either way).
    """
    cfg = next(c for c in exp.CONFIGS if c.key == config)
    rmse = {}
    for name, line_model, correction in (
        ("uncorrected", "equivalent_planes", "none"),
        ("corrected", "equivalent_planes", "iterated"),
        ("rigorous", "rigorous", "iterated"),
    ):
        report = run(exp.configure(cbers_job, cfg, True, False, line_model, correction, model))
        assert report["adjustment"]["converged"]
        rmse[name] = exp.measure(report)["orient_m"]
        gsd = exp.measure(report)["gsd_m"]
    assert rmse["corrected"] < gain * rmse["uncorrected"], rmse
    assert rmse["rigorous"] <= 1.05 * rmse["corrected"], rmse
    assert rmse["rigorous"] < 0.5 * gsd, rmse


def test_scene_lines_are_road_segments_in_sad69_utm(cbers_job):
    assert cbers_job["crs"] == "EPSG:29192"
    ids = [gl["id"] for gl in cbers_job["lines"]]
    assert ids[:2] == ["L01", "L02"] and len([i for i in ids if i[0] == "L"]) == 50 and len([i for i in ids if i[0] == "R"]) == 30
    gl = cbers_job["lines"][0]
    assert gl["sigma_m"] == [0.5] * 3 and len(gl["observations"][0]["points"]) >= 10
    x, y, _h = gl["endpoints"][0]
    assert 3e5 < x < 8e5 and 7.4e6 < y < 7.6e6  # UTM 22S around 22.4 S, 51.1 W


def test_script_rewrites_only_its_section(exp, tmp_path):
    doc = tmp_path / "experiments.md"
    doc.write_text(f"# Experiments\n\nintro\n\n<!-- BEGIN seed000 -->\nkeep me\n<!-- END seed000 -->\n\n{exp.BEGIN}\nold numbers\n{exp.END}\n")
    assert exp.main(["--replicates", "1", "--output", str(doc)]) == 0
    text = doc.read_text()
    assert "old numbers" not in text and "keep me" in text and text.startswith("# Experiments\n\nintro")
    assert text.count(exp.BEGIN) == 1 and text.count(exp.END) == 1
    section = text[text.index(exp.BEGIN) : text.index(exp.END)]
    for c in exp.CONFIGS:
        assert f"| {c.key}: " in section
    for _key, label, *_ in exp.VARIANTS:
        assert label in section
    assert "### Discussion" in section
