"""SPOT 5 DIMAP v1: the exact model from the metadata alone against the product's own tie points
(independent evidence: the public HRS segment of tests/data/vendor/README.md; DIMAP v1 has no
RPC), the corrections' sizes, the job fragment, and refusals."""

from __future__ import annotations

import re
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from monte_carlo import direct_georeferencing, stereo_points
from tolerances import SAME_NUMBER_REL

from solver.cli import main
from solver.schema.job import Camera, Image
from solver.sensors.dimap_spot5 import Spot5Product, read_spot5, tie_point_check
from solver.sensors.job_fragment import fragment

FILE_TIME_S = 1e-6  # times read from the file's text (microseconds written)
LOOK_ANGLE_ABS = 0.01  # the first detector's look angle, tan(20 deg) as the product's nominal field states it

FILE = Path(__file__).parents[2] / "data" / "vendor" / "stereopipeline" / "spot_example1.xml"
TIE_POINT_M = 0.2  # the tie points' 6 decimals of a degree are 0.11 m of latitude; measured 0.03 and 0.04 m


@pytest.fixture(scope="module")
def product():
    return read_spot5(FILE)


def test_reads_the_segment(product) -> None:
    m = product.model
    assert (m.lines, m.columns) == (96168, 300)
    assert product.line_period_s == pytest.approx(7.5199705115e-04, rel=SAME_NUMBER_REL)
    # scene centre line 48085 (1-based) at 12:31:39.349737: line 48084 (0-based) there
    t = m.line_time(np.array([48084.0]))[0]
    assert t == pytest.approx((39.349737 - 27.0) + 3 * 60, abs=FILE_TIME_S)  # seconds after the first ephemeris point 12:28:27


def test_exact_model_meets_the_products_tie_points(product) -> None:
    c = tie_point_check(product)
    # the corners at column 1 are within the segment's 300 look angles; those at column 12000 are not
    assert c["points"] == 2 and c["outside_columns"] == 2
    assert max(c["distances_m"]) < TIE_POINT_M, c


@pytest.mark.parametrize("name,low,high", [("aberration", 15, 35), ("light_time", 0.1, 1.0), ("refraction", 0.5, 2.0)])
def test_each_correction_moves_the_ground_point_by_its_expected_size(product, name, low, high) -> None:
    # the vendor's location model has none of them (the tie points agree without): switched on,
    # each moves the ground by its physical size (aberration ~25 microradians x 830 km)
    model = product.model.with_corrections(**{name: True})
    c = product.corners[product.corners[:, 1] == 0]
    d = np.linalg.norm(model.image_to_ecef(c[:, 0], c[:, 1], c[:, 4]) - product.model.image_to_ecef(c[:, 0], c[:, 1], c[:, 4]), axis=1)
    assert np.all((d > low) & (d < high)), d


def test_job_fragment(product) -> None:
    doc = fragment([product], ["S"])
    note = doc.pop("sensor_metadata")[0]
    Camera(**doc["cameras"][0])
    Image(**doc["images"][0])
    # the look-angle table as one straight chip: its curvature and the along-track angle's
    # variation over these 300 detectors stay below half a pixel
    assert note["difference_px"]["rms"] < 0.5, note
    # HRS1 looks forward by ~20 deg: an along-track chip offset of f tan(20 deg)
    cam = doc["cameras"][0]
    assert cam["chips"][0]["dx_mm"] / cam["focal_mm"] == pytest.approx(np.tan(np.radians(20.0)), abs=LOOK_ANGLE_ABS)


def test_import_sensor_command_on_spot5(tmp_path, capsys) -> None:
    out = tmp_path / "s.json"
    assert main(["import-sensor", str(FILE), "--check-rpc", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "SPOT 5 (HRS)" in err and "2 tie points" in err, err


def _variant(pattern: str, repl: str, count: int = 1) -> str:
    return re.sub(pattern, repl, FILE.read_text(), count=count, flags=re.S)


@pytest.mark.parametrize("name,text,expected", [
    ("dimap_v3", lambda: _variant(r"<METADATA_FORMAT version='1.1'>", "<METADATA_FORMAT version='3.0'>"),
     "DIMAP version 3.0: 1.x (SPOT 1-5) or 2.x (SPOT 6/7, Pleiades) expected"),
    ("spot6_in_v1", lambda: _variant(r"<MISSION_INDEX>5</MISSION_INDEX>", "<MISSION_INDEX>6</MISSION_INDEX>"),
     "SPOT 6: a DIMAP v1 product of SPOT 1 to 5 expected"),
    ("few_look_angles", lambda: _variant(r"<Look_Angles>\s*<DETECTOR_ID>300</DETECTOR_ID>.*?</Look_Angles>", ""),
     "look angles (rad) of detectors 1 to 300 expected in increasing order (every column, or the first and last), 299 found"),
    ("out_of_range", lambda: _variant(r"(<Corrected_Attitude>\s*<Angles>.*?)<OUT_OF_RANGE>N", r"\1<OUT_OF_RANGE>Y"), "OUT_OF_RANGE"),
    ("bad_psi", lambda: _variant(r"<PSI_X>[^<]*</PSI_X>", "<PSI_X>0.3.4</PSI_X>"), "PSI_X: not a number"),
    ("no_ephemeris", lambda: _variant(r"<Ephemeris>.*</Ephemeris>", ""), "Data_Strip/Ephemeris: missing"),
])
def test_bad_spot5_files_exit_2_naming_the_element(tmp_path, capsys, name, text, expected) -> None:
    path = tmp_path / f"{name}.dim"
    path.write_text(text())
    assert main(["import-sensor", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and expected in err, err


@pytest.mark.slow
def test_the_fragment_adjusts_to_the_exact_model_through_the_solver(product) -> None:
    """End to end, as for WorldView-2: 25 ground points imaged by the exact model over the 72-s
    segment, 4 of them control; the solver's PASS-J2 (the fragment's default for SPOT 5) must fit
    them to a fraction of a pixel (OA-J2, which propagates the first line's state alone, ends
    8 px off along track on this segment)."""
    from solver.api import run

    doc = fragment([product], ["S"])
    doc.pop("sensor_metadata")
    assert doc["images"][0]["model"]["name"] == "PASS-J2"
    m = product.model
    rng = np.random.default_rng(2)
    n = 25
    lines, cols = rng.uniform(0, m.lines - 1, n), rng.uniform(0, m.columns - 1, n)
    ground = m.image_to_ground(lines, cols, rng.uniform(-200, 800, n))
    points = [{"id": f"P{k}", "role": "gcp" if k < 4 else "check", "coordinates": [float(v) for v in ground[k]],
               **({"sigma_m": [0.5, 0.5, 0.5]} if k < 4 else {})} for k in range(n)]
    obs = [{"image": "S", "point": f"P{k}", "line": float(lines[k]), "column": float(cols[k]), "sigma_px": 0.5} for k in range(n)]
    report = run({"schema_version": "1.0", "name": "SPOT 5 from its metadata", "crs": "EPSG:4326", **doc,
                  "points": points, "observations": obs})
    rmse = report["images"][0]["residual_rmse"]
    assert rmse["line_px"] < 0.5 and rmse["column_px"] < 0.5, rmse  # measured 0.15 / 0.04 px
    assert report["checkpoints"]["rmse_m"]["planimetric"] < 5.0  # m, mono (GSD 10 m); measured 2.2 m


def _shifted_times(text: str, dt: float) -> str:
    def f(m: re.Match) -> str:
        t = datetime.fromisoformat(m.group(2)) + timedelta(seconds=dt)
        return f"<{m.group(1)}>{t.strftime('%Y-%m-%dT%H:%M:%S.%f')}</{m.group(1)}>"

    return re.sub(r"<(TIME|SCENE_CENTER_TIME)>([^<]*)</\1>", f, text)


def backward_mate(product) -> Spot5Product:
    """HRS2 to the public segment's HRS1: the same file with every along-track look angle
    negated (looking back by 20 degrees) and the lines and corrected attitude later by the time
    the orbit takes to bring the backward view onto the forward one's ground (2 h tan 20 deg over
    the ground speed, about 92 s; the file's DORIS states reach 2 min beyond)."""
    m = product.model
    t = m.line_time(np.array([m.lines / 2.0]))
    p, v = m.position(t)[0], m.velocity(t)[0]
    r_earth = 6371e3
    psi = float(np.mean(np.arctan(product.look.tangents(np.arange(m.columns, dtype=float))[0])))
    dt = 2 * (np.linalg.norm(p) - r_earth) * np.tan(abs(psi)) / (np.linalg.norm(v) * r_earth / np.linalg.norm(p))
    text = re.sub(r"<PSI_X>([^<]*)</PSI_X>", lambda k: f"<PSI_X>{-float(k.group(1))!r}</PSI_X>", FILE.read_text())
    text = re.sub(r"<Corrected_Attitudes>.*</Corrected_Attitudes>", lambda k: _shifted_times(k.group(0), dt), text, flags=re.S)
    text = re.sub(r"<SCENE_CENTER_TIME>[^<]*</SCENE_CENTER_TIME>", lambda k: _shifted_times(k.group(0), dt), text)
    return read_spot5(FILE, "hrs2.dim", text.encode())


MC_RUNS = 100
# empirical / predicted 3-D check-point RMSE over the runs: 1 +- 0.025 expected from sampling
# alone at 100 runs (one standard deviation, from the runs' scatter); measured 1.04
# (6.5 m against 6.2 m predicted)
MC_RATIO = (0.8, 1.25)


@pytest.mark.slow
def test_direct_georeferencing_predicted_precision_by_monte_carlo(product) -> None:
    """SPOT 5 HRS along-track stereo without control (the public HRS1 segment and its HRS2 mate,
    :func:`backward_mate`, on one PASS-J2 pass): 12 tie and 12 check points imaged by the exact
    models, the metadata perturbed in each run as the job's weights say it errs (every DORIS
    state of the pass and every attitude sample independently, tests/solver/sensors/monte_carlo.py).
    The empirical 3-D check-point RMSE over the runs must match the RMSE the reports predict."""
    b = backward_mate(product)
    base = fragment([product, b], ["F", "B"])
    base.pop("sensor_metadata")
    assert [im["model"]["name"] for im in base["images"]] == ["PASS-J2", "PASS-J2"]
    m = product.model
    points, obs = stereo_points({"F": m, "B": b.model})
    assert len(points) == 24
    mc = direct_georeferencing(base, points, obs, MC_RUNS)
    assert MC_RATIO[0] <= mc["ratio"] <= MC_RATIO[1], mc
