"""examples/: every example job is valid and adjusts to a sigma0 near 1, and the commands in
examples/README.md regenerate each file (the documents are what the README says): the same
structure, keys, strings, integers and ids exactly, every number within a tolerance far below
anything an adjustment could notice (1e-6 px, 1e-6 m; 1e-5 m for integrated orbit positions) but
above the differences between machines (other BLAS builds and CPUs stop the simulator's Newton
iterations on other last bits: ~2e-8 px was seen)."""

from __future__ import annotations

import json
import math
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from pyproj import CRS

from solver.api import run, validate
from solver.schema.job import load_job

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
JOBS = sorted(p for p in EXAMPLES.glob("*.json") if not p.name.endswith(".truth.json"))


def _readme_commands() -> list[list[str]]:
    text = (EXAMPLES / "README.md").read_text()
    block = re.search(r"```sh\n(.*?)```", text, re.S).group(1)
    return [shlex.split(cmd) for cmd in block.replace("\\\n", " ").splitlines() if cmd.startswith("pba simulate")]


@pytest.mark.parametrize("path", JOBS, ids=lambda p: p.stem)
def test_example_is_valid_and_adjusts(path: Path) -> None:
    job = json.loads(path.read_text())
    assert validate(load_job(job))["valid"]
    rep = run(job)
    assert 0.7 < rep["adjustment"]["sigma0_aposteriori"] < 1.3
    r = rep["checkpoints"]["rmse_m"]
    limit = 40.0 if "direct" in path.stem else 5.0  # no control: the attitude noise sets it
    height = r["u"] or 0.0  # a single image: check points on the terrain, no height error
    assert math.sqrt(r["e"] ** 2 + r["n"] ** 2 + height**2) < limit, r


# Tolerance of a regenerated number by the unit its key names (the last key of its path).
PX = 1e-6  # image coordinates, pixels
M = 1e-6  # lengths and positions, metres
# platform positions come from minutes of orbit integration: numpy 1.26 against 2.4 on one machine
# moved the ephemeris 3 min from the epoch by 9.9e-7 m, so 1e-5 m (1.4e-12 of the orbit radius;
# the adjustment weights these at 1 m and more)
M_ORBIT = 1e-5
DEG_GROUND = 1e-11  # longitude/latitude: 1e-11 deg is ~1e-6 m on the ground
DEG_VIEW = 1e-10  # attitude angles: 1e-10 deg moves a point ~1e-6 m from ~700 km
RAD_VIEW = 2e-12  # the same in radians (also rotation-matrix elements)
S = 3e-10  # times: a PRISM line is 3.7e-4 s, so 3e-10 s is under 1e-6 px
M_S = 1e-7  # velocities: 1e-7 m/s moves the orbit 1e-6 m over a 10 s image
MM = 1e-9  # focal-plane lengths: 1e-9 mm is 1.4e-7 PRISM pixels
OTHER_REL = 1e-12  # anything else (settings, IOP, terrain and Earth constants), relative


def _tolerance(key: str, geographic: bool) -> tuple[float, float]:
    """(absolute, relative) tolerance of a number under ``key``."""
    if key in ("line", "column") or key.endswith("_px"):
        return PX, 0.0
    if key.endswith(("lon_deg", "lat_deg")):
        return DEG_GROUND, 0.0
    if key.endswith("_m_s"):
        return M_S, 0.0
    if key in ("position_ecef_m", "state0_ecef"):
        return M_ORBIT, 0.0
    if key.endswith("_m"):
        return M, 0.0
    if key.endswith("_deg"):
        return DEG_VIEW, 0.0
    if key.endswith("_rad") or key == "camera_from_ecef":
        return RAD_VIEW, 0.0
    if key.endswith("_s"):
        return S, 0.0
    if key.endswith("_mm"):
        return MM, 0.0
    return 0.0, OTHER_REL


def assert_documents_close(got: object, want: object, where: str = "", key: str = "", geographic: bool = False) -> None:
    """``got`` equals ``want`` in structure and in every non-float value; floats within the
    tolerance of their key (:func:`_tolerance`)."""
    if isinstance(want, dict):
        assert isinstance(got, dict) and got.keys() == want.keys(), where
        if "crs" in want and isinstance(want["crs"], str):
            geographic = CRS.from_user_input(want["crs"]).is_geographic
        for k in want:
            assert_documents_close(got[k], want[k], f"{where}/{k}", k, geographic)
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), where
        for i, (g, w) in enumerate(zip(got, want)):
            sub = key
            if key == "coordinates":  # x, y, h in the document's CRS
                sub = ("lon_deg", "lat_deg", "height_m")[i] if geographic else "coordinate_m"
            assert_documents_close(g, w, f"{where}/{i}", sub, geographic)
    elif isinstance(want, float) and not isinstance(want, bool):
        absolute, relative = _tolerance(key, geographic)
        assert isinstance(got, (int, float)) and math.isclose(got, want, rel_tol=relative, abs_tol=absolute), (where, got, want)
    else:
        assert type(got) is type(want) and got == want, (where, got, want)


def test_document_comparison_has_teeth() -> None:
    doc = {"crs": "EPSG:4326", "observations": [{"image": "a", "line": 481.822449308516, "column": 3.0}]}
    near = {"crs": "EPSG:4326", "observations": [{"image": "a", "line": 481.82244928781427, "column": 3.0}]}
    assert_documents_close(near, doc)  # the difference seen between two machines (2e-8 px)
    for bad in (
        {"crs": "EPSG:4326", "observations": [{"image": "a", "line": 481.8224513, "column": 3.0}]},  # 2e-6 px
        {"crs": "EPSG:4326", "observations": [{"image": "b", "line": 481.822449308516, "column": 3.0}]},
        {"crs": "EPSG:4326", "observations": [{"image": "a", "line": 481.822449308516, "column": 3.0, "chip": "1"}]},
        {"crs": "EPSG:4326", "observations": []},
    ):
        with pytest.raises(AssertionError):
            assert_documents_close(bad, doc)
    assert_documents_close({"crs": "EPSG:4326", "coordinates": [-51.0 + 5e-12, -22.0]}, {"crs": "EPSG:4326", "coordinates": [-51.0, -22.0]})
    with pytest.raises(AssertionError):  # 1e-9 deg is 0.1 mm on the ground
        assert_documents_close({"crs": "EPSG:4326", "coordinates": [-51.0 + 1e-9, -22.0]}, {"crs": "EPSG:4326", "coordinates": [-51.0, -22.0]})


def test_readme_commands_regenerate_every_example(tmp_path: Path) -> None:
    commands = _readme_commands()
    made = set()
    for cmd in commands:
        out = Path(cmd[cmd.index("-o") + 1])
        cmd[cmd.index("-o") + 1] = str(tmp_path / out.name)
        subprocess.run([sys.executable, "-m", "solver.cli", *cmd[1:]], check=True, capture_output=True)
        for name in (out.name, out.name[: -len(".json")] + ".truth.json"):
            assert_documents_close(json.loads((tmp_path / name).read_text()), json.loads((EXAMPLES / name).read_text()), name)
        made.add(out.name)
    assert made == {p.name for p in JOBS}
