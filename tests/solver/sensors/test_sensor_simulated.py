"""Measurements simulated on vendor metadata (solver/sensors/simulated.py, ``pba
simulate-measurements``) and what they exposed: tie points of an agile satellite's job start
where their rays meet.

Independent evidence: the exact models' own intersection of the simulated measurements
(solver.sensors.agreement.intersect, Gauss-Newton on the exact ground-to-image) must return the
simulated truth; the simulated per-image shifts must come back as the vendor RPC's misfit (the
RPB of the real files, fitted by Maxar, not by us).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from solver.cli import main
from solver.geometry.geodesy import LocalFrame, ecef_to_geodetic, geodetic_to_ecef
from solver.schema.job import load_job
from solver.sensors.agreement import intersect
from solver.sensors.job_fragment import fragment
from solver.sensors.maxar import read_maxar
from solver.sensors.simulated import height_range, simulate_measurements

DATA = Path(__file__).parents[2] / "data" / "vendor" / "stereopipeline"
IDS = ["L", "R"]

TRUTH_M = 0.01  # noise-free measurements intersected by the exact models land on the truth (Gauss-Newton converged to mm)
SHIFT_PX = 0.6  # the vendor RPC's misfit equals the simulated shift within the RPC's own agreement with the exact model (0.15-0.55 px)
TIE_START_M = 30.0  # initial tie points within the metadata's error (3 m shifts, 0.2 px job form); with the nominal attitude: 6000 km


@pytest.fixture(scope="module")
def pair():
    return [read_maxar(DATA / "wv_test1.xml"), read_maxar(DATA / "wv_test2.xml")]


def _lgs(frame: LocalFrame, lon_lat_h: np.ndarray) -> np.ndarray:
    return frame.to_lgs(geodetic_to_ecef(np.atleast_2d(lon_lat_h)))


def test_noise_free_measurements_intersect_on_the_truth(pair) -> None:
    sim = simulate_measurements([p.model for p in pair], IDS, height_range(pair[0].rpc), 2, 2, 4,
                                shift_sigma_m=0.0, noise_px=0.0, survey_sigma_m=0.0, seed=4)
    names = list(sim.truth["points"])
    obs = {(o["image"], o["point"]): (o["line"], o["column"]) for o in sim.observations}
    image_points = [np.array([obs[(i, n)] for n in names]) for i in IDS]
    truth = np.array([sim.truth["points"][n] for n in names])
    x = intersect([p.model for p in pair], image_points, truth + np.array([1e-4, -1e-4, 100.0]))
    frame = LocalFrame.at_centroid(geodetic_to_ecef(truth))
    assert np.max(np.linalg.norm(_lgs(frame, x) - _lgs(frame, truth), axis=1)) < TRUTH_M
    surveyed = {p["id"]: p["coordinates"] for p in sim.points if p["role"] != "tie"}
    assert all(np.allclose(surveyed[n], sim.truth["points"][n], rtol=0, atol=1e-9) for n in surveyed)  # no survey noise asked
    assert [p["role"] for p in sim.points].count("tie") == 4


def test_each_images_shift_is_the_vendor_rpcs_misfit(pair) -> None:
    """Image i sees the truth G where its metadata sees G - shift_i: the vendor's RPC (the same
    metadata) projects G - shift_i onto the measurement, and misses G by about shift / GSD."""
    sim = simulate_measurements([p.model for p in pair], IDS, height_range(pair[0].rpc), 3, 3, 0,
                                shift_sigma_m=3.0, noise_px=0.0, survey_sigma_m=0.0, seed=5)
    truth = np.array(list(sim.truth["points"].values()))
    frame = LocalFrame.at_centroid(geodetic_to_ecef(truth))
    for image_id, product in zip(IDS, pair):
        e, n = sim.truth["image_shifts_en_m"][image_id]
        moved = frame.to_ecef(_lgs(frame, truth) - np.array([e, n, 0.0]))
        g = ecef_to_geodetic(moved)
        line, col = product.rpc.project(g[:, 0], g[:, 1], g[:, 2])
        measured = np.array([[o["line"], o["column"]] for o in sim.observations if o["image"] == image_id])
        assert np.max(np.hypot(line - measured[:, 0], col - measured[:, 1])) < SHIFT_PX


def test_tie_points_of_an_agile_satellite_start_where_their_rays_meet(pair) -> None:
    """WorldView-2 looks 15-30 degrees off its orbital frame: the initial attitude comes from the
    weighted attitude samples, so the tie points' first intersection lands near the truth."""
    from solver.procedures.single import prepare

    sim = simulate_measurements([p.model for p in pair], IDS, height_range(pair[0].rpc), 4, 0, 8, seed=6)
    doc = fragment(pair, IDS)
    doc.pop("sensor_metadata")
    job = load_job({"schema_version": "1.0", "name": "agile", "crs": "EPSG:4326", **doc,
                    "points": sim.points, "observations": sim.observations})
    problem = prepare(job)
    for point in problem.points:
        if point.role != "tie":
            continue
        truth = problem.frame.to_lgs(geodetic_to_ecef(np.array(sim.truth["points"][point.id])))
        assert np.linalg.norm(point.xyz - truth) < TIE_START_M, (point.id, point.xyz, truth)


def test_the_command_writes_what_pba_job_reads(tmp_path, capsys) -> None:
    out = tmp_path / "meas"
    assert main(["simulate-measurements", str(DATA / "wv_test1.xml"), str(DATA / "wv_test2.xml"),
                 "--image-id", "L", "--image-id", "R", "--gcps", "3", "--checks", "5", "--ties", "6", "-o", str(out)]) == 0
    assert "direct georeferencing off by" in capsys.readouterr().err
    control = list(csv.DictReader(line for line in (out / "control.csv").open() if not line.startswith("#")))
    assert [r["id"] for r in control] == ["G01", "G02", "G03"] and "role" not in control[0]
    assert len(list(csv.DictReader((out / "L.csv").open()))) == 3 + 5 + 6
    assert set(json.loads((out / "truth.json").read_text())["image_shifts_en_m"]) == {"L", "R"}
    job = tmp_path / "job.json"
    assert main(["job", "--sensor", f"L={DATA / 'wv_test1.xml'}", "--sensor", f"R={DATA / 'wv_test2.xml'}",
                 "--image", f"L={out / 'L.csv'}", "--image", f"R={out / 'R.csv'}",
                 "--gcps", str(out / "control.csv"), "--checks", str(out / "checks.csv"), "-o", str(job)]) == 0
    roles = [p["role"] for p in json.loads(job.read_text())["points"]]
    assert (roles.count("gcp"), roles.count("check"), roles.count("tie")) == (3, 5, 6)


@pytest.mark.parametrize("argv, words", [
    (["--image-id", "L"], "1 --image-id for 2 files"),
    (["--image-id", "L", "--image-id", "L"], "image ids must differ"),
    (["--gcps", "0", "--checks", "0", "--ties", "0"], "not all 0"),
])
def test_bad_requests_exit_2_with_a_message(tmp_path, capsys, argv, words) -> None:
    rc = main(["simulate-measurements", str(DATA / "wv_test1.xml"), str(DATA / "wv_test2.xml"), *argv, "-o", str(tmp_path / "m")])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("pba simulate-measurements: ") and words in err, err


def test_images_without_overlap_exit_2(tmp_path, capsys) -> None:
    assert main(["simulate-measurements", str(DATA / "wv_test1.xml"), str(DATA / "wv_mvp_1.xml"), "-o", str(tmp_path / "m")]) == 2
    assert "fall inside every image" in capsys.readouterr().err


def test_a_bad_metadata_file_is_named(tmp_path, capsys) -> None:
    bad = tmp_path / "bad.xml"
    bad.write_text("<isd><IMD>")
    assert main(["simulate-measurements", str(bad), "-o", str(tmp_path / "m")]) == 2
    assert str(bad) in capsys.readouterr().err
