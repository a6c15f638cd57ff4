"""``POST /jobs/compose`` and the sensor presets of the camera library, in process.

The example triplet's source files (examples/prism-triplet-sources: CSV, QGIS .points, ASP
.gcp, survey, state, ephemeris and attitude tables) uploaded as multipart give the example
job's content; a file problem is a 422 problem document naming file, line and column."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any, Iterator

import pytest
from fastapi.testclient import TestClient
from test_service_api import assert_problem, body, make_client

from solver.importers.presets import PRESETS, preset_camera

ROOT = Path(__file__).resolve().parents[3]
SOURCES = ROOT / "examples" / "prism-triplet-sources"
EXAMPLE = ROOT / "examples" / "prism-triplet.json"
IMAGES = ("prism-backward", "prism-nadir", "prism-forward")
PX_TOL = 1e-9  # px: QGIS's +-0.5 px shifts


@pytest.fixture
def local(tmp_path: Path) -> Iterator[TestClient]:
    with make_client(tmp_path) as c:
        yield c


def example_spec() -> dict[str, Any]:
    measurements = {
        "prism-backward": ["prism-backward.csv"],
        "prism-nadir": ["prism-nadir.points", "prism-nadir-ties.csv"],
        "prism-forward": ["prism-forward.gcp", "prism-forward-ties.csv"],
    }
    return {
        "name": "PRISM triplet, Presidente Prudente (simulated)",
        "crs": "EPSG:4326",
        "points": ["survey.csv"],
        "camera_files": ["cameras.json"],
        "models": ["K2"],
        "images": [
            {
                "id": i,
                "measurements": measurements[i],
                "state": f"{i}.state.csv",
                "ephemeris": f"{i}.ephemeris.csv",
                "attitude": f"{i}.attitude.csv",
            }
            for i in IMAGES
        ],
    }


def upload(c: TestClient, spec: dict[str, Any], files: dict[str, bytes]) -> Any:
    return c.post(
        "/jobs/compose",
        data={"spec": json.dumps(spec)},
        files=[("files", (name, data, "application/octet-stream")) for name, data in files.items()],
    )


def example_files() -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(SOURCES.iterdir())}


def test_compose_the_example_triplet_from_its_files(local: TestClient) -> None:
    r = upload(local, example_spec(), example_files())
    assert r.status_code == 200, r.text[:2000]
    doc = r.json()
    job, want = doc["job"], json.loads(EXAMPLE.read_text())
    assert {k: job[k] for k in ("name", "crs", "cameras", "images")} == {k: want[k] for k in ("name", "crs", "cameras", "images")}
    assert sorted(job["points"], key=lambda p: p["id"]) == sorted(want["points"], key=lambda p: p["id"])
    got = {(o["image"], o["point"]): o for o in job["observations"]}
    assert got.keys() == {(o["image"], o["point"]) for o in want["observations"]}
    for o in want["observations"]:
        g = got[(o["image"], o["point"])]
        assert abs(g["line"] - o["line"]) < PX_TOL and abs(g["column"] - o["column"]) < PX_TOL
    assert doc["validation"]["valid"] is True and doc["validation"]["dof"] == 219
    assert doc["summary"]["images"]["prism-nadir"] == {"gcp": 22, "check": 20, "tie": 40}
    assert any("tie points" in n for n in doc["notes"])
    # and the composed document is a job the server accepts
    assert local.post("/jobs/validate", json=body(job)).status_code == 200


def test_a_bad_file_is_a_problem_naming_file_line_column(local: TestClient) -> None:
    files = example_files()
    lines = files["prism-nadir.points"].decode().splitlines()
    lines[4] = lines[4].replace(",1,0,0,0", ",yes,0,0,0")  # the enable field of the third row
    files["prism-nadir.points"] = ("\n".join(lines) + "\n").encode()
    doc = assert_problem(upload(local, example_spec(), files), 422, "/files/prism-nadir.points")
    entry = doc["errors"][0]
    assert (entry["file"], entry["line"], entry["column"]) == ("prism-nadir.points", 5, "enable")


def test_spec_problems_point_into_the_spec(local: TestClient) -> None:
    spec = example_spec()
    spec["images"][1]["measurements"].append("missing.csv")
    assert_problem(upload(local, spec, example_files()), 422, "/spec/images/1/measurements/2")
    assert_problem(upload(local, {"images": []}, example_files()), 422, "/spec/images")
    r = local.post("/jobs/compose", data={"spec": "{not json"}, files=[("files", ("a.csv", b"x"))])
    assert_problem(r, 422)


def test_library_cameras_by_name_are_refs_resolved_for_the_checks(local: TestClient) -> None:
    """Without cameras.json the images name the presets: the job keeps refs to the shared
    versions, the checks see the resolved cameras."""
    spec = example_spec()
    spec["camera_files"] = []
    for im in spec["images"]:
        im["camera"] = im["id"]
    r = upload(local, spec, {k: v for k, v in example_files().items() if k != "cameras.json"})
    assert r.status_code == 200, r.text[:2000]
    cams = r.json()["job"]["cameras"]
    assert cams[1] == {"id": "prism-nadir", "ref": {"name": "shared/prism-nadir", "version": 1}}
    assert r.json()["validation"]["valid"] is True


def test_presets_are_shared_library_cameras_once(tmp_path: Path, triplet_doc: dict[str, Any]) -> None:
    for _ in range(2):  # a restart publishes nothing twice
        with make_client(tmp_path) as c:
            for name in PRESETS:
                got = c.get(f"/cameras/shared/{name}").json()
                assert got["version"] == 1 and got["shared"] is True
                want = {k: v for k, v in preset_camera(name).items() if k != "id"}
                assert {k: got["definition"][k] for k in want} == want
                assert c.get(f"/cameras/shared/{name}/versions").json()["numberMatched"] == 1
    with make_client(tmp_path) as c:
        job = copy.deepcopy(triplet_doc)
        job["cameras"] = job["cameras"][:2]
        job["images"][2]["camera"] = {"ref": {"name": "prism-forward"}}
        r = c.post("/jobs/validate", json=body(job))
        assert r.status_code == 200, r.text[:1000]


def test_hostile_uploads_are_4xx_never_500(local: TestClient) -> None:
    """NaN in the spec or a camera file, untransformable coordinates, duplicate columns."""
    obs = {"a.csv": b"point,line,column\nA,1,2\n"}
    image = [{"id": "N", "measurements": ["a.csv"], "camera": "prism-nadir"}]
    r = local.post("/jobs/compose", data={"spec": '{"images": [{"id": "N"}], "options": {"x": NaN}}'}, files=[("files", ("a.csv", b"x"))])
    assert_problem(r, 422, "/spec")
    cams = {**obs, "c.json": b'[{"id": "prism-nadir", "focal_mm": NaN}]'}
    assert_problem(upload(local, {"images": image, "camera_files": ["c.json"]}, cams), 422, "/files/c.json")
    bad = {"a.points": b"#CRS: EPSG:4326\nmapX,mapY,sourceX,sourceY\n1e300,1e300,1,-1\n", "s.csv": b"id,x,y,z\nA,1e300,1e300,1e300\n"}
    spec = {"images": [{"id": "N", "measurements": ["a.points"], "camera": "prism-nadir"}], "gcps": ["s.csv"]}
    assert_problem(upload(local, spec, bad), 422, "/files/a.points")
    r = upload(local, {"images": image, "camera": "hrsc"}, obs)
    assert r.status_code == 200 and r.json()["validation"]["valid"] is False  # the image's own camera wins
    r = upload(local, {"images": [{"id": "N", "measurements": ["a.csv"], "camera": "hrsc"}]}, obs)
    assert_problem(r, 422, "/spec/camera")
    r = upload(local, {"images": image}, {"a.csv": b"point,line,column,row\nA,1,2,3\n"})
    doc = assert_problem(r, 422, "/files/a.csv")
    assert (doc["errors"][0]["line"], doc["errors"][0]["column"]) == (1, "row")


def test_compose_rpc_images_from_uploaded_rpc_files(local: TestClient, tmp_path: Path) -> None:
    """An all-RPC triplet of the simulator written as source files (measurements, survey, each
    image's NAME_RPC.TXT) and uploaded: a valid job of RPC images (no cameras) with the spec's
    bias model and one image's own; a bad RPC file is a 422 naming it."""
    from solver.importers.export import write_sources
    from solver.simulate import presets
    from solver.simulate.rpc import RpcSettings
    from solver.simulate.scene import SceneSettings

    s = SceneSettings(preset="prism-triplet", seed=4, rpc=RpcSettings("RPC-SHIFT", {"a0": 5.0, "b0": 3.0}))
    job = presets.prism_triplet(s, gcps=6, checks=4, tie_points=12).job()
    write_sources(job, tmp_path)
    files = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    ids = [im["id"] for im in job["images"]]
    spec = {
        "crs": job["crs"], "points": ["survey.csv"], "rpc_model": "RPC-SHIFT",
        "images": [{"id": i, "measurements": [f"{i}.csv"], "rpc": f"{i}_RPC.TXT"} for i in ids],
    }
    spec["images"][1]["rpc_model"] = "RPC-DRIFT"
    r = upload(local, spec, files)
    assert r.status_code == 200, r.text[:2000]
    doc = r.json()
    assert doc["validation"]["valid"] is True, doc["validation"]
    assert doc["job"]["cameras"] == []
    assert [im["model"]["name"] for im in doc["job"]["images"]] == ["RPC-SHIFT", "RPC-DRIFT", "RPC-SHIFT"]
    assert all(set(im) == {"id", "rpc", "model"} for im in doc["job"]["images"])
    files[f"{ids[0]}_RPC.TXT"] = b"LINE_OFF: 12\n"
    assert_problem(upload(local, spec, files), 422, f"/files/{ids[0]}_RPC.TXT")
    raster = {**files, "scene.tif": b"II*\x00" + bytes(64)}  # uploads are read in the server's process: sidecars only
    raster_spec = {**spec, "images": [{**spec["images"][0], "rpc": "scene.tif"}, *spec["images"][1:]]}
    doc = assert_problem(upload(local, raster_spec, raster), 422, "/files/scene.tif")
    assert doc["errors"][0]["code"] == "not_an_rpc_file"
    spec["images"][2]["rpc"] = "missing_RPC.TXT"
    files[f"{ids[0]}_RPC.TXT"] = (tmp_path / f"{ids[0]}_RPC.TXT").read_bytes()
    assert_problem(upload(local, spec, files), 422, "/spec/images/2/rpc")


def test_compose_images_from_uploaded_sensor_metadata(local: TestClient) -> None:
    """Vendor metadata uploaded as an image's ``sensor`` file (a real WorldView-2 XML and a
    simulated SPOT 6 DIMAP v2): cameras, ephemeris, attitude and model come from it, as with
    ``pba job --sensor``; a hostile or damaged file is a 422 naming the file and the element."""
    import numpy as np
    from simulated_dimap import Scene, dimap_v2_xml

    from solver.sensors.maxar import read_maxar

    wv = ROOT / "tests" / "data" / "vendor" / "stereopipeline" / "wv_mvp_1.xml"
    r = read_maxar(wv).rpc
    ground = np.column_stack([r.long_off + 0.2 * r.long_scale * np.array([-1, 0, 1, 0.5]),
                              r.lat_off + 0.2 * r.lat_scale * np.array([0, 1, -1, 0.5]), np.full(4, r.height_off)])
    lc = np.column_stack(r.project(ground[:, 0], ground[:, 1], ground[:, 2]))
    files = {
        "wv.xml": wv.read_bytes(),
        "DIM_SPOT6.XML": dimap_v2_xml(Scene())[0].encode(),
        "wv.csv": ("point,line,column\n" + "".join(f"G{k},{x[0]:.3f},{x[1]:.3f}\n" for k, x in enumerate(lc))).encode(),
        "s6.csv": b"point,line,column\nG0,100.0,200.0\n",
        "gcps.csv": ("id,lon,lat,z\n" + "".join(f"G{k},{g[0]:.9f},{g[1]:.9f},{g[2]:.3f}\n" for k, g in enumerate(ground))).encode(),
    }
    spec = {"crs": "EPSG:4979", "gcps": ["gcps.csv"],
            "images": [{"id": "WV", "measurements": ["wv.csv"], "sensor": "wv.xml"},
                       {"id": "S6", "measurements": ["s6.csv"], "sensor": "DIM_SPOT6.XML"}]}
    res = upload(local, spec, files)
    assert res.status_code == 200, res.text[:2000]
    job = res.json()["job"]
    assert [c["id"] for c in job["cameras"]] == ["WV", "S6"]
    assert [i["model"]["name"] for i in job["images"]] == ["OA-J2", "OA-J2"]
    assert all(i["ephemeris"] and i["attitude"] for i in job["images"])
    bomb = b'<?xml version="1.0"?><!DOCTYPE d [<!ENTITY a "aaaa"><!ENTITY b "&a;&a;&a;">]><Dimap_Document>&b;</Dimap_Document>'
    for bad, element in ((bomb, ""), (files["DIM_SPOT6.XML"].replace(b"<NCOLS>2500</NCOLS>", b"<NCOLS>x</NCOLS>"), "NCOLS")):
        doc = assert_problem(upload(local, spec, {**files, "DIM_SPOT6.XML": bad}), 422, "/files/DIM_SPOT6.XML")
        assert "DIM_SPOT6.XML" in json.dumps(doc) and element in json.dumps(doc), doc


def test_an_orthorectified_inpe_record_is_refused_with_the_reason(local: TestClient) -> None:
    """A level 4 (orthorectified) CBERS-4A record describes the raw acquisition, while its raster
    is a UTM map grid: measurements in that raster are no pushbroom lines and columns, so the
    server refuses to compose a rigorous job from it (422) and says why, naming the file."""
    f = ROOT / "tests" / "data" / "vendor" / "cbers-2-stac" / "CBERS_4A_MUX_20220810_222_116_L4_BAND6.xml"
    spec = {"images": [{"id": "M", "measurements": ["m.csv"], "sensor": f.name}]}
    doc = assert_problem(upload(local, spec, {f.name: f.read_bytes(), "m.csv": b"point,line,column\nG0,100,100\n"}), 422)
    assert f.name in doc["detail"] and "level 4 (orthorectified)" in doc["detail"] and "UTM map grid" in doc["detail"], doc
    assert doc["errors"][0]["code"] == "bad_sensor_metadata", doc


def test_a_sensor_metadata_upload_is_bounded_by_its_bytes(local: TestClient) -> None:
    """A metadata file is not counted in rows (a SPOT 5 scene's DIMAP has 25,000 lines) but
    bounded by bytes: above MAX_SENSOR_BYTES it is refused before it is parsed (413)."""
    from service.compose import MAX_SENSOR_BYTES

    spec = {"images": [{"id": "S", "measurements": ["s.csv"], "sensor": "METADATA.DIM"}]}
    big = b"<Dimap_Document>" + b" " * MAX_SENSOR_BYTES + b"</Dimap_Document>"
    doc = assert_problem(upload(local, spec, {"METADATA.DIM": big, "s.csv": b"point,line,column\nG0,1,1\n"}), 413)
    assert "METADATA.DIM" in doc["detail"] and str(MAX_SENSOR_BYTES) in doc["detail"], doc


# -- one specification: the wire spec is the solver's ComposeRequest ------------------------
def test_the_spec_carries_every_field_of_the_solvers_request() -> None:
    """Every field of ComposeRequest and ImageSources (but those the server does not take
    from uploads) is a field of the spec under its own name, and a spec setting each to a
    value other than its default reaches the solver's request with that value."""
    from dataclasses import fields

    from service.compose import NOT_UPLOADED, ComposeSpec, ImageSpec, _request, parse_spec
    from solver.importers.compose import ComposeRequest, ImageSources, SourceFile

    assert {f.name for f in fields(ComposeRequest)} <= set(ComposeSpec.model_fields) | NOT_UPLOADED
    assert {f.name for f in fields(ImageSources)} - NOT_UPLOADED == set(ImageSpec.model_fields)
    image = {
        "id": "A", "measurements": ["m.csv"], "camera": "cam", "ephemeris": "e.csv", "attitude": "a.csv",
        "attitude_base": "ab.csv", "state": "s.csv", "first_line_time_s": 12.5, "rpc": "r_RPC.TXT", "rpc_model": "RPC-SHIFT", "sensor": "DIM_A.XML",
    }
    spec = {
        "images": [image], "gcps": ["g.csv"], "checks": ["c.csv"], "points": ["p.csv"], "asp_gcp": ["x.gcp"],
        "camera_files": ["cams.json"], "camera": "default-cam", "crs": "EPSG:32722", "models": ["K1", "K2"],
        "rpc_model": "RPC-AFFINE", "options": {"covariance": False}, "name": "n", "time_scale": "UTC",
        "sigma_px": 0.3, "match_tolerance_m": 2.0, "bias_prior_px": 4.0,
        "dem": "dem.tif", "dem_sigma_m": 3.0, "dem_vertical": "egm96", "map_crs": "EPSG:4326", "columns": {"g.csv": {"E": "x"}},
        "measurements": ["ties.csv"],
    }
    names = [*image["measurements"], *(image[k] for k in ("ephemeris", "attitude", "attitude_base", "state", "rpc", "sensor"))]
    names += [n for k in ("gcps", "checks", "points", "asp_gcp", "camera_files", "measurements") for n in spec[k]]
    names.append(spec["dem"])
    uploads = {n: n.encode() for n in names}
    req = _request(parse_spec(json.dumps(spec)), uploads)
    for f in fields(ComposeRequest):
        if f.name in NOT_UPLOADED or f.name == "images":
            continue
        value = getattr(req, f.name)
        if isinstance(value, list) and value and isinstance(value[0], SourceFile):
            value = [v.name for v in value]
        elif isinstance(value, SourceFile):  # a single file of the request (the DEM)
            value = value.name
        assert value == spec[f.name], f.name
    (got,) = req.images
    for f in fields(ImageSources):
        if f.name in NOT_UPLOADED:
            continue
        value = getattr(got, f.name)
        if isinstance(value, SourceFile):
            value = value.name
        elif isinstance(value, list):
            value = [v.name for v in value]
        assert value == image[f.name], f.name
    assert req.gcps[0].columns == {"E": "x"} and req.gcps[0].data == b"g.csv"
