"""``pba import-rpc`` and ``POST /jobs/compose`` on vendors' files that hold an RPC without being
the RPC file GDAL expects: a DIMAP v2 metadata file under any name (its RPC component beside
it), an ALOS ``RPC-*.txt`` (one fixed-width line, GDAL's ALOS reader), and the refusals that
name the file and the element when the RPC is not there."""

from __future__ import annotations

import json

import numpy as np
import pytest
from simulated_dimap import Scene, dimap_v2_xml
from test_importers_rpc import SCALARS, _dimap_xml
from test_sensors_dimap_v2 import _rpc_of

from solver.cli import main
from solver.geometry.rpc import RPC
from solver.importers.compose import ComposeRequest, ImageSources, SourceFile, compose_job
from solver.importers.errors import SourceError
from solver.importers.rpc import read_rpc, read_rpc_bytes

COEFF_ABS = 1e-12  # GDAL's RPC metadata keeps the coefficients as written (O(1) numbers)
ALOS_ABS = 5e-6  # ALOS' fixed-width fields keep 5 decimals of a coefficient (+1.23456E-01) and 4 of an angle


@pytest.fixture(scope="module")
def product():
    scene = Scene()
    text, truth = dimap_v2_xml(scene, rpc_name="RPC_SIM_P_1.XML")
    return text, _rpc_of(scene, truth)


def _same(a: RPC, b: RPC, tol: float) -> None:
    for k in SCALARS:
        assert getattr(a, k) == pytest.approx(getattr(b, k), abs=max(tol, 1e-9)), k
    for k in ("line_num", "line_den", "samp_num", "samp_den"):
        np.testing.assert_allclose(getattr(a, k), getattr(b, k), atol=tol, err_msg=k)


@pytest.mark.parametrize("name", ["DIM_SIM_P_1.XML", "scene_metadata.xml"])
def test_dimap_metadata_gives_its_rpc_component(tmp_path, product, name) -> None:
    text, rpc = product
    (tmp_path / name).write_text(text)
    (tmp_path / "RPC_SIM_P_1.XML").write_text(_dimap_xml(rpc))
    out = tmp_path / "rpc.json"
    assert main(["import-rpc", str(tmp_path / name), "-o", str(out)]) == 0
    _same(RPC.from_job(json.loads(out.read_text())), rpc, COEFF_ABS)


@pytest.mark.parametrize("name", ["DIM_SIM_P_1.XML", "scene_metadata.xml"])
def test_dimap_metadata_without_its_rpc_exits_2_naming_the_component(tmp_path, capsys, product, name) -> None:
    text, _ = product
    (tmp_path / name).write_text(text)
    assert main(["import-rpc", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and name in err and "element Dataset_Content/Dataset_Components" in err \
        and "RPC_SIM_P_1.XML, not found beside it" in err, err


def _alos_line(rpc: RPC) -> str:
    """An ALOS RPC-*.txt: offsets and scales in fields of 6, 5, 8, 9, 5 characters (twice), then
    the line numerator, line denominator, sample numerator and denominator coefficients in
    12-character fields (GDAL's ALOS metadata reader)."""
    head = (f"{rpc.line_off:06.0f}{rpc.samp_off:05.0f}{rpc.lat_off:+08.3f}{rpc.long_off:+09.3f}{rpc.height_off:+05.0f}"
            f"{rpc.line_scale:06.0f}{rpc.samp_scale:05.0f}{rpc.lat_scale:+08.5f}{rpc.long_scale:+09.5f}{rpc.height_scale:+05.0f}")
    coeffs = "".join(f"{c:+.5E}" for part in (rpc.line_num, rpc.line_den, rpc.samp_num, rpc.samp_den) for c in part)
    return head + coeffs + "\n"


def test_alos_rpc_txt(tmp_path, product) -> None:
    _, fitted = product
    rounded = RPC(round(fitted.line_off), round(fitted.samp_off), round(fitted.lat_off, 3), round(fitted.long_off, 3),
                  round(fitted.height_off), round(fitted.line_scale), round(fitted.samp_scale), round(fitted.lat_scale, 5),
                  round(fitted.long_scale, 5), round(fitted.height_scale), fitted.line_num, fitted.line_den,
                  fitted.samp_num, fitted.samp_den)
    path = tmp_path / "RPC-ALPSMN123456789_O1B2R_UW.txt"
    path.write_text(_alos_line(rounded))
    _same(read_rpc(path), rounded, ALOS_ABS)
    _same(read_rpc_bytes(path.read_bytes(), "../x/" + path.name), rounded, ALOS_ABS)


def test_alos_rpc_txt_too_short_exits_2(tmp_path, capsys) -> None:
    path = tmp_path / "RPC-ALPSMN1_O1B2R_UW.txt"
    path.write_text("015000 7500\n")
    assert main(["import-rpc", str(path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and str(path) in err, err


def test_compose_answers_a_located_problem_for_dimap_metadata_sent_as_rpc(product) -> None:
    text, _ = product
    req = ComposeRequest(images=[ImageSources("N", [], rpc=SourceFile("scene.XML", text), rpc_model="RPC-SHIFT")])
    with pytest.raises(SourceError) as exc:
        compose_job(req)
    problems = [str(p) for p in exc.value.source_problems]
    assert any(p.startswith("scene.XML, element Dataset_Content") and "its RPC is the component RPC_SIM_P_1.XML" in p for p in problems), problems
