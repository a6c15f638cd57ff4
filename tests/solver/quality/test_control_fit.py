"""Control that does not belong (solver/quality/control_fit.py), found before solving, on the
simulated SPOT 1-4 scene (tests/solver/sensors/simulated_spot14.py: the job as the reader
composes it, control imaged by the scene's truth):

- another image's control (the same ground points measured where a neighbouring image, the
  scene shifted by 5,700 columns, sees them: what the 43 real control points of a SPOT 2 scene
  of 1999 look like against it) is refused by name, with the offset and the stated uncertainty;
  ``options.control_check: warn`` adjusts it anyway and names it in the report;
- one blunder is not refused (data snooping's job) but named in the warnings;
- control of the image itself passes (no false alarm with the stated uncertainty of the job's
  own weights, at 0-2000 m of terrain).
"""

from __future__ import annotations

import copy
import json
import re

import numpy as np
import pytest
from spot14_jobs import foreign, product, truth_job

from solver.api import run
from solver.cli import main
from solver.errors import JobError

SHIFT_COLUMNS = 5700.0  # the measured columns of "another image's" control


@pytest.fixture(scope="module")
def scene_job(tmp_path_factory):
    scene, _, p = product(tmp_path_factory.mktemp("spot14"))
    return scene, truth_job(scene, p, 17, 10, 4, perturb=False)


def test_another_images_control_is_refused_by_name(scene_job) -> None:
    scene, job = scene_job
    with pytest.raises(JobError) as exc:
        run(foreign(scene, job))
    problem = exc.value.problems[0]
    assert exc.value.code == "control_does_not_belong" and problem.location == ("images", 0)
    text = problem.message
    assert "these 17 control points" in text and "P0, P1, P2" in text and "another image's points?" in text, text
    assert re.search(r"5,7\d\d columns to the right of", text) and "stated uncertainty" in text, text
    named = {d["point"] for d in problem.detail["points"]}
    assert named == {f"P{k}" for k in range(17)}  # every control point, no check point
    offsets = np.array([d["offset_column_px"] for d in problem.detail["points"]])
    # the shift, to what the job form's chips extrapolate beyond the image's edge (measured 5,701-5,726)
    assert np.all(np.abs(offsets - SHIFT_COLUMNS) < 50.0), offsets


def test_warn_adjusts_anyway_and_names_them_in_the_report(scene_job) -> None:
    scene, job = scene_job
    bad = foreign(scene, job)
    bad["options"]["control_check"] = "warn"
    rep = run(bad)
    said = [w for w in rep["warnings"] if "these 17 control points" in w]
    assert said and "adjusted anyway" in said[0], rep["warnings"][:3]


def test_pba_run_exits_2_naming_them(scene_job, tmp_path, capsys) -> None:
    scene, job = scene_job
    path = tmp_path / "job.json"
    path.write_text(json.dumps(foreign(scene, job)))
    assert main(["run", str(path), "-o", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err
    assert "control_does_not_belong" in err and "P0" in err and "another image's points?" in err, err


def test_one_blunder_is_left_to_data_snooping(scene_job) -> None:
    _, job = scene_job
    bad = copy.deepcopy(job)
    o = next(o for o in bad["observations"] if o["point"] == "P3")
    o["line"] += 400.0
    rep = run(bad)
    said = [w for w in rep["warnings"] if "control point P3 is" in w]
    assert said and "left to data snooping" in said[0] and "blunders" in said[0], rep["warnings"][:3]


def test_the_images_own_control_passes(scene_job) -> None:
    _, job = scene_job
    rep = run(job)
    assert not any("control point" in w and "projected" in w for w in rep["warnings"]), rep["warnings"]
