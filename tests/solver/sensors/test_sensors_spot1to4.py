"""SPOT 1-4 DIMAP v1: attitude given as the gyros' angular speeds (integrated from the first
absolute AOCS angle) and the look angles of the first and last detector only. No public SPOT
1-4 product may be committed (the ones we found carry a non-commercial licence;
docs/sensor-metadata.md gives the numbers measured on them), so the public SPOT 5 segment
(tests/data/vendor) is rewritten in SPOT 1-4's form around a known, analytic attitude:

- truth: the same segment in SPOT 5's form, its corrected yaw, pitch and roll replaced by the
  analytic angles sampled every 20 ms (the SPOT 5 path meets the product's own tie points,
  tests/solver/sensors/test_sensors_spot5.py);
- SPOT 1-4 form: no corrected attitude; ``Aocs_Attitude/Angles_List`` with the analytic angles
  at the first and last time, ``Angular_Speeds_List`` with their analytic derivatives at 8 Hz;
- both: the look angles of detectors 1 and 300 only.
"""

from __future__ import annotations

import re
from datetime import datetime, timedelta

import numpy as np
import pytest

from solver.cli import main
from solver.sensors.dimap_spot5 import read_spot5

FILE = __import__("pathlib").Path(__file__).parents[2] / "data" / "vendor" / "stereopipeline" / "spot_example1.xml"
T0 = datetime(2008, 3, 4, 12, 31, 3)  # before the segment's first line (12:31:03.19)
SPAN_S = 73.0
GROUND_M = 0.05  # integrated speeds vs the truth (trapezoids at 8 Hz of these angles: below 1e-8 rad, 1 cm at 830 km)


def _angles(t: np.ndarray) -> np.ndarray:
    """(n, 3) yaw, pitch, roll (rad) of the truth: slow oscillations and a drift, as gyros see."""
    w1, w2 = 2 * np.pi / 40.0, 2 * np.pi / 55.0
    return np.column_stack([4e-5 + 2e-6 * t, 3e-5 * np.cos(w2 * t), 1e-5 + 2e-5 * np.sin(w1 * t)])


def _rates(t: np.ndarray) -> np.ndarray:
    w1, w2 = 2 * np.pi / 40.0, 2 * np.pi / 55.0
    return np.column_stack([np.full(t.shape, 2e-6), -3e-5 * w2 * np.sin(w2 * t), 2e-5 * w1 * np.cos(w1 * t)])


def _time(t: float) -> str:
    return (T0 + timedelta(seconds=float(t))).strftime("%Y-%m-%dT%H:%M:%S.%f")


def _rows(tag: str, t: np.ndarray, v: np.ndarray) -> str:
    return "".join(f"<{tag}><TIME>{_time(x)}</TIME><YAW>{a[0]!r}</YAW><PITCH>{a[1]!r}</PITCH><ROLL>{a[2]!r}</ROLL>"
                   f"<OUT_OF_RANGE>N</OUT_OF_RANGE></{tag}>" for x, a in zip(t, v.tolist()))


def _two_detectors(text: str) -> str:
    cells = re.findall(r"<Look_Angles>.*?</Look_Angles>", text, flags=re.S)
    return re.sub(r"<Look_Angles_List>.*</Look_Angles_List>", lambda _m: f"<Look_Angles_List>{cells[0]}{cells[-1]}</Look_Angles_List>",
                  text, count=1, flags=re.S)


def truth_text() -> str:
    t = np.arange(0.0, SPAN_S, 0.02)
    text = re.sub(r"(<Corrected_Attitude>).*(</Corrected_Attitude>)", lambda m: m.group(1) + _rows("Angles", t, _angles(t)) + m.group(2),
                  FILE.read_text(), count=1, flags=re.S)
    return _two_detectors(text)


def spot2_text(with_absolute: bool = True) -> str:
    ts = np.arange(0.125, SPAN_S - 0.1, 0.125)
    ends = np.array([0.0, SPAN_S - 0.05])
    absolute = f"<Angles_List>{_rows('Angles', ends, _angles(ends))}</Angles_List>" if with_absolute else ""
    aocs = f"<Aocs_Attitude>{absolute}<Angular_Speeds_List>{_rows('Angular_Speeds', ts, _rates(ts))}</Angular_Speeds_List></Aocs_Attitude>"
    text = re.sub(r"<Aocs_Attitude>.*</Aocs_Attitude>", lambda _m: aocs, FILE.read_text(), count=1, flags=re.S)
    text = re.sub(r"<Corrected_Attitudes>.*</Corrected_Attitudes>", "", text, count=1, flags=re.S)
    text = text.replace("<MISSION_INDEX>5</MISSION_INDEX>", "<MISSION_INDEX>2</MISSION_INDEX>", 1)
    return _two_detectors(text)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("spot2")
    (d / "truth.dim").write_text(truth_text())
    (d / "spot2.dim").write_text(spot2_text())
    return read_spot5(d / "truth.dim"), read_spot5(d / "spot2.dim")


def test_integrated_speeds_meet_the_truth(models) -> None:
    truth, spot2 = models
    assert spot2.mission == "SPOT 2" and spot2.look.detectors.tolist() == [0.0, 299.0]
    m = truth.model
    L, C = np.meshgrid(np.linspace(0, m.lines - 1, 9), np.linspace(0, m.columns - 1, 5), indexing="ij")
    L, C = L.ravel(), C.ravel()
    for h in (0.0, 2000.0):
        d = np.linalg.norm(spot2.model.image_to_ecef(L, C, np.full(L.size, h)) - m.image_to_ecef(L, C, np.full(L.size, h)), axis=1)
        assert d.max() < GROUND_M, d.max()


def test_without_absolute_angles_the_integral_is_zero_at_the_scene_centre(tmp_path) -> None:
    path = tmp_path / "spot2.dim"
    path.write_text(spot2_text(with_absolute=False))
    p = read_spot5(path)
    centre = (datetime(2008, 3, 4, 12, 31, 39, 349737) - T0).total_seconds()
    # the model's attitude at the scene centre is the orbital frame turned by zero angles: the
    # truth's attitude there differs by the truth's angles at the centre
    truth = read_spot5(_write(tmp_path / "t.dim", truth_text()))
    line = 48084.0
    t_model = p.model.line_time(np.array([line]))[0]
    r_zero = p.model.rotation(np.array([t_model]))[0]
    r_truth = truth.model.rotation(np.array([t_model]))[0]
    angle = np.arccos(np.clip((np.trace(r_zero.T @ r_truth) - 1) / 2, -1, 1))
    assert angle == pytest.approx(np.linalg.norm(_angles(np.array([centre]))[0]), rel=0.05)


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize("name,edit,expected", [
    ("fast", lambda t: re.sub(r"(<Angular_Speeds><TIME>[^<]*</TIME><YAW>)[^<]*", r"\g<1>0.5", t, count=1), "angular speeds above 0.1 rad/s"),
    ("flagged", lambda t: re.sub(r"(<Angular_Speeds>.*?)<OUT_OF_RANGE>N", r"\1<OUT_OF_RANGE>Y", t, count=1, flags=re.S), "OUT_OF_RANGE"),
    ("no_speeds", lambda t: re.sub(r"<Angular_Speeds_List>.*</Angular_Speeds_List>", "", t, count=1, flags=re.S),
     "Aocs_Attitude/Angular_Speeds_List: missing"),
    ("unordered", lambda t: re.sub(r"<TIME>2008-03-04T12:31:03.250000</TIME>", "<TIME>2008-03-04T12:31:03.125000</TIME>", t, count=1),
     "angular speed times must increase"),
])
def test_bad_spot1to4_files_exit_2_naming_the_element(tmp_path, capsys, name, edit, expected) -> None:
    text = spot2_text()
    bad = edit(text)
    assert bad != text
    path = _write(tmp_path / f"{name}.dim", bad)
    assert main(["import-sensor", str(path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and str(path) in err and expected in err, err


JOB_FORM_PX = 0.5  # straight chips for the two-detector look angles (measured 0.03-0.09 px RMS on real scenes)


def test_job_fragment(models) -> None:
    from solver.schema.job import Camera, Image
    from solver.sensors.job_fragment import fragment

    _, spot2 = models
    doc = fragment([spot2], ["S2"])
    note = doc.pop("sensor_metadata")[0]
    Camera(**doc["cameras"][0])
    Image(**doc["images"][0])
    assert note["satellite"] == "SPOT 2" and doc["images"][0]["model"]["name"] == "PASS-J2"
    assert note["difference_px"]["rms"] < JOB_FORM_PX, note
