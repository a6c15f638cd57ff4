"""``pba simulate small-triplet``: three views of a small camera (the tutorials' and quick
matching trials' scene): N x N pixels, views pitched -20, 0, +20 degrees, ~20 m ground pixels
over 200-1200 m of terrain, every point inside every image; the rasters written without a
warning (raw geometry has no georeferencing by design); a size too small exits 2."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.errors import NotGeoreferencedWarning

from solver.cli import main

SIZE = 96


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")  # reading them back here
def test_the_scene_is_small_and_sees_every_point(tmp_path: Path) -> None:
    out = tmp_path / "sim.json"
    with warnings.catch_warnings():
        warnings.simplefilter("error", NotGeoreferencedWarning)
        assert main(["simulate", "small-triplet", "--size", str(SIZE), "--gcps", "4", "--checks", "3", "--tie-points", "5",
                     "--raster", "-o", str(out)]) == 0
    job = json.loads(out.read_text())
    assert [im["id"] for im in job["images"]] == ["back", "nadir", "fwd"]
    assert {(c["lines"], c["columns"]) for c in job["cameras"]} == {(SIZE, SIZE)}
    roles = [p["role"] for p in job["points"]]
    assert (roles.count("gcp"), roles.count("check"), roles.count("tie")) == (4, 3, 5)
    assert len(job["observations"]) == 3 * 12
    lc = np.array([[o["line"], o["column"]] for o in job["observations"]])
    assert np.all((lc > -1.0) & (lc < SIZE))  # inside, up to the 0.5 px measurement noise
    heights = [p["coordinates"][2] for p in job["points"] if p.get("coordinates")]
    assert 150.0 < min(heights) and max(heights) < 1250.0  # terrain 200-1200 m, survey noise 0.2 m
    truth = json.loads(out.with_name("sim.truth.json").read_text())
    assert {im["id"]: im["mounting_pitch_deg"] for im in truth["images"]} == {"back": -20.0, "nadir": 0.0, "fwd": 20.0}
    for view in ("back", "nadir", "fwd"):
        with rasterio.open(tmp_path / f"sim.{view}.tif") as src:
            assert (src.height, src.width) == (SIZE, SIZE)


def test_a_size_below_the_minimum_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "small-triplet", "--size", "10", "-o", str(tmp_path / "x.json")]) == 2
    assert "small-triplet --size 10: at least 64 pixels" in capsys.readouterr().err
