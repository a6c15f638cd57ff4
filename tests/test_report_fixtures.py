"""The report of every example job equals the one stored in tests/fixtures/reports/, written by
the code before the restructuring of issue 14 (solver/ in layered packages): the report is a
public contract (docs/report-contract.md), so moving code must not change it.

Structure, keys, strings, booleans, ``None`` and integers (counts, iterations) must be equal
exactly. Floats come out of a Ceres solve and a covariance inversion, so other BLAS builds and
CPUs move their last bits: each is compared within ``rel 1e-9`` of its value (4 mm of an ECEF
coordinate, 1e-9 of a covariance element) or an absolute floor of 1e-6 in its unit (1 micrometre,
1e-6 px, 1e-6 of a sigma), and longitudes and latitudes within 1e-10 deg (1e-5 m on the ground):
far below anything a reader of the report could act on, and above what a refactoring that changes
no arithmetic can produce (it reproduces the bits). Wall
clock times (``*_time_s``) are not compared.

Regenerate the fixtures only for a deliberate change of the report:
``python -c 'import tests.test_report_fixtures as t; t.regenerate()'``.
"""

from __future__ import annotations

import gzip
import json
import math
from pathlib import Path
from typing import Any

import pytest

from solver.api import run

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
FIXTURES = Path(__file__).resolve().parent / "fixtures" / "reports"
JOBS = sorted(p for p in EXAMPLES.glob("*.json") if not p.name.endswith(".truth.json"))

REL = 1e-9
ABS = 1e-6
ABS_DEG_GROUND = 1e-10


def _fixture(job: Path) -> Path:
    return FIXTURES / (job.stem + ".report.json.gz")


def regenerate() -> None:
    """Write the fixture of every example job from the current code."""
    for job in JOBS:
        with gzip.open(_fixture(job), "wt") as f:
            json.dump(run(json.loads(job.read_text())), f, indent=0)


def assert_reports_close(got: Any, want: Any, where: str = "", key: str = "") -> None:
    """``got`` equals ``want`` in structure and every non-float; floats within the tolerances above."""
    if isinstance(want, dict):
        assert isinstance(got, dict) and list(got) == list(want), (where, sorted(set(got) ^ set(want)) if isinstance(got, dict) else got)
        for k in want:
            if k.endswith("_time_s"):
                continue
            assert_reports_close(got[k], want[k], f"{where}/{k}", k)
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), where
        for i, (g, w) in enumerate(zip(got, want)):
            assert_reports_close(g, w, f"{where}/{i}", key)
    elif isinstance(want, float):
        ground = key.endswith(("lon_deg", "lat_deg"))
        rel, floor = (0.0, ABS_DEG_GROUND) if ground else (REL, ABS)
        assert isinstance(got, (int, float)) and not isinstance(got, bool), (where, got)
        assert math.isclose(got, want, rel_tol=rel, abs_tol=floor), (where, got, want)
    else:
        assert type(got) is type(want) and got == want, (where, got, want)


def test_comparison_has_teeth() -> None:
    want = {"a": {"lon_deg": -51.0, "sigma": 0.5, "n": 3, "s": "x"}, "solve_time_s": 1.0}
    assert_reports_close({"a": {"lon_deg": -51.0 + 1e-12, "sigma": 0.5 + 1e-9, "n": 3, "s": "x"}, "solve_time_s": 9.0}, want)
    for bad in (
        {"a": {"lon_deg": -51.0 + 1e-9, "sigma": 0.5, "n": 3, "s": "x"}, "solve_time_s": 1.0},
        {"a": {"lon_deg": -51.0, "sigma": 0.50001, "n": 3, "s": "x"}, "solve_time_s": 1.0},
        {"a": {"lon_deg": -51.0, "sigma": 0.5, "n": 4, "s": "x"}, "solve_time_s": 1.0},
        {"a": {"lon_deg": -51.0, "sigma": 0.5, "n": 3, "s": "y"}, "solve_time_s": 1.0},
        {"a": {"sigma": 0.5, "lon_deg": -51.0, "n": 3, "s": "x"}, "solve_time_s": 1.0},  # key order
    ):
        with pytest.raises(AssertionError):
            assert_reports_close(bad, want)


@pytest.mark.slow
@pytest.mark.parametrize("job", JOBS, ids=lambda p: p.stem)
def test_report_unchanged(job: Path) -> None:
    with gzip.open(_fixture(job), "rt") as f:
        want = json.load(f)
    got = json.loads(json.dumps(run(json.loads(job.read_text()))))  # as a client reads it
    assert_reports_close(got, want)
