"""The job builder of the web page: the example triplet built from its source files (CSV,
QGIS .points, ASP .gcp, survey, state, ephemeris, attitude and camera files), submitted through
the page, reaches the same report as the JSON example (sigma0 and check-point RMSE to 1e-6);
a survey whose header is not recognised gets a column map."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pba_service_harness import ROOT, Server, submit_async, wait_status
from playwright.sync_api import expect

pytestmark = pytest.mark.browser

SOURCES = ROOT / "examples" / "prism-triplet-sources"
EXAMPLE = ROOT / "examples" / "prism-triplet.json"
SOLVE_MS = 240_000
SAME = 1e-6  # sigma0 (dimensionless) and RMSE (m): the same adjustment, points in another order


@pytest.fixture(scope="module")
def local_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A local single-user server of this module's own (overrides the session's): the jobs
    submitted here must not appear in the job lists other browser tests start from."""
    with Server(tmp_path_factory.mktemp("builder-local"), workers=1, require_api_keys="false") as srv:
        yield srv


def test_build_the_example_triplet_from_its_files(page: Any, local_server: Server, tmp_path: Path) -> None:
    page.goto(f"{local_server.url}/ui")
    page.set_input_files("#builder-input", [str(p) for p in sorted(SOURCES.iterdir())])
    expect(page.locator("#builder-status")).to_contain_text("219 degrees of freedom", timeout=60_000)
    # what the page recognised
    kinds = {
        "survey.csv": "points",
        "cameras.json": "cameras",
        "prism-nadir.points": "measurements",
        "prism-forward.gcp": "measurements",
        "prism-nadir-ties.csv": "measurements",
        "prism-backward.state.csv": "state",
        "prism-forward.attitude.csv": "attitude",
    }
    for name, kind in kinds.items():
        expect(page.locator(f'select.b-kind[data-file="{name}"]')).to_have_value(kind)
    expect(page.locator('input.b-image[data-file="prism-nadir-ties.csv"]')).to_have_value("prism-nadir")
    expect(page.locator('select.b-camera[data-image="prism-forward"]')).to_have_value("prism-forward")
    expect(page.locator("#builder-messages")).to_contain_text("prism-nadir: 22 gcp, 20 check, 40 tie measured")
    page.fill("#b-name", "triplet from files")
    expect(page.locator("#builder-json")).to_have_value(re.compile('"name": "triplet from files"'), timeout=60_000)
    expect(page.locator("#builder-status")).to_contain_text("219 degrees of freedom", timeout=60_000)
    built = json.loads(page.locator("#builder-json").input_value())
    assert built["name"] == "triplet from files" and len(built["observations"]) == 246
    page.click("#builder-submit")
    expect(page.locator("#cur-status")).to_have_text("successful", timeout=SOLVE_MS)
    job_id = page.locator("#cur-id").inner_text()

    with local_server.client() as c:
        example_id = submit_async(c, json.loads(EXAMPLE.read_text()))
        assert wait_status(c, example_id, timeout=SOLVE_MS / 1000)["status"] == "successful"
        from_files = c.get(f"/jobs/{job_id}/results").json()["report"]
        from_json = c.get(f"/jobs/{example_id}/results").json()["report"]
    a, b = from_files["adjustment"], from_json["adjustment"]
    assert abs(a["sigma0_aposteriori"] - b["sigma0_aposteriori"]) < SAME
    assert a["dof"] == b["dof"] == 219
    for k in ("e", "n", "u", "planimetric"):
        assert abs(from_files["checkpoints"]["rmse_m"][k] - from_json["checkpoints"]["rmse_m"][k]) < SAME
    assert from_files["checkpoints"]["n"] == from_json["checkpoints"]["n"] == 20


def test_an_unrecognised_header_gets_a_column_map(page: Any, local_server: Server, tmp_path: Path) -> None:
    files = [p for p in sorted(SOURCES.iterdir()) if p.name != "survey.csv"]
    lines = (SOURCES / "survey.csv").read_text().splitlines()
    head = lines.index("id,x,y,z,sx,sy,sz,role")
    lines[head] = "Ponto,Leste,Norte,Altura,sx,sy,sz,role"
    survey = tmp_path / "levantamento.csv"
    survey.write_text("\n".join(lines) + "\n")
    page.goto(f"{local_server.url}/ui")
    page.set_input_files("#builder-input", [str(p) for p in files] + [str(survey)])
    row = page.locator('tr[data-file="levantamento.csv"]')
    expect(row.locator(".problem")).to_contain_text(f"levantamento.csv, line {head + 1}", timeout=60_000)
    expect(row.locator(".problem")).to_contain_text("no column for id, x, y, z")
    for column, name in (("Ponto", "id"), ("Leste", "x"), ("Norte", "y"), ("Altura", "z")):
        page.select_option(f'select.b-map[data-column="{column}"]', name)
    expect(page.locator("#builder-status")).to_contain_text("219 degrees of freedom", timeout=60_000)
    expect(row.locator(".problem")).to_have_count(0)


def test_build_an_rpc_block_from_its_files(page: Any, local_server: Server, tmp_path: Path) -> None:
    """RPC images: each image's NAME_RPC.TXT is recognised as its RPC, the image gets a bias
    model instead of a sensor, and the composed job has RPC images (no cameras) with the models
    chosen on the page; submitted, it is adjusted."""
    from solver.importers.export import write_sources
    from solver.simulate import presets
    from solver.simulate.rpc import RpcSettings
    from solver.simulate.scene import SceneSettings

    s = SceneSettings(preset="prism-triplet", seed=5, rpc=RpcSettings("RPC-DRIFT", {"a0": 6.0, "b0": -4.0}))
    job = presets.prism_triplet(s, gcps=6, checks=4, tie_points=12).job()
    write_sources(job, tmp_path)
    ids = [im["id"] for im in job["images"]]
    page.goto(f"{local_server.url}/ui")
    page.set_input_files("#builder-input", [str(p) for p in sorted(tmp_path.iterdir())])
    expect(page.locator("#builder-status")).to_contain_text("degrees of freedom", timeout=60_000)
    for i in ids:
        expect(page.locator(f'select.b-kind[data-file="{i}_RPC.TXT"]')).to_have_value("rpc")
        expect(page.locator(f'input.b-image[data-file="{i}_RPC.TXT"]')).to_have_value(i)
        expect(page.locator(f'select.b-rpc-model[data-image="{i}"]')).to_have_value("RPC-DRIFT")
    expect(page.locator("select.b-camera")).to_have_count(0)
    page.select_option(f'select.b-rpc-model[data-image="{ids[0]}"]', "RPC-SHIFT")
    expect(page.locator("#builder-json")).to_have_value(re.compile('"RPC-SHIFT"'), timeout=60_000)
    expect(page.locator("#builder-status")).to_contain_text("degrees of freedom", timeout=60_000)
    built = json.loads(page.locator("#builder-json").input_value())
    assert built["cameras"] == []
    assert [im["model"]["name"] for im in built["images"]] == ["RPC-SHIFT", "RPC-DRIFT", "RPC-DRIFT"]
    assert all("rpc" in im and "camera" not in im for im in built["images"])
    page.click("#builder-submit")
    expect(page.locator("#cur-status")).to_have_text("successful", timeout=SOLVE_MS)


def test_build_an_image_from_its_sensor_metadata(page: Any, local_server: Server, tmp_path: Path) -> None:
    """A vendor metadata file (a real WorldView-2 support-data XML) is recognised as the sensor
    of its image: no camera to choose, and the composed job carries the metadata's camera,
    ephemeris, attitude and model."""
    from utils.vendor_control import WORLDVIEW, write_rpc_control

    (tmp_path / "wv_mvp_1.xml").write_bytes(WORLDVIEW.read_bytes())
    write_rpc_control(WORLDVIEW, tmp_path, "wv_mvp_1")
    page.goto(f"{local_server.url}/ui")
    page.fill("#b-crs", "EPSG:4979")
    page.set_input_files("#builder-input", [str(p) for p in sorted(tmp_path.iterdir())])
    expect(page.locator('select.b-kind[data-file="wv_mvp_1.xml"]')).to_have_value("sensor", timeout=60_000)
    expect(page.locator('input.b-image[data-file="wv_mvp_1.xml"]')).to_have_value("wv_mvp_1")
    expect(page.locator("select.b-camera")).to_have_count(0)
    expect(page.locator("#builder-status")).to_contain_text("degrees of freedom", timeout=60_000)
    built = json.loads(page.locator("#builder-json").input_value())
    assert [c["id"] for c in built["cameras"]] == ["wv_mvp_1"]
    im = built["images"][0]
    assert im["model"]["name"] == "OA-J2" and im["ephemeris"] and im["attitude"]


def test_the_way_back_keeps_the_attitude_base(page: Any, local_server: Server, tmp_path: Path) -> None:
    """A job composed from vendor metadata (the real WorldView-2 file) written back as source
    files (``pba job-sources``): the page recognises the attitude-base table by its name and
    the composed job carries the delivered attitude as its base again, sample for sample. (The
    first line's time is an argument of ``pba job``, not a file: the page's job needs it set,
    so only the composition is checked here.)"""
    from utils.vendor_control import WORLDVIEW as wv
    from utils.vendor_control import write_rpc_control

    from solver.cli import main
    from solver.importers.export import write_sources

    src = tmp_path / "src"
    src.mkdir()
    write_rpc_control(wv, src, "W")
    job_path = tmp_path / "job.json"
    assert main(["job", "--sensor", f"W={wv}", "--image", f"W={src / 'W.csv'}", "--gcps", str(src / "gcps.csv"),
                 "--crs", "EPSG:4979", "-o", str(job_path)]) == 0
    job = json.loads(job_path.read_text())
    base = job["images"][0]["attitude_base"]
    back = tmp_path / "back"
    write_sources(job, back)
    assert (back / "W.attitude-base.csv").is_file()
    page.goto(f"{local_server.url}/ui")
    page.fill("#b-crs", "EPSG:4979")
    page.set_input_files("#builder-input", [str(p) for p in sorted(back.iterdir())])
    expect(page.locator('select.b-kind[data-file="W.attitude-base.csv"]')).to_have_value("attitude_base", timeout=60_000)
    expect(page.locator('input.b-image[data-file="W.attitude-base.csv"]')).to_have_value("W")
    expect(page.locator("#builder-status")).to_contain_text("composed", timeout=60_000)
    built = json.loads(page.locator("#builder-json").input_value())
    again = built["images"][0]["attitude_base"]
    assert len(again) == len(base)
    assert max(abs(a["pitch_deg"] - b["pitch_deg"]) for a, b in zip(again, base)) < 1e-9  # degrees: the table's text form


def test_build_an_rpc_pair_with_bias_priors_and_a_dem(page: Any, local_server: Server, tmp_path: Path) -> None:
    """Two real RPC images (their GDAL sidecars), a tie-point table and the SRTM crop named as a
    DEM: the builder sends the DEM, its vertical datum and sigma and the bias prior; the
    composed job carries the DEM's ellipsoidal grid and a prior on every bias term."""
    data = ROOT / "tests" / "data"
    ties = []
    for im in ("ventoux_left", "ventoux_right"):  # one measurement file per image, named after it
        ties.append(tmp_path / f"{im}-ties.csv")
        ties[-1].write_text("point,line,column\n" + "".join(f"T{k},{100 + 30 * k},{120 + 25 * k}\n" for k in range(8)))
    dem = tmp_path / "srtm-dem.tif"
    dem.write_bytes((data / "dem" / "srtm_ventoux.tif").read_bytes())
    page.goto(f"{local_server.url}/ui")
    page.select_option("#b-dem-vertical", "egm96")
    page.fill("#b-dem-sigma", "6")
    page.fill("#b-bias-prior", "4")
    page.set_input_files("#builder-input", [str(data / "matching" / "ventoux_left_RPC.TXT"),
                                            str(data / "matching" / "ventoux_right_RPC.TXT"), *map(str, ties), str(dem)])
    expect(page.locator('select.b-kind[data-file="srtm-dem.tif"]')).to_have_value("dem")
    expect(page.locator("#builder-json")).to_have_value(re.compile('"dem"'), timeout=60_000)
    built = json.loads(page.locator("#builder-json").input_value())
    assert built["dem"]["sigma_m"] == 6.0 and "EGM96" in built["dem"]["grid"]["vertical"]
    assert all(set(im["bias_prior"]) == {"a0", "a_line", "b0", "b_line"} for im in built["images"])
    assert built["images"][0]["bias_prior"]["a0"]["sigma"] == 4.0
