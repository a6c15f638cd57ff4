"""``pba match`` (solver/matching/) against simulated truth: a backward / nadir / forward triplet
(20 m GSD, 480 x 480 pixels, terrain 200-1200 m, so the views differ by up to ~20 px of relief
parallax) rendered with the simulator's rich texture (a random ground texture, per-view gain,
offset and noise, 16-bit: ``pba simulate --raster-texture rich``).

Truth of a matched tie point: the ground point of its reference pixel (the first image's
measurement, an integer pixel) on the true terrain, projected with the true geometry into the
other images (solver/simulate, independent of the matching and of the adjustment).
"""

from __future__ import annotations

import copy
import csv
import json
import shutil

import numpy as np
import pytest
import rasterio

from solver import api
from solver.cli import main
from solver.geometry.rpc import RpcBias
from solver.gis.rpc_io import write_sidecar
from solver.importers.measurements_csv import read_measurements
from solver.raster_gate import create_raster
from solver.simulate.camera import simple_camera
from solver.simulate.raster import render_image
from solver.simulate.rpc import fit_image_rpc
from solver.simulate.scene import Group, Scene, SceneSettings

pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")]

SIZE_PX = 480
TRUTH_RMS_PX = 0.2  # the done-when bound on matched positions before adjustment (radial RMS)
BLUNDER_PX = 1.0  # no kept measurement may be wrong by more than this after data snooping
CHECK_RMSE_RATIO = 1.10  # check-point RMSE with matched ties within 10% of that with exact ties
GRID = ["--grid", "5", "--per-cell", "4"]


@pytest.fixture(scope="module")
def triplet(tmp_path_factory):
    d = tmp_path_factory.mktemp("match")
    cams = [simple_camera(n, 520.0, 0.013, 0.00292, SIZE_PX, SIZE_PX, p) for n, p in (("back", -20.0), ("nadir", 0.0), ("fwd", 20.0))]
    settings = SceneSettings(preset="match-test", seed=3, name="match", model="J2-2", noise_px=0.05, terrain_min_m=200.0, terrain_max_m=1200.0)
    scene = Scene(settings, [Group(cams, 8, 8, 30)]).simulate()
    job = scene.job()
    (d / "sim.json").write_text(json.dumps(job))
    paths = []
    for i, g in enumerate(scene.images):
        data = render_image(scene, i, texture="rich", seed=3)
        path = d / f"sim.{g.id}.tif"
        with rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1, dtype=data.dtype.name) as dst:
            dst.write(data, 1)
        paths.append(path)
    return scene, job, d, paths


def _truth_errors(scene, measurements) -> dict[tuple[str, str], np.ndarray]:
    """{(reference image, other image): (n, 2) measured - true (line, column)} of every tie point."""
    ids = [g.id for g in scene.images]
    by_point: dict[str, list[dict]] = {}
    for m in measurements:
        by_point.setdefault(m["point"], []).append(m)
    out: dict[tuple[str, str], list] = {}
    for ms in by_point.values():
        ms = sorted(ms, key=lambda m: ids.index(m["image"]))
        ref = ms[0]
        ground = scene.images[ids.index(ref["image"])].image_to_ground(np.array([ref["line"]]), np.array([ref["column"]]), terrain=scene.terrain)
        for m in ms[1:]:
            pr = scene.images[ids.index(m["image"])].ground_to_image(ground)
            out.setdefault((ref["image"], m["image"]), []).append((m["line"] - pr.line[0], m["column"] - pr.column[0]))
    return {k: np.array(v) for k, v in out.items()}


@pytest.fixture(scope="module")
def matched(triplet):
    scene, job, d, paths = triplet
    out, summary = d / "ties.csv", d / "summary.json"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("PBA_MATCH_THREADS", "2")  # detection ahead in a second thread (test_deterministic_output: the same with one)
        assert main(["match", *map(str, paths), "--job", str(d / "sim.json"), "-o", str(out), "--summary", str(summary), "-q", *GRID]) == 0
    measurements = read_measurements(out.read_text(), "ties.csv")  # the importers read what we write
    return measurements, json.loads(summary.read_text()), out


def test_matched_ties_are_within_0_2_px_of_the_truth(triplet, matched):
    scene, *_ = triplet
    measurements, summary, _ = matched
    errors = _truth_errors(scene, measurements)
    assert set(errors) >= {("back", "nadir"), ("back", "fwd")}
    for pair, e in errors.items():
        rms = float(np.sqrt(np.mean(np.sum(e**2, axis=1))))
        assert rms < TRUTH_RMS_PX, (pair, rms)
    # every image carries points over most of its cells, most points are in three images
    assert summary["tie_points"] >= 60
    assert summary["images_per_tie_point"].get("3", 0) >= 0.8 * summary["tie_points"]
    assert all(im["cells_covered"] >= 0.6 for im in summary["images"])
    # the 3-D check of the three-image points: the simulator's views have no orientation error
    # (bias well under the 0.2 px accuracy) and it removes few measurements
    assert all(abs(b) < 0.2 for im in summary["images"] for b in im["bias_px"]), summary["images"]
    assert sum(im["removed_3d"] for im in summary["images"]) <= 0.05 * summary["measurements"]
    all_errors = np.vstack(list(errors.values()))
    print("largest truth error (px):", float(np.max(np.hypot(all_errors[:, 0], all_errors[:, 1]))))
    # the stated precision is that of the errors, within a factor 2 (the reference image's
    # measurement is the defining pixel: its sigma is the floor)
    for (ref, other), e in errors.items():
        row = next((p for p in summary["pairs"] if p["images"] == [ref, other]), None)
        if row and row["sigma_px"] and len(e) > 30:
            rms_1d = float(np.sqrt(np.mean(e**2)))
            assert 0.5 * rms_1d < row["sigma_px"] < 2.0 * rms_1d, (ref, other, row["sigma_px"], rms_1d)


def test_deterministic_output(triplet, matched, monkeypatch):
    """The same ties CSV again, and with the detection in one thread (the fixture's detects
    ahead in a second: PBA_MATCH_THREADS=2)."""
    _scene, _job, d, paths = triplet
    _m, _s, first = matched
    again = d / "again.csv"
    monkeypatch.setenv("PBA_MATCH_THREADS", "1")
    assert main(["match", *map(str, paths), "--job", str(d / "sim.json"), "-o", str(again), "-q", *GRID]) == 0
    assert again.read_text() == first.read_text()


def _with_ties(job: dict, measurements: list[dict], snooping: bool) -> dict:
    """The simulated job with its tie points replaced by ``measurements``."""
    out = copy.deepcopy(job)
    ties = {p["id"] for p in out["points"] if p["role"] == "tie"}
    out["points"] = [p for p in out["points"] if p["role"] != "tie"]
    out["points"] += [{"id": pid, "role": "tie"} for pid in sorted({m["point"] for m in measurements})]
    out["observations"] = [o for o in out["observations"] if o["point"] not in ties] + measurements
    if snooping:
        out["options"] = {"blunder_detection": {}}
    return out


def _rmse_3d(report: dict) -> float:
    r = report["checkpoints"]["rmse_m"]
    return float(np.sqrt(r["e"] ** 2 + r["n"] ** 2 + r["u"] ** 2))


def test_adjustment_with_matched_ties(triplet, matched):
    """The matched ties orient the block as well as the simulator's exact ones (check points),
    and data snooping removes measurements shifted by 3 px, leaving none wrong by > 1 px."""
    scene, job, *_ = triplet
    measurements, *_ = matched
    exact = _rmse_3d(api.run(job))
    with_matched = _rmse_3d(api.run(_with_ties(job, measurements, False)))
    assert with_matched <= CHECK_RMSE_RATIO * exact, (with_matched, exact)

    # blunders: five measurements of the third image of three-image points shifted by 3 px
    # (a shift along the epipolar line of a two-image point is absorbed by its height: no test
    # can see it; three rays can)
    spoiled = copy.deepcopy(measurements)
    n_images = {}
    for m in spoiled:
        n_images[m["point"]] = n_images.get(m["point"], 0) + 1
    shifted = [m for m in spoiled if m["image"] == "fwd" and n_images[m["point"]] == 3][::17][:5]
    for m in shifted:
        m["line"] += 3.0
        m["column"] += 1.0
    report = api.run(_with_ties(job, spoiled, True))
    rejected = {(o["image"], o["point"]) for o in report["observations"] if o.get("rejected")}
    assert len(shifted) == 5 and {m["point"] for m in shifted} <= {p for _i, p in rejected}
    kept = [m for m in spoiled if (m["image"], m["point"]) not in rejected]
    errors = np.vstack(list(_truth_errors(scene, kept).values()))
    assert np.max(np.hypot(errors[:, 0], errors[:, 1])) < BLUNDER_PX


@pytest.fixture(scope="module")
def rpc_pair(triplet, tmp_path_factory):
    """The backward and forward rasters with RPC sidecars fitted to the true geometry (no job)."""
    scene, _job, d, paths = triplet
    e = tmp_path_factory.mktemp("rpc")
    out = []
    for i in (0, 2):
        dst = e / f"{scene.images[i].id}.tif"
        shutil.copyfile(paths[i], dst)
        rpc = fit_image_rpc(scene.images[i], RpcBias(), (100.0, 1300.0))
        write_sidecar(rpc, e / f"{scene.images[i].id}_RPC.TXT")
        out.append(dst)
    return scene, e, out


def test_images_with_rpcs_need_no_job(rpc_pair):
    scene, e, paths = rpc_pair
    out = e / "ties.csv"
    assert main(["match", *map(str, paths), "-o", str(out), "-q", "--heights", "100,1300", *GRID]) == 0
    rows = list(csv.DictReader(out.open()))
    assert {r["image"] for r in rows} == {"back", "fwd"}
    errors = _truth_errors(scene, [{**r, "line": float(r["line"]), "column": float(r["column"])} for r in rows])
    e_bf = errors[("back", "fwd")]
    assert float(np.sqrt(np.mean(np.sum(e_bf**2, axis=1)))) < TRUTH_RMS_PX


def test_default_heights_reach_terrain_far_from_the_rpc_height_offset(triplet, tmp_path):
    """RPCs fitted over -1,800 to 1,300 m (height offset -250 m, scale 1,550 m) of a terrain at
    200-1,200 m, near the top of their range (as a vendor's RPC of a high plateau can be): with
    no --heights the matching searches the RPCs' whole range and every overlapping tile, and
    finds ties over the whole overlap, as accurate as with the terrain's own range."""
    scene, _job, _d, paths = triplet
    out = []
    for i in (0, 2):
        dst = tmp_path / f"{scene.images[i].id}.tif"
        shutil.copyfile(paths[i], dst)
        write_sidecar(fit_image_rpc(scene.images[i], RpcBias(), (-1800.0, 1300.0)), tmp_path / f"{scene.images[i].id}_RPC.TXT")
        out.append(dst)
    ties, summary = tmp_path / "ties.csv", tmp_path / "summary.json"
    assert main(["match", *map(str, out), "-o", str(ties), "--summary", str(summary), "-q", *GRID]) == 0
    s = json.loads(summary.read_text())
    assert s["height_range_m"][0] <= -1799.0 and s["height_range_m"][1] >= 1299.0
    assert all(im["cells_covered"] >= 0.6 for im in s["images"]), s["images"]
    rows = list(csv.DictReader(ties.open()))
    errors = _truth_errors(scene, [{**r, "line": float(r["line"]), "column": float(r["column"])} for r in rows])
    e_bf = errors[("back", "fwd")]
    assert len(e_bf) >= 60
    assert float(np.sqrt(np.mean(np.sum(e_bf**2, axis=1)))) < TRUTH_RMS_PX


def _fails(argv, capsys, *words):
    assert main(argv) == 2
    err = capsys.readouterr().err
    for w in words:
        assert w in err, err


def test_bad_rasters_exit_2(triplet, rpc_pair, tmp_path, capsys):
    _scene, _job, d, paths = triplet
    job = str(d / "sim.json")
    out = str(tmp_path / "t.csv")
    # truncated: the header is there, half of the pixels are not
    cut = tmp_path / "sim.back.tif"
    data = paths[0].read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    _fails(["match", str(cut), str(paths[1]), "--job", job, "-o", out, "-q"], capsys, "sim.back.tif")
    # absurd size (a sparse GeoTIFF header claiming 2,000,000 columns)
    huge = tmp_path / "huge.tif"
    with create_raster(huge, driver="GTiff", width=2_000_000, height=10, count=1, dtype="uint8", tiled=True, sparse_ok=True):
        pass
    _fails(["match", f"back={huge}", str(paths[1]), "--job", job, "-o", out, "-q"], capsys, "2000000 x 10 pixels")
    # a VRT (a format naming other files: never opened)
    vrt = tmp_path / "huge.vrt"
    vrt.write_text(f'<VRTDataset rasterXSize="500" rasterYSize="10"><VRTRasterBand dataType="Byte" band="1"><SimpleSource><SourceFilename>{paths[1]}</SourceFilename></SimpleSource></VRTRasterBand></VRTDataset>')
    _fails(["match", f"back={vrt}", str(paths[1]), "--job", job, "-o", out, "-q"], capsys, "not a supported raster format")
    # not a raster
    txt = tmp_path / "notes.tif"
    txt.write_text("hello")
    _fails(["match", f"back={txt}", str(paths[1]), "--job", job, "-o", out, "-q"], capsys, "not a supported raster format")
    # a raster the job does not know
    _fails(["match", str(tmp_path / "other.tif"), str(paths[1]), "--job", job, "-o", out, "-q"], capsys, "which image")
    # no RPC and no job
    _fails(["match", *map(str, paths[:2]), "-o", out, "-q"], capsys, "no RPC")
    # no overlap: the second image's RPC moved one degree east
    _s, e, rpc_paths = rpc_pair
    far = tmp_path / "far"
    far.mkdir()
    for p in rpc_paths:
        shutil.copyfile(p, far / p.name)
        side = p.with_name(p.stem + "_RPC.TXT").read_text()
        if p.stem == "fwd":
            lines = [ln if not ln.startswith("LONG_OFF") else f"LONG_OFF: {float(ln.split()[1]) + 1.0} degrees" for ln in side.splitlines()]
            side = "\n".join(lines) + "\n"
        (far / (p.stem + "_RPC.TXT")).write_text(side)
    _fails(["match", str(far / "back.tif"), str(far / "fwd.tif"), "-o", out, "-q", "--heights", "100,1300"], capsys, "no two images overlap")


def test_failures_write_the_summary_and_say_what_to_try(triplet, rpc_pair, tmp_path, capsys):
    """Every outcome writes the summary; a failure names what to try; a raster too small to
    match is named as such (not as 'no overlap')."""
    _scene, _job, d, paths = triplet
    _s, e, rpc_paths = rpc_pair
    out, summary = str(tmp_path / "t.csv"), tmp_path / "summary.json"
    # 1 x 1 pixels
    tiny = tmp_path / "back.tif"
    with rasterio.open(tiny, "w", driver="GTiff", width=1, height=1, count=1, dtype="uint8") as dst:
        dst.write(np.zeros((1, 1), np.uint8), 1)
    _fails(["match", str(tiny), str(paths[1]), "--job", str(d / "sim.json"), "-o", out, "-q"], capsys, "back.tif", "1 x 1 pixels", "too small")
    # no overlap at any height: fwd's RPC one degree east; the summary lists the pairs tried
    far = tmp_path / "far"
    far.mkdir()
    for p in rpc_paths:
        shutil.copyfile(p, far / p.name)
        side = p.with_name(p.stem + "_RPC.TXT").read_text()
        if p.stem == "fwd":
            side = "\n".join(ln if not ln.startswith("LONG_OFF") else f"LONG_OFF: {float(ln.split()[1]) + 1.0} degrees" for ln in side.splitlines()) + "\n"
        (far / (p.stem + "_RPC.TXT")).write_text(side)
    _fails(["match", str(far / "back.tif"), str(far / "fwd.tif"), "-o", out, "--summary", str(summary), "-q"], capsys,
           "no two images overlap", "--heights", str(summary))
    s = json.loads(summary.read_text())
    assert s["tie_points"] == 0 and s["pairs"] == [] and len(s["pairs_tried"]) <= 1
    assert s["height_range_m"][0] <= 100.0 and s["height_range_m"][1] >= 1300.0  # the RPCs' whole range (fitted over 100-1300 m)
    # the same scene's geometry over noise: candidates in the band, no match; the summary says
    # where the features were lost and the message what to try
    noise = tmp_path / "noise"
    noise.mkdir()
    shutil.copyfile(rpc_paths[0], noise / "back.tif")
    shutil.copyfile(rpc_paths[0].with_name("back_RPC.TXT"), noise / "back_RPC.TXT")
    with rasterio.open(rpc_paths[1]) as src:
        shape, dtype = (src.height, src.width), src.dtypes[0]
    rng = np.random.default_rng(0)
    with rasterio.open(noise / "fwd.tif", "w", driver="GTiff", width=shape[1], height=shape[0], count=1, dtype=dtype) as dst:
        dst.write(rng.integers(1000, 3000, size=shape).astype(dtype), 1)
    shutil.copyfile(rpc_paths[1].with_name("fwd_RPC.TXT"), noise / "fwd_RPC.TXT")
    summary.unlink()
    _fails(["match", str(noise / "back.tif"), str(noise / "fwd.tif"), "-o", out, "--summary", str(summary), "-q", *GRID], capsys,
           "no tie point survived", "--search-px", str(summary))
    s = json.loads(summary.read_text())
    (pair,) = s["pairs"]
    assert pair["candidates"] > 0 and pair["tie_points"] == 0
    lost = pair["rejected"]
    assert sum(lost.values()) == pair["features"] - pair["matched"] + pair["removed_epipolar"]
    assert lost["ratio_test"] + lost["mutual_check"] + lost["ransac"] > 0


def test_job_match_adds_tie_points(triplet):
    """``pba job ... --match`` (its helper on a composed job): the matched tie points join the
    job as tie points with their measurements, ids clear of the job's own, and the job is valid."""
    from solver.api import validate
    from solver.importers.job_cli import add_matched_ties
    from solver.matching.features import MatchSettings
    from solver.schema.job import load_job

    _scene, job, d, paths = triplet
    composed = _with_ties(job, [], False)
    composed["points"].append({"id": "M00001", "role": "tie"})  # an id the matching would take
    composed["observations"] += [{"image": "back", "point": "M00001", "line": 10.0, "column": 10.0},
                                 {"image": "fwd", "point": "M00001", "line": 12.0, "column": 11.0}]
    summary = add_matched_ties(composed, [f"{p.name.split('.')[1]}={p}" for p in paths], MatchSettings(grid=5))
    ids = [p["id"] for p in composed["points"]]
    assert len(ids) == len(set(ids))
    matched = [o for o in composed["observations"] if o["point"].startswith("MM")]
    assert len(matched) == summary["measurements"] and summary["tie_points"] >= 60
    assert validate(load_job(composed))["valid"]
