"""``pba job --image FILE`` without ``ID=``: a measurement CSV whose ``image`` column names each
row's image (the tie points ``pba match -o`` writes) joins the job as the same file split per
image would; rows naming an image that is not given, and a non-CSV file, are located problems
(exit 2)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from solver.cli import main

ROOT = Path(__file__).parents[3]
SOURCES = ROOT / "examples" / "prism-triplet-sources"
IMAGES = ("prism-backward", "prism-nadir", "prism-forward")


def _args(tmp_path: Path, ties: list[str]) -> list[str]:
    """The example triplet's command with its control in CSV and its ties as given."""
    args = ["job", "--points", str(SOURCES / "survey.csv"), "--camera-file", str(SOURCES / "cameras.json")]
    for name in IMAGES:
        args += ["--state", f"{name}={SOURCES / f'{name}.state.csv'}"]
    args += ["--image", f"prism-backward={SOURCES / 'prism-backward.csv'}"]
    return args + ties + ["-o", str(tmp_path / "job.json")]


def _observations(path: Path) -> set[tuple[str, str, float, float]]:
    return {(o["image"], o["point"], o["line"], o["column"]) for o in json.loads(path.read_text())["observations"]}


def test_a_file_naming_its_images_equals_the_files_per_image(tmp_path: Path) -> None:
    per_image = [f"--image={name}={SOURCES / f'{name}-ties.csv'}" for name in IMAGES[1:]]
    assert main(_args(tmp_path, per_image)) == 0
    split = _observations(tmp_path / "job.json")
    rows = ["image,point,line,column,sigma_px"]
    for name in IMAGES[1:]:
        lines = (SOURCES / f"{name}-ties.csv").read_text().splitlines()
        rows += [f"{name},{line}" for line in lines[1:] if line and not line.startswith("#")]
    named = tmp_path / "ties.csv"
    named.write_text("\n".join(rows) + "\n")
    assert main(_args(tmp_path, ["--image", str(named)])) == 0
    assert _observations(tmp_path / "job.json") == split


@pytest.mark.parametrize("content, name, words", [
    ("image,point,line,column\nprism-nadir,T1,1,2\nsomewhere,T1,3,4\n", "ties.csv", "'somewhere' not among the images given"),
    ("point,line,column\nT1,1,2\n", "ties.csv", "image"),
    ("#CRS: EPSG:4326\nmapX,mapY,sourceX,sourceY,enable\n", "ties.points", "must be a CSV whose image column"),
])
def test_bad_named_files_are_located(tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str, name: str, words: str) -> None:
    path = tmp_path / name
    path.write_text(content)
    assert main(_args(tmp_path, [f"--image=prism-nadir={SOURCES / 'prism-nadir-ties.csv'}", "--image", str(path)])) == 2
    err = capsys.readouterr().err
    assert str(path) in err and words in err, err
