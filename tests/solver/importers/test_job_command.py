"""``pba job``: the example triplet's source files compose the example job again; the
composer's checks (time scales, cameras, images); what it prints; the sensor presets; the
image camera ``{"ref": ...}`` form of the job schema."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from tolerances import SAME_NUMBER_REL

from solver.cli import main
from solver.importers.compose import ComposeRequest, ImageSources, SourceFile, compose_job, summarize
from solver.importers.errors import SourceError
from solver.importers.presets import PRESETS, preset_camera
from solver.schema.job import Camera, load_job

CHIP_PLACE_MM = 1e-9  # nominal chip places symmetric about the principal point: sums of column counts x pixel size
SAME_ADJUSTMENT_REL = 1e-6  # the same job written and read back adjusts to the same check-point RMSE

ROOT = Path(__file__).parents[3]
SOURCES = ROOT / "examples" / "prism-triplet-sources"
EXAMPLE = ROOT / "examples" / "prism-triplet.json"
PX_TOL = 1e-9  # px: QGIS's +-0.5 px shifts, a few ulps of 1e4

# the command of examples/README.md ("from your own files")
EXAMPLE_ARGS = [
    "job", "--name", "PRISM triplet, Presidente Prudente (simulated)", "--crs", "EPSG:4326",
    "--points", "survey.csv", "--camera-file", "cameras.json", "--model", "K2",
    "--image", "prism-backward=prism-backward.csv",
    "--state", "prism-backward=prism-backward.state.csv",
    "--ephemeris", "prism-backward=prism-backward.ephemeris.csv",
    "--attitude", "prism-backward=prism-backward.attitude.csv",
    "--image", "prism-nadir=prism-nadir.points", "--image", "prism-nadir=prism-nadir-ties.csv",
    "--state", "prism-nadir=prism-nadir.state.csv",
    "--ephemeris", "prism-nadir=prism-nadir.ephemeris.csv",
    "--attitude", "prism-nadir=prism-nadir.attitude.csv",
    "--image", "prism-forward=prism-forward.gcp", "--image", "prism-forward=prism-forward-ties.csv",
    "--state", "prism-forward=prism-forward.state.csv",
    "--ephemeris", "prism-forward=prism-forward.ephemeris.csv",
    "--attitude", "prism-forward=prism-forward.attitude.csv",
]


def same_job_content(a: dict[str, Any], b: dict[str, Any]) -> None:
    """Equal jobs up to the order of points and observations (pixels to PX_TOL)."""
    assert {k: a[k] for k in ("name", "crs", "cameras", "images")} == {k: b[k] for k in ("name", "crs", "cameras", "images")}
    assert sorted(a["points"], key=lambda p: p["id"]) == sorted(b["points"], key=lambda p: p["id"])
    oa = {(o["image"], o["point"]): o for o in a["observations"]}
    ob = {(o["image"], o["point"]): o for o in b["observations"]}
    assert oa.keys() == ob.keys()
    for k, o in oa.items():
        assert abs(o["line"] - ob[k]["line"]) < PX_TOL and abs(o["column"] - ob[k]["column"]) < PX_TOL
        assert o.get("sigma_px") == ob[k].get("sigma_px") and o.get("chip") == ob[k].get("chip")


def test_example_sources_compose_the_example_job(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """CSV (backward), QGIS .points (nadir), ASP .gcp (forward), survey, state, ephemeris and
    attitude tables: the same job as examples/prism-triplet.json."""
    monkeypatch.chdir(SOURCES)
    out = tmp_path / "job.json"
    assert main([*EXAMPLE_ARGS, "-o", str(out)]) == 0
    same_job_content(json.loads(out.read_text()), json.loads(EXAMPLE.read_text()))
    err = capsys.readouterr().err
    assert "points: 22 gcp, 20 check, 40 tie" in err
    for image in ("prism-backward", "prism-nadir", "prism-forward"):
        assert f"image {image}: 22 gcp, 20 check, 40 tie measured" in err
    assert "valid: " in err


def test_readme_shows_the_example_command() -> None:
    readme = (ROOT / "examples" / "README.md").read_text()
    block = re.search(r"```sh\ncd examples/prism-triplet-sources\n(pba job .*?)\n```", readme, re.S)
    assert block, "examples/README.md has the pba job command of the source files"
    assert shlex.split(block.group(1).replace("\\\n", " ")) == ["pba", *EXAMPLE_ARGS, "-o", "job.json"]


def test_job_sources_writes_what_pba_job_reads_back(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The other way round: the example job written as sources (all three formats) and read."""
    out = tmp_path / "src"
    assert main(["job-sources", str(EXAMPLE), "-o", str(out), "--format", "prism-backward=asp",
                 "--format", "prism-forward=qgis"]) == 0
    assert (out / "prism-backward.gcp").exists() and (out / "prism-forward.points").exists()
    monkeypatch.chdir(out)
    args = [a.replace("prism-backward.csv", "prism-backward.gcp") for a in EXAMPLE_ARGS]
    args = [a.replace("prism-nadir.points", "prism-nadir.csv").replace("prism-forward.gcp", "prism-forward.points") for a in args]
    args = [a for a in args if a not in ("prism-nadir=prism-nadir-ties.csv",)]
    args = [a for i, a in enumerate(args) if not (a == "--image" and args[i + 1].startswith("--"))]
    args += ["--image", "prism-backward=prism-backward-ties.csv"]
    assert main([*args, "-o", str(tmp_path / "job.json")]) == 0
    same_job_content(json.loads((tmp_path / "job.json").read_text()), json.loads(EXAMPLE.read_text()))


def test_file_problems_are_printed_with_file_line_column(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    Path("survey.csv").write_text("id,x,y,z\nA,-51.1,-22.0,400\nB,-51.2,-22.1,4OO\n")
    Path("n.csv").write_text("point,line,column\nA,10,20\n")
    assert main(["job", "--camera", "prism-nadir", "--image", "N=n.csv", "--gcps", "survey.csv"]) == 2
    assert "survey.csv, line 3, column z: '4OO' is not a number" in capsys.readouterr().err


def _req(**kw: Any) -> ComposeRequest:
    im = ImageSources("N", [SourceFile("n.csv", "point,line,column\nA,10,20\nT1,30,40\n")], "prism-nadir")
    return ComposeRequest(images=[im], gcps=[SourceFile("s.csv", "id,x,y,z\nA,-51.1,-22.0,400\n")], **kw)


def test_time_scales_of_one_image_must_agree() -> None:
    req = _req()
    req.images[0].state = SourceFile("state.csv", "# time_scale: UTC\ntime_s,x,y,z,vx,vy,vz\n10,7e6,0,0,0,7500,0\n")
    req.images[0].ephemeris = SourceFile("eph.csv", "# time_scale: GPS\nt,x,y,z,vx,vy,vz\n0,7e6,0,0,0,7500,0\n60,7e6,1,0,0,7500,0\n")
    with pytest.raises(SourceError) as exc:
        compose_job(req)
    assert exc.value.source_problems[0].code == "time_scale_mismatch"
    assert "UTC" in str(exc.value) and "GPS" in str(exc.value)


def test_preset_camera_and_tie_points_and_unknown_camera() -> None:
    composed = compose_job(_req())
    job = composed.job
    assert job["cameras"] == [preset_camera("prism-nadir")]
    assert {p["id"]: p["role"] for p in job["points"]} == {"A": "gcp", "T1": "tie"}
    assert any("tie points" in n for n in composed.notes)
    req = _req()
    req.images[0].camera = "hrsc"
    with pytest.raises(SourceError) as exc:
        compose_job(req)
    assert exc.value.source_problems[0].code == "unknown_camera"


def test_summary_flags_single_image_points_and_points_outside() -> None:
    job = json.loads(EXAMPLE.read_text())
    job["observations"] = [o for o in job["observations"] if not (o["point"] == "T0001" and o["image"] != "prism-nadir")]
    bad = next(o for o in job["observations"] if o["point"] == "P05" and o["image"] == "prism-forward")
    bad["line"] = 16000.0  # beyond the last line's lower edge (15999.5)
    s = summarize(job)
    assert s["single_image"] == ["T0001"] and s["single_image_ties"] == ["T0001"]
    assert s["outside"] == [{"image": "prism-forward", "point": "P05", "line": 16000.0, "column": bad["column"]}]
    assert s["images"]["prism-nadir"] == {"gcp": 22, "check": 20, "tie": 40}
    assert s["images"]["prism-backward"]["tie"] == 39


def test_presets_hold_the_papers_values() -> None:
    """Seed 001 Table 1 focal lengths, seed 000 pixel and line time, seed 001's chips."""
    focal = {"prism-backward": 1999.8762715, "prism-nadir": 1999.8630195, "prism-forward": 2000.0645632}
    for name, f in focal.items():
        cam = Camera.model_validate(preset_camera(name))
        assert cam.focal_mm == f and cam.pixel_mm == 0.0071 and cam.line_time_s == 0.00037
        assert (cam.lines, cam.columns) == (16000, 14496)
        widths = {c.columns for c in cam.chips}
        assert widths == ({4992} if name == "prism-nadir" else {4928}) and len(cam.chips) == 4
        ends = [(c.first_column, c.first_column + c.columns) for c in cam.chips]
        assert all(a[1] - b[0] == 32 for a, b in zip(ends, ends[1:], strict=False))  # 32-column overlaps
        assert ends[0][0] <= 0 and ends[-1][1] >= 14496  # every image column on a chip
        # nominal chip places: symmetric about the principal point
        assert cam.chips[0].dy_mm == pytest.approx(-cam.chips[3].dy_mm, abs=CHIP_PLACE_MM)
    assert {"prism-backward", "prism-nadir", "prism-forward", "cbers-ccd"} <= set(PRESETS)
    assert preset_camera("prism-backward")["mounting_pitch_deg"] == -23.8
    assert all(v.version == i + 1 for versions in PRESETS.values() for i, v in enumerate(versions))


def test_an_image_may_name_a_library_camera_in_place() -> None:
    doc = json.loads((ROOT / "examples" / "prism-nadir.json").read_text())
    doc["cameras"] = []
    doc["images"][0]["camera"] = {"ref": {"name": "prism-nadir"}}
    job = load_job(doc)
    assert job.images[0].camera == "prism-nadir"
    assert [(c.id, c.ref.name if c.ref else None) for c in job.cameras] == [("prism-nadir", "prism-nadir")]
    doc["images"][0]["camera"] = {"ref": {"name": "prism-nadir", "version": 2}}
    assert load_job(doc).cameras[0].id == "prism-nadir@v2"
    doc["cameras"] = [{"id": "prism-nadir@v2", "focal_mm": 1.0, "pixel_mm": 0.01, "line_time_s": 0.001, "lines": 10, "columns": 10}]
    with pytest.raises(ValueError, match="defines otherwise"):
        load_job(doc)


def test_column_map_model_comparison_and_options(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """--columns renames a survey's header, several --model names make a comparison, --options
    is merged into the job's options."""
    monkeypatch.chdir(tmp_path)
    Path("levantamento.csv").write_text("Ponto;Leste;Norte;Altura\nA;-51.1;-22.0;400\n")
    Path("n.csv").write_text("point,line,column\nA,10,20\n")
    args = ["job", "--camera", "prism-nadir", "--image", "N=n.csv", "--gcps", "levantamento.csv",
            "--columns", "levantamento.csv:Ponto=id,Leste=x,Norte=y,Altura=z", "--model", "K1,K2",
            "--options", '{"covariance": false}', "-o", "job.json"]
    assert main(args) == 1  # composed and written; one control point cannot orient an image
    job = json.loads(Path("job.json").read_text())
    assert job["points"] == [{"id": "A", "role": "gcp", "coordinates": [-51.1, -22.0, 400.0]}]
    assert job["options"] == {"covariance": False, "models": ["K1", "K2"]}
    assert job["images"][0]["model"] == {"name": "K1"}
    assert "problem: " in capsys.readouterr().err


def _rpc_numbers(rpc: dict[str, Any]) -> np.ndarray:
    keys = [k for k in sorted(rpc) if k != "pixel_convention"]
    return np.concatenate([np.atleast_1d(np.asarray(rpc[k], float)) for k in keys])


def test_rpc_images_round_trip_through_job_sources_and_pba_job(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A mixed block of the simulator (K2 nadir camera image, two RPC-DRIFT images) written as
    sources (the RPC images' RPCs as GDAL's NAME_RPC.TXT) and composed again by ``pba job --rpc
    ... --rpc-model ...``: the RPCs come back through GDAL (every number to 1e-12 relative: the
    text carries 16 significant digits), the RPC images have no camera, the rest is the same
    job, and its adjustment equals the original's."""
    from solver.api import run
    from solver.simulate import presets
    from solver.simulate.rpc import RpcSettings
    from solver.simulate.scene import SceneSettings

    s = SceneSettings(preset="prism-triplet", seed=2, rpc=RpcSettings("RPC-DRIFT", {"a0": 15.0, "b0": -8.0}, (1, 3)))
    job = presets.prism_triplet(s, gcps=8, checks=8, tie_points=20).job()
    rpc_ids = [im["id"] for im in job["images"] if im.get("rpc")]
    assert len(rpc_ids) == 2 and len(job["cameras"]) == 1
    src = tmp_path / "src"
    job_path = tmp_path / "original.json"
    job_path.write_text(json.dumps(job))
    assert main(["job-sources", str(job_path), "-o", str(src)]) == 0
    assert sorted(p.name for p in src.glob("*_RPC.TXT")) == sorted(f"{i}_RPC.TXT" for i in rpc_ids)
    # the command it prints: "pba job ARGS -o job.json"
    printed = shlex.split(capsys.readouterr().err.strip().splitlines()[-1])
    assert printed[:2] == ["pba", "job"] and printed[-2:] == ["-o", "job.json"]
    args = printed[2:-2]
    assert "--rpc" in args and "--rpc-model" in args
    monkeypatch.chdir(src)
    out = tmp_path / "job.json"
    assert main(["job", *args, "-o", str(out)]) == 0
    back = json.loads(out.read_text())
    for a, b in zip(back["images"], job["images"], strict=True):
        assert a["id"] == b["id"] and a["model"] == b["model"]
        if b.get("rpc"):
            assert "camera" not in a and a["rpc"]["pixel_convention"] == "center"
            np.testing.assert_allclose(_rpc_numbers(a["rpc"]), _rpc_numbers(b["rpc"]), rtol=SAME_NUMBER_REL, atol=0)
    rigorous = lambda d: {**d, "images": [im for im in d["images"] if not im.get("rpc")]}  # noqa: E731
    same_job_content(rigorous(back), rigorous(job))
    ra, rb = run(back), run(job)
    # the same adjustment: the RPC numbers differ by at most 1e-12 relative (measured 0)
    assert ra["checkpoints"]["rmse_m"]["3d"] == pytest.approx(rb["checkpoints"]["rmse_m"]["3d"], rel=SAME_ADJUSTMENT_REL)


MATCHING = ROOT / "tests" / "data" / "matching"


def test_bias_prior_puts_a_prior_on_every_rpc_bias_term(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``pba job --rpc ... --bias-prior PX``: two real RPC images (Pleiades, Mont Ventoux) with
    tie points only. Without the flag the datum is undefined (exit 1, the problem says so); with
    it every RPC image's offsets get 0 +- PX and its drift terms PX over the image's extent, and
    the job is valid."""
    monkeypatch.chdir(tmp_path)
    ties = "point,image,line,column\n" + "".join(
        f"T{k},{im},{100 + 30 * k},{120 + 25 * k}\n" for k in range(8) for im in ("L", "R"))
    Path("ties.csv").write_text(ties)
    base = ["job", "--rpc", f"L={MATCHING / 'ventoux_left_RPC.TXT'}", "--rpc", f"R={MATCHING / 'ventoux_right_RPC.TXT'}",
            "--image", "ties.csv", "-o", "job.json"]
    assert main(base) == 1
    assert "datum is undefined" in capsys.readouterr().err
    assert main(base + ["--bias-prior", "4"]) == 0, capsys.readouterr().err
    job = json.loads(Path("job.json").read_text())
    for im in job["images"]:
        assert im["model"]["name"] == "RPC-DRIFT"
        prior = im["bias_prior"]
        assert set(prior) == {"a0", "a_line", "b0", "b_line"}
        assert prior["a0"] == {"value": 0.0, "sigma": 4.0} and prior["b0"] == {"value": 0.0, "sigma": 4.0}
        lines = 2 * im["rpc"]["line_scale"]
        # the drift's prior moves the image's last line by the same 4 px
        assert prior["a_line"]["sigma"] * lines == pytest.approx(4.0, rel=1e-12)
        assert prior["b_line"]["sigma"] * lines == pytest.approx(4.0, rel=1e-12)
    assert main(base + ["--bias-prior", "0"]) == 2
    assert "positive number of pixels" in capsys.readouterr().err


def test_a_vendor_job_survives_job_sources(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A job composed from a real WorldView-2 support file (its ephemeris, first line time and
    the delivered attitude as its base) with five control points measured by the file's RPC:
    written as source files and composed again by ``pba job``, it is a valid job again with the
    same first line time and the base sample for sample (1e-9 degrees: the table's text form)."""
    from utils.vendor_control import WORLDVIEW as sensor
    from utils.vendor_control import write_rpc_control

    from solver.importers.export import write_sources

    write_rpc_control(sensor, tmp_path, "W")
    first = tmp_path / "first.json"
    assert main(["job", "--sensor", f"W={sensor}", "--image", f"W={tmp_path / 'W.csv'}", "--gcps", str(tmp_path / "gcps.csv"),
                 "--crs", "EPSG:4979", "-o", str(first)]) == 0
    job = json.loads(first.read_text())
    im = job["images"][0]
    assert len(im["attitude_base"]) > 10 and "approx_state" not in im
    out = tmp_path / "src"
    args = write_sources(job, out)
    assert "--attitude-base" in args and "--first-line-time" in args
    monkeypatch.chdir(out)
    assert main(["job", *args, "-o", str(tmp_path / "again.json")]) == 0  # valid again
    again = json.loads((tmp_path / "again.json").read_text())["images"][0]
    assert again["first_line_time_s"] == pytest.approx(im["first_line_time_s"], abs=1e-9)
    assert len(again["attitude_base"]) == len(im["attitude_base"])
    for a, b in zip(again["attitude_base"], im["attitude_base"]):
        for k in ("time_s", "roll_deg", "pitch_deg", "yaw_deg"):
            assert a[k] == pytest.approx(b[k], abs=1e-9), (k, a, b)
    assert len(again["attitude"]) == len(im["attitude"])
