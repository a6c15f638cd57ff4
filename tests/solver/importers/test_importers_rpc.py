"""``pba import-rpc`` (issue 17): RPCs read by GDAL from the files GDAL reads — GeoTIFF RPC tags,
``_RPC.TXT`` and ``.RPB`` sidecars (written by solver/gis/rpc_io.py, bare or beside a raster)
and a DIMAP RPC XML written here in the layout GDAL's Pleiades reader parses (1-based offsets,
which GDAL converts) — come back as the job's ``images[].rpc`` object field by field.

Tolerances: offsets and scales to 1e-9 relative (GDAL prints ~15 significant digits, the
files hold 16); coefficients to 1e-12 absolute (they are O(1) and smaller); a DIMAP offset
wrong by GDAL's one pixel, or a half-pixel convention slip, is 1e8 times these.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from tolerances import RECOMPUTED_REL

from solver.cli import main
from solver.geometry.rpc import RPC
from solver.gis.rpc_io import write_raster_with_rpc, write_sidecar
from solver.importers.errors import SourceError
from solver.importers.rpc import read_rpc
from solver.simulate import presets
from solver.simulate.rpc import RpcSettings
from solver.simulate.scene import SceneSettings

RPC_NUMBER_ABS = 1e-12  # RPC coefficients and offsets written and read back (values of O(1))

pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")

SCALARS = ["line_off", "samp_off", "lat_off", "long_off", "height_off", "line_scale", "samp_scale", "lat_scale", "long_scale", "height_scale"]
COEFFS = {"line_num_coeff": "line_num", "line_den_coeff": "line_den", "samp_num_coeff": "samp_num", "samp_den_coeff": "samp_den"}


@pytest.fixture(scope="module")
def rpc() -> RPC:
    """A realistic RPC: fitted by the simulator to a tilted PRISM-like image (ideal geometry)."""
    s = SceneSettings(preset="prism-single", seed=4, rpc=RpcSettings("RPC-AFFINE", {"a0": 3.0, "b_line": 1e-5}))
    scene = presets.prism_single(s, camera="forward", gcps=6, checks=2)
    r = scene.rpcs[0]
    r.err_bias, r.err_rand = 1.5, 0.25
    return r


def _assert_same(obj: dict, rpc: RPC, line_shift: float = 0.0) -> None:
    for k in SCALARS:
        want = getattr(rpc, k) + (line_shift if k in ("line_off", "samp_off") else 0.0)
        assert obj[k] == pytest.approx(want, rel=RECOMPUTED_REL, abs=RPC_NUMBER_ABS), k
    for k, attr in COEFFS.items():
        assert len(obj[k]) == 20
        np.testing.assert_allclose(obj[k], getattr(rpc, attr), rtol=0, atol=RPC_NUMBER_ABS, err_msg=k)


def _blank_tif(path, n=8):
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="uint8") as dst:
        dst.write(np.zeros((1, n, n), np.uint8))


def _dimap_xml(rpc: RPC) -> str:
    """A DIMAP v2 RPC file as Pleiades products have it: Global_RFM with the ground-to-image
    (Inverse_Model) coefficients and RFM_Validity with offsets and scales, LINE_OFF and SAMP_OFF
    1-based (the top-left pixel's centre is (1, 1))."""
    md = rpc.to_gdal()
    coeffs = "".join(
        f"<{key}_{i}>{v}</{key}_{i}>" for key in ("SAMP_NUM_COEFF", "SAMP_DEN_COEFF", "LINE_NUM_COEFF", "LINE_DEN_COEFF")
        for i, v in enumerate(md[key].split(), start=1)
    )
    validity = "".join(
        f"<{k.upper()}>{getattr(rpc, k) + (1.0 if k in ('line_off', 'samp_off') else 0.0)!r}</{k.upper()}>" for k in SCALARS
    )
    return (
        "<?xml version='1.0' encoding='UTF-8'?>\n<Dimap_Document><Rational_Function_Model><Global_RFM>"
        f"<Inverse_Model>{coeffs}</Inverse_Model><RFM_Validity>{validity}</RFM_Validity>"
        "</Global_RFM></Rational_Function_Model></Dimap_Document>\n"
    )


@pytest.mark.parametrize("kind", ["tags", "txt", "rpb", "txt-beside", "rpb-beside"])
def test_gdal_files_round_trip(tmp_path, rpc, kind) -> None:
    if kind == "tags":
        _blank_tif(tmp_path / "raw.tif")
        source = write_raster_with_rpc(rpc, tmp_path / "raw.tif", tmp_path / "scene.tif")
    elif kind in ("txt", "rpb"):
        source = write_sidecar(rpc, tmp_path / ("scene_RPC.TXT" if kind == "txt" else "scene.RPB"))
    else:
        _blank_tif(tmp_path / "scene.tif")
        write_sidecar(rpc, tmp_path / ("scene_RPC.TXT" if kind == "txt-beside" else "scene.RPB"))
        source = tmp_path / "scene.tif"
    out = tmp_path / "rpc.json"
    assert main(["import-rpc", str(source), "-o", str(out)]) == 0
    obj = json.loads(out.read_text())
    assert obj["pixel_convention"] == "center"
    _assert_same(obj, rpc)
    assert obj["err_bias"] == pytest.approx(1.5) and obj["err_rand"] == pytest.approx(0.25)


def test_dimap_rpc_xml_through_gdal(tmp_path, rpc) -> None:
    """GDAL's reader subtracts DIMAP's 1-based origin: the object is in ours (centre at 0)."""
    xml = tmp_path / "RPC_PHR1A_P_201801011030_SEN_1.XML"
    xml.write_text(_dimap_xml(rpc))
    _assert_same(read_rpc(xml).to_job(), rpc)


def test_gdal_convention_and_whole_image_entry(tmp_path, rpc, capsys) -> None:
    source = write_sidecar(rpc, tmp_path / "scene_RPC.TXT")
    assert main(["import-rpc", str(source), "--image-id", "N", "--model", "RPC-SHIFT", "--pixel-convention", "gdal"]) == 0
    entry = json.loads(capsys.readouterr().out)
    assert set(entry) == {"id", "rpc", "model"} and entry["id"] == "N" and entry["model"] == {"name": "RPC-SHIFT"}
    assert entry["rpc"]["pixel_convention"] == "gdal"
    _assert_same(entry["rpc"], rpc, line_shift=0.5)
    back = RPC.from_job(entry["rpc"])  # converted back to ours once
    assert back.line_off == pytest.approx(rpc.line_off, rel=RECOMPUTED_REL) and back.samp_off == pytest.approx(rpc.samp_off, rel=RECOMPUTED_REL)


@pytest.mark.parametrize("name,content", [
    ("scene.RPB", "this is not an RPB\n"),
    ("scene_RPC.TXT", "LINE_OFF: 12\n"),
    ("scene.tif", None),  # a raster without RPC
    ("notes.json", '{"a": 1}'),
    ("missing.RPB", False),
])
def test_bad_files_exit_2_with_the_file_named(tmp_path, capsys, name, content) -> None:
    path = tmp_path / name
    if content is None:
        _blank_tif(path)
    elif content is not False:
        path.write_text(content)
    assert main(["import-rpc", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "Traceback" not in err
    with pytest.raises(SourceError):
        read_rpc(path)


@pytest.mark.parametrize("kind", ["txt", "rpb", "dimap"])
def test_uploaded_bytes_are_read_under_their_name_only(tmp_path, rpc, kind) -> None:
    """An upload (bytes and the name the client gave): read through GDAL like the file, the
    name deciding the reader; a name with directories is never opened as a path; a raster is
    refused (uploads are read in the server's process: its small sidecar is what to send)."""
    from solver.gis.rpc_io import rpc_rpb, rpc_txt
    from solver.importers.rpc import read_rpc_bytes

    data = {"txt": rpc_txt, "rpb": rpc_rpb, "dimap": _dimap_xml}[kind](rpc).encode()
    name = {"txt": "/etc/scene_RPC.TXT", "rpb": "..\\scene.RPB", "dimap": "../RPC_PHR1A_P_2018_SEN_1.XML"}[kind]
    _assert_same(read_rpc_bytes(data, name).to_job(), rpc)
    _blank_tif(tmp_path / "blank.tif")
    raster = write_raster_with_rpc(rpc, tmp_path / "blank.tif", tmp_path / "scene.tif")
    with pytest.raises(SourceError) as exc:
        read_rpc_bytes(raster.read_bytes(), "scene.tif")
    assert exc.value.source_problems[0].code == "not_an_rpc_file"
    with pytest.raises(SourceError) as exc:
        read_rpc_bytes(b"LINE_OFF: 12\n", "/etc/passwd_RPC.TXT")
    assert exc.value.source_problems[0].file == "/etc/passwd_RPC.TXT"  # named as given, not opened


def test_compose_an_rpc_image_from_an_upload(rpc) -> None:
    """The composer (pba job, POST /jobs/compose): an image with an RPC file and no camera
    becomes {id, rpc, model}; a bad RPC file is a located problem."""
    from solver.gis.rpc_io import rpc_txt
    from solver.importers.compose import ComposeRequest, ImageSources, SourceFile, compose_job

    meas = SourceFile("N.csv", "point,line,column\nA,100.5,200.25\nB,900,3000\nC,5000,1000\n")
    survey = SourceFile("survey.csv", "id,x,y,z\nA,-51.1,-22.0,400\nB,-51.2,-22.1,410\nC,-51.15,-22.05,420\n")
    req = ComposeRequest(images=[ImageSources("N", [meas], rpc=SourceFile("N_RPC.TXT", rpc_txt(rpc)), rpc_model="RPC-SHIFT")],
                         gcps=[survey], models=["K2"])
    job = compose_job(req).job
    (image,) = job["images"]
    assert set(image) == {"id", "rpc", "model"} and image["model"] == {"name": "RPC-SHIFT"}
    _assert_same(image["rpc"], rpc)
    assert job["cameras"] == []
    bad = ComposeRequest(images=[ImageSources("N", [meas], rpc=SourceFile("N_RPC.TXT", "LINE_OFF: 12\n"))], gcps=[survey])
    with pytest.raises(SourceError) as exc:
        compose_job(bad)
    assert [p.file for p in exc.value.source_problems] == ["N_RPC.TXT"]
