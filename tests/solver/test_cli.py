"""The pba command line: run with a report and summary, models, validate, compare, preanalysis."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from utils.scenes import single_image_job

PBA = [sys.executable, "-m", "solver.cli"]


def test_run_writes_report_and_prints_summary(tmp_path: Path):
    job, _ = single_image_job("K2", seed=1)
    jp = tmp_path / "job.json"
    jp.write_text(json.dumps(job))
    out = tmp_path / "report.json"
    r = subprocess.run(PBA + ["run", str(jp), "-o", str(out)], capture_output=True, text=True, check=True)
    rep = json.loads(out.read_text())
    assert rep["adjustment"]["converged"]
    assert "sigma0 a posteriori" in r.stdout and "check points (9, mono)" in r.stdout
    assert f"{rep['adjustment']['sigma0_aposteriori']:.4g}" in r.stdout


def test_models_lists_every_model():
    r = subprocess.run(PBA + ["models", "--json"], capture_output=True, text=True, check=True)
    names = [m["name"] for m in json.loads(r.stdout)]
    assert {"K1", "K2", "J2-1", "J2-2", "ON1", "ON2", "P1", "P2", "GENERAL", "MT8"} <= set(names)
    text = subprocess.run(PBA + ["models"], capture_output=True, text=True, check=True).stdout
    assert "ux [m/s]" in text and "frame LGS" in text


def test_validate_and_run_report_bad_input_with_exit_code_2(tmp_path: Path):
    job, _ = single_image_job("P2", seed=1)
    job["observations"][0]["point"] = "ghost"
    jp = tmp_path / "bad.json"
    jp.write_text(json.dumps(job))
    r = subprocess.run(PBA + ["validate", str(jp)], capture_output=True, text=True)
    assert r.returncode == 2 and "unknown_point" in r.stdout and "observations/0/point" in r.stdout
    r = subprocess.run(PBA + ["run", str(jp)], capture_output=True, text=True)
    assert r.returncode == 2 and "ghost" in r.stderr


def test_compare_prints_side_by_side_table(tmp_path: Path):
    job, _ = single_image_job("K2", seed=1)
    jp = tmp_path / "job.json"
    jp.write_text(json.dumps(job))
    r = subprocess.run(PBA + ["compare", str(jp), "--models", "K1,P2,ON1", "-o", str(tmp_path / "c.json")], capture_output=True, text=True, check=True)
    lines = [ln for ln in r.stdout.splitlines() if ln.split() and ln.split()[0] in ("K1", "P2", "ON1")]
    assert len(lines) == 3
    rep = json.loads((tmp_path / "c.json").read_text())
    assert [row["model"] for row in rep["table"]] == ["K1", "P2", "ON1"]


def test_preanalysis_writes_report_and_prints_predicted_precision(tmp_path: Path):
    """pba preanalysis: a single K2 image planned with its 14 control and 9 check points (the
    simulated job without its observations); a planned point without coordinates is exit 2."""
    job, _ = single_image_job("K2", seed=1)
    job["observations"] = []
    jp = tmp_path / "plan.json"
    jp.write_text(json.dumps(job))
    out = tmp_path / "plan.report.json"
    r = subprocess.run(PBA + ["preanalysis", str(jp), "-o", str(out)], capture_output=True, text=True, check=True)
    rep = json.loads(out.read_text())
    assert rep["kind"] == "preanalysis"
    assert rep["adjustment"]["n_planned_image_points"] == 23
    assert "check points (9): predicted RMSE" in r.stdout
    pr = rep["checkpoints"]["predicted_rmse_m"]
    assert f"{pr['e']:.3f}" in r.stdout
    job["points"].append({"id": "planned-tie", "role": "tie"})
    jp.write_text(json.dumps(job))
    r = subprocess.run(PBA + ["preanalysis", str(jp)], capture_output=True, text=True)
    assert r.returncode == 2 and "planned_point_without_coordinates" in r.stderr


def test_export_camera_without_an_estimate_exits_2_naming_the_report(tmp_path: Path):
    job, _ = single_image_job("K2", seed=1)
    jp, rp = tmp_path / "job.json", tmp_path / "report.json"
    jp.write_text(json.dumps(job))
    rp.write_text(json.dumps({"cameras": []}))  # not a self-calibration report
    cam = job["cameras"][0]["id"]
    r = subprocess.run(PBA + ["export-camera", str(jp), str(rp), "--camera", cam], capture_output=True, text=True)
    assert r.returncode == 2 and str(rp) in r.stderr and "self-calibration" in r.stderr, r.stderr
    rp.write_text(json.dumps({"cameras": [{"id": cam, "iop": {"df": 0.002}}]}))
    r = subprocess.run(PBA + ["export-camera", str(jp), str(rp), "--camera", cam], capture_output=True, text=True, check=True)
    assert json.loads(r.stdout)["iop"]["df"] == 0.002 and json.loads(r.stdout)["id"] == cam


def test_a_written_report_is_strict_json_as_the_servers(tmp_path: Path, monkeypatch):
    """pba run -o and the server write a report through the one serialiser: non-finite
    numbers as null (before, the CLI wrote NaN, which strict JSON parsers refuse)."""
    import math

    import numpy as np

    import solver.api
    import solver.commands
    from solver.cli import main
    from solver.report.json_text import report_json

    report = {"kind": "comparison", "sigma0": float("nan"), "condition": np.float64(np.inf), "v": np.array([1.5, -np.inf])}
    monkeypatch.setattr(solver.api, "run", lambda job, progress=None, cancel=None: report)
    monkeypatch.setattr("solver.compare.comparison_table_text", lambda rep: "table")
    job, _ = single_image_job("K2", seed=1)
    jp, out = tmp_path / "job.json", tmp_path / "report.json"
    jp.write_text(json.dumps(job))
    assert main(["run", str(jp), "-o", str(out), "-q"]) == 0

    def no_constants(name: str):
        raise AssertionError(f"{name} in a written report")

    written = json.loads(out.read_text(), parse_constant=no_constants)
    assert written == {"kind": "comparison", "sigma0": None, "condition": None, "v": [1.5, None]}
    assert json.loads(report_json(report), parse_constant=no_constants) == written  # the server's text
    assert math.isnan(report["sigma0"])  # the caller's report is not modified
    assert solver.commands.report_json is report_json
