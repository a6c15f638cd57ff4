"""examples/: every example job is valid and adjusts to a sigma0 near 1, and the commands in
examples/README.md regenerate each file exactly (the documents are what the README says)."""

from __future__ import annotations

import json
import math
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from solver.api import run, validate
from solver.job import load_job

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


def test_readme_commands_regenerate_every_example(tmp_path: Path) -> None:
    commands = _readme_commands()
    made = set()
    for cmd in commands:
        out = Path(cmd[cmd.index("-o") + 1])
        cmd[cmd.index("-o") + 1] = str(tmp_path / out.name)
        subprocess.run([sys.executable, "-m", "solver.cli", *cmd[1:]], check=True, capture_output=True)
        assert json.loads((tmp_path / out.name).read_text()) == json.loads((EXAMPLES / out.name).read_text()), out
        made.add(out.name)
    assert made == {p.name for p in JOBS}
