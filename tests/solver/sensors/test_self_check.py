"""The self-check (solver/sensors/self_check.py, ``pba check-sensor``, the warnings of ``pba
import-sensor``): everything a file states, against the exact model and the job form.

Evidence that it sees what the corner check could not (the defects of SPOT 1-4 products that
passed the old check): on the simulated SPOT 1-4 scene (tests/solver/sensors/simulated_spot14.py)

- velocities left inertial (the screening's conversion switched off): the exact model still
  meets every corner and the centre (it uses the velocities for its orbital frame only), the job
  form misses them by hundreds of pixels and the self-check says so;
- tangents interpolated linearly: the corners still agree, the scene centre does not.

And on the public files of tests/data/vendor every comparison is within its limit.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from spot14_jobs import product

from solver.cli import main
from solver.sensors import ephemeris_check
from solver.sensors.detectors import LookAngles, _table
from solver.sensors.formats import read_product
from solver.sensors.self_check import LIMITS_PX, self_check

DATA = Path(__file__).parents[2] / "data" / "vendor"
PUBLIC = [DATA / "stereopipeline" / "spot_example1.xml", DATA / "stereopipeline" / "wv_test1.xml",
          DATA / "shareloc" / "PHRDIMAP_P1BP--2018122638935449CP.XML",
          DATA / "pyrugged" / "DIM_PHR1A_P_201202250025599_SEN_PRG_FC_5847-001.XML",
          DATA / "cbers-2-stac" / "CBERS_4_MUX_20170528_090_084_L2_BAND6.xml"]


@pytest.fixture(scope="module")
def sim14(tmp_path_factory):
    return product(tmp_path_factory.mktemp("spot14"))


def _rows(check, reference: str, model: str):
    return [r for r in check.rows if r.reference.startswith(reference) and r.model == model]


def test_the_simulated_scene_passes_every_comparison(sim14) -> None:
    _, _, p = sim14
    c = self_check(p)
    refs = {(r.reference, r.model) for r in c.rows}
    corners, centre = "corners (tie points, located without the attitude)", "scene centre (located without the attitude)"
    assert refs == {(corners, "exact"), (corners, "job form"), (centre, "exact"), (centre, "job form"),
                    ("the exact model over the image", "job form")}, refs
    assert c.passed, [r.as_dict() for r in c.rows]
    assert any("no vendor RPC" in n for n in c.notes)


def _as_before(monkeypatch) -> None:
    """The reading before the velocities' frame was screened: never converted, never refused (the
    screening would now refuse such states as inconsistent: 21-28 km per 60 s)."""
    monkeypatch.setattr(ephemeris_check, "INERTIAL_RATIO", float("inf"))
    monkeypatch.setattr(ephemeris_check, "tolerance_m", lambda dt: np.full(np.shape(dt), 1e9))


def test_inertial_velocities_used_as_earth_fixed_are_seen_by_the_job_form(sim14, monkeypatch) -> None:
    _, path, _ = sim14
    _as_before(monkeypatch)
    p = read_product(path)
    assert p.screening.velocity_frame == "earth-fixed"
    c = self_check(p)
    assert all(r.passed for r in c.rows if r.model == "exact")  # the exact model cannot tell
    bad = [r for r in c.failures() if r.model == "job form"]
    assert {r.reference.split(" (")[0] for r in bad} >= {"corners", "scene centre", "the exact model over the image"}
    assert min(r.max_px for r in bad) > 100 * LIMITS_PX["job"], [r.as_dict() for r in bad]


def test_tangents_interpolated_linearly_are_seen_by_the_scene_centre(sim14, monkeypatch) -> None:
    _, path, _ = sim14

    def tangent_linear(self, columns):
        c = np.atleast_1d(np.asarray(columns, float))
        return _table(c, self.detectors, self.along), _table(c, self.detectors, self.across)

    monkeypatch.setattr(LookAngles, "tangents", tangent_linear)
    c = self_check(read_product(path), job_form=False)
    corners, centre = _rows(c, "corners", "exact")[0], _rows(c, "scene centre", "exact")[0]
    assert corners.passed and not centre.passed and centre.max_px > 10 * LIMITS_PX["point"], (corners, centre)


@pytest.mark.parametrize("path", PUBLIC, ids=lambda p: p.name[:24])
def test_public_files_pass(path) -> None:
    c = self_check(read_product(path))
    assert c.rows and c.passed, [r.as_dict() for r in c.failures()]
    assert any(r.model == "job form" for r in c.rows)


def test_check_sensor_table_json_and_a_given_rpc(tmp_path, capsys) -> None:
    from solver.gis.rpc_io import rpc_txt

    wv = PUBLIC[1]
    rpc_file = tmp_path / "WV_RPC.TXT"
    rpc_file.write_text(rpc_txt(read_product(wv).rpc))
    assert main(["check-sensor", str(wv), "--image-id", "W", "--rpc", str(rpc_file)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"vendor RPC \(WV_RPC.TXT\)\s+exact\s+605", out) and "job form" in out, out
    assert main(["check-sensor", str(wv), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc[0]["passed"] and {r["reference"] for r in doc[0]["rows"]} >= {"vendor RPC (in the metadata file)"}


def test_import_sensor_warns_loudly_and_strict_exits_2(sim14, monkeypatch, tmp_path, capsys) -> None:
    _, path, _ = sim14
    out = tmp_path / "f.json"
    assert main(["import-sensor", str(path), "--image-id", "S", "-o", str(out)]) == 0
    assert "S: self-check: 5 comparisons within their limits" in capsys.readouterr().err
    _as_before(monkeypatch)
    out.unlink()
    assert main(["import-sensor", str(path), "--image-id", "S", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "S: WARNING: self-check: scene centre (located without the attitude) vs the job form model" in err, err
    assert main(["import-sensor", str(path), "--image-id", "S", "--strict", "-o", str(tmp_path / "g.json")]) == 2
    assert not (tmp_path / "g.json").exists() and "beyond their limits (--strict)" in capsys.readouterr().err
    assert main(["check-sensor", str(path), "--strict"]) == 2
    assert "ABOVE THE LIMIT" in capsys.readouterr().out


def test_a_reverse_scanned_maxar_product_has_no_job_form(tmp_path, capsys) -> None:
    """WorldView products scanned in reverse (the public WV01 support data of COSI-Corr's tests
    is one: its job form was 30,900 px from its exact model) are refused for a job, said by name."""
    text = PUBLIC[1].read_text()
    text = re.sub(r"<TLCLISTList>.*?</TLCLISTList>", "", text, flags=re.S).replace(
        "<SCANDIRECTION>Forward</SCANDIRECTION>", "<SCANDIRECTION>Reverse</SCANDIRECTION>")
    assert "Reverse" in text
    path = tmp_path / "reverse.xml"
    path.write_text(text)
    c = self_check(read_product(path))
    assert any(n.startswith("no job form: Reverse") for n in c.notes) and not any(r.model == "job form" for r in c.rows)
    assert main(["import-sensor", str(path), "-o", str(tmp_path / "f.json")]) == 2
    assert "SCANDIRECTION: Reverse: the lines were imaged backwards in time" in capsys.readouterr().err


TABLE_PX = 2e-3  # the docs table's numbers (printed to 3 decimals) against a fresh run


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def test_the_docs_table_is_the_scripts_output() -> None:
    """docs/sensor-metadata.md's self-check table is scripts/sensor_table.py's output for the
    public files (regenerate: python scripts/sensor_table.py --write)."""
    import importlib.util

    root = Path(__file__).parents[3]
    spec = importlib.util.spec_from_file_location("sensor_table", root / "scripts" / "sensor_table.py")
    table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(table)
    doc = (root / "docs" / "sensor-metadata.md").read_text()
    written = doc[doc.index(table.BEGIN) + len(table.BEGIN):doc.index(table.END)].strip().splitlines()
    fresh = table.table([str(table.VENDOR / f) for f in table.FILES]).splitlines()
    assert len(written) == len(fresh), "the table's rows changed: python scripts/sensor_table.py --write"
    for w, f in zip(written, fresh):
        for a, b in zip(_cells(w), _cells(f)):
            try:
                assert abs(float(a) - float(b)) <= TABLE_PX + 1e-3 * abs(float(b)), (w, f)
            except ValueError:
                assert a == b, (w, f)


GDAL_CORNER_PX = 0.5  # GDAL's pixel (0, 0) is the top-left corner; ours the top-left centre
SAME_EVALUATOR_PX = 1e-6  # our RPC evaluator against GDAL's transformer on the same points (both evaluate the same ratio)


def test_the_rpc_reference_through_gdals_transformer() -> None:
    """The self-check's RPC rows evaluate the vendor's RPC with our evaluator; GDAL's RPC
    transformer (an independent implementation) gives the same agreement with the exact model."""
    from solver.gis.rpc_io import gdal_ground_to_image, gdal_rpc
    from solver.sensors.agreement import image_grid

    p = read_product(PUBLIC[1])
    L, C, H = image_grid(p.model, p.rpc)
    g = p.model.image_to_ground(L, C, H)
    rows, cols = gdal_ground_to_image(gdal_rpc(p.rpc), g[:, 0], g[:, 1], g[:, 2])
    ours_l, ours_c = p.rpc.project(g[:, 0], g[:, 1], g[:, 2])
    assert np.abs(rows - GDAL_CORNER_PX - ours_l).max() < SAME_EVALUATOR_PX
    assert np.abs(cols - GDAL_CORNER_PX - ours_c).max() < SAME_EVALUATOR_PX
    row = next(r for r in self_check(p, job_form=False).rows if r.reference.startswith("vendor RPC"))
    gdal = np.hypot(rows - GDAL_CORNER_PX - L, cols - GDAL_CORNER_PX - C)
    assert abs(float(np.sqrt(np.mean(gdal**2))) - row.rms_px) < 1e-4 and abs(float(gdal.max()) - row.max_px) < 1e-4


def test_check_sensor_says_when_kernels_compile(monkeypatch, capsys) -> None:
    """The job form runs the adjustment's kernels: on a first run after an install they compile
    (a minute or more), and the command says so as pba run does (the notices themselves are the
    kernel cache's: solver.kernels.cache.compile_notices, tested there)."""
    from contextlib import contextmanager

    from solver.kernels import cache

    @contextmanager
    def notices(say):
        say("compiling the adjustment's kernels (first run): a minute or more")
        yield

    monkeypatch.setattr(cache, "compile_notices", notices)
    assert main(["check-sensor", str(PUBLIC[4])]) == 0
    assert "compiling the adjustment's kernels (first run)" in capsys.readouterr().err
