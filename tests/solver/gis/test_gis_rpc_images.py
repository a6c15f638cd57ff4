"""Refined RPC of an RPC image (issue 17, item 4), checked through GDAL: the RPC that
``pba export-rpc`` writes for an adjusted RPC image, read by GDAL's RPC transformer, reproduces
the adjusted model — the delivered RPC (evaluated by GDAL too) plus the report's bias
``a0 .. b_column`` by the contract's equations, solved here per point with numpy — within
0.01 px RMS (the issue's criterion) and 0.05 px at most, for a bias that folds into the RPC
(RPC-SHIFT, or any bias without the cross terms a_column and b_line: exact) and those that do
not (RPC-DRIFT's b_line, RPC-AFFINE: refitted).

The RPCs are the simulator's (``pba simulate --rpc-model``: fitted to the true geometry of a
PRISM-like ideal image and a CBERS-like raw image, plus a known bias), so the chain "true bias
in the report -> refined RPC through GDAL = the simulated noise-free measurements" is checked
as well. Until the job schema has ``images[].rpc`` (the engine half of issue 17) the adjusted
image is built from the job's image entry and a report entry made here with the contract's
parameter names; the end-to-end test through ``pba run`` runs once the schema has it.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from tolerances import ROUND_TRIP_PX

from solver.cli import main
from solver.geometry.rpc import RPC, RpcBias
from solver.gis.rpc_image import RpcImage, refined_rpc, rpc_image
from solver.gis.rpc_io import gdal_ground_to_image, gdal_rpc, write_sidecar
from solver.schema.job import Image

SURFACE_HEIGHT_M = 1e-4  # image_to_ground on a height function lands on it: the intersection's tolerance
FOLDED_BIAS_PX = 1e-8  # the bias folded into the RPC's offsets and scales is exact: rounding only

PROPAGATED_SIGMA_REL = 1e-6  # sigmas propagated through the bias by the module vs by hand: finite differences of the RPC

pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")

GDAL_CORNER_PX = 0.5
RMS_TOL_PX = 0.01
MAX_TOL_PX = 0.05
TRUE_BIAS = {"a0": 20.0, "a_line": 1e-4, "a_column": -3e-5, "b0": -12.0, "b_line": 2e-5, "b_column": 5e-5}
# adjusted biases as a report would carry them (contract names; absent ones 0)
REPORTS = {
    "RPC-SHIFT": {"a0": 19.6, "b0": -12.3},
    "RPC-DRIFT": {"a0": 19.6, "a_line": 1.2e-4, "b0": -12.3, "b_line": -4e-5},
    "RPC-AFFINE": {"a0": 19.6, "a_line": 1.2e-4, "a_column": -2.5e-5, "b0": -12.3, "b_line": 2.5e-5, "b_column": 4e-5},
}
HEIGHTS = (250.0, 650.0)


@pytest.fixture(scope="module", params=["prism-single", "cbers-scene"])
def simulated(request, tmp_path_factory):
    d = tmp_path_factory.mktemp(request.param)
    out = d / "job.json"
    bias = ",".join(f"{k}={v}" for k, v in TRUE_BIAS.items())
    assert main(["simulate", request.param, "-o", str(out), "--seed", "9", "--rpc-model", "RPC-AFFINE", "--rpc-bias", bias]) == 0
    return json.loads(out.read_text()), json.loads((d / "job.truth.json").read_text())


def _report_entry(image_id: str, values: dict[str, float]) -> dict:
    return {"id": image_id, "parameters": [{"name": k, "value": v, "sigma": 0.1, "unit": "px" if k in ("a0", "b0") else "px/px"} for k, v in values.items()]}


def _gdal_file_rpc(rpc: RPC, tmp_path, name: str):
    """The RPC as GDAL reads it from the sidecar beside a raster (the exported file)."""
    with rasterio.open(tmp_path / f"{name}.tif", "w", driver="GTiff", width=8, height=8, count=1, dtype="uint8") as dst:
        dst.write(np.zeros((1, 8, 8), np.uint8))
    write_sidecar(rpc, tmp_path / f"{name}_RPC.TXT")
    with rasterio.open(tmp_path / f"{name}.tif") as src:
        assert src.rpcs is not None
        return src.rpcs


def _contract_model(delivered_gdal, values: dict[str, float], lon, lat, h):
    """The adjusted model by the contract's equations: GDAL's delivered RPC (our convention),
    then per point the 2 x 2 system of line_obs, column_obs."""
    rl, rc = gdal_ground_to_image(delivered_gdal, lon, lat, h)
    rl, rc = rl - GDAL_CORNER_PX, rc - GDAL_CORNER_PX
    b = {k: values.get(k, 0.0) for k in TRUE_BIAS}
    m = np.array([[1 - b["a_line"], -b["a_column"]], [-b["b_line"], 1 - b["b_column"]]])
    rhs = np.column_stack([rl + b["a0"], rc + b["b0"]])
    sol = np.linalg.solve(m, rhs.T).T
    return sol[:, 0], sol[:, 1]


def _ground_sample(rpc: RPC, n=400, seed=11):
    rng = np.random.default_rng(seed)
    lon = rpc.long_off + rpc.long_scale * rng.uniform(-0.8, 0.8, n)
    lat = rpc.lat_off + rpc.lat_scale * rng.uniform(-0.8, 0.8, n)
    h = rng.uniform(*HEIGHTS, n)
    return lon, lat, h


@pytest.mark.parametrize("model", list(REPORTS))
def test_refined_rpc_through_gdal_reproduces_the_adjusted_model(simulated, tmp_path, model) -> None:
    job, _ = simulated
    entry = {**job["images"][0], "model": {"name": model}}
    image = rpc_image(entry, _report_entry(entry["id"], REPORTS[model]))
    refined = refined_rpc(image, HEIGHTS)
    assert refined.fit["method"] == ("folded" if model == "RPC-SHIFT" else "refit")  # b_line, a_column: cross terms
    assert refined.fit["check_residuals"]["rms_px"] < RMS_TOL_PX
    delivered = RPC.from_job(entry["rpc"])
    lon, lat, h = _ground_sample(delivered)
    want_l, want_c = _contract_model(gdal_rpc(delivered), REPORTS[model], lon, lat, h)
    rows, cols = gdal_ground_to_image(_gdal_file_rpc(refined, tmp_path, "refined"), lon, lat, h)
    err = np.hypot(rows - GDAL_CORNER_PX - want_l, cols - GDAL_CORNER_PX - want_c)
    assert np.sqrt(np.mean(err**2)) < RMS_TOL_PX and np.max(err) < MAX_TOL_PX, (np.sqrt(np.mean(err**2)), np.max(err))
    # the bias matters: the delivered RPC alone is tens of pixels off
    dl, dc = gdal_ground_to_image(gdal_rpc(delivered), lon, lat, h)
    assert np.min(np.hypot(dl - GDAL_CORNER_PX - want_l, dc - GDAL_CORNER_PX - want_c)) > 5.0


@pytest.mark.parametrize("model", ["RPC-SHIFT", "RPC-AFFINE"])
def test_the_refined_rpcs_check_grid_shares_no_point_with_its_fit_grid(simulated, monkeypatch, model) -> None:
    """The refined RPC's check residuals (its record's ``check_residuals``) assess it on points
    it was not fitted to, folded or refitted (tests/solver/gis/rpc_grids.py)."""
    from rpc_grids import assert_independent, spy_grids

    from solver.gis import rpc_image as module

    grids = spy_grids(monkeypatch, module)
    job, _ = simulated
    entry = {**job["images"][0], "model": {"name": model}}
    refined_rpc(rpc_image(entry, _report_entry(entry["id"], REPORTS[model])), HEIGHTS)
    assert_independent(grids["fit"], grids["check"])


def test_true_bias_gives_a_refined_rpc_that_hits_the_simulated_truth(simulated, tmp_path) -> None:
    """Report = the simulator's true bias: GDAL on the refined RPC gives the truth file's
    noise-free measurements (the exact projection of the simulated image)."""
    job, truth = simulated
    entry = job["images"][0]
    (rec,) = truth["rpc_images"]
    refined = refined_rpc(rpc_image(entry, _report_entry(entry["id"], rec["bias"])), HEIGHTS)
    pts = {p["id"]: p for p in truth["points"]}
    obs = truth["observations"]
    lon, lat, h = (np.array([pts[o["point"]][k] for o in obs]) for k in ("lon_deg", "lat_deg", "height_m"))
    rows, cols = gdal_ground_to_image(_gdal_file_rpc(refined, tmp_path, "truth"), lon, lat, h)
    err = np.hypot(rows - GDAL_CORNER_PX - np.array([o["line"] for o in obs]), cols - GDAL_CORNER_PX - np.array([o["column"] for o in obs]))
    assert np.max(err) < RMS_TOL_PX, err


def test_image_to_ground_inverts_ground_to_image(simulated) -> None:
    """The iteration (image to ground, at a height or on a surface) against the explicit
    forward model, to 1e-6 px and 1e-4 m."""
    job, _ = simulated
    image = rpc_image(job["images"][0], _report_entry(job["images"][0]["id"], REPORTS["RPC-AFFINE"]))
    assert isinstance(image, RpcImage)
    rng = np.random.default_rng(3)
    line = rng.uniform(*image.line_range, 200)
    col = rng.uniform(*image.column_range, 200)
    ecef = image.image_to_ground(line, col, height_m=rng.uniform(*HEIGHTS, 200))
    l2, c2, chip = image.ground_to_image(ecef)
    assert np.max(np.abs(l2 - line)) < ROUND_TRIP_PX and np.max(np.abs(c2 - col)) < ROUND_TRIP_PX and np.all(chip == 0)

    def surface(lon, lat):
        return 400.0 + 3000.0 * (lon - image.rpc.long_off) - 2000.0 * (lat - image.rpc.lat_off)

    from solver.geometry.geodesy import ecef_to_geodetic

    llh = ecef_to_geodetic(image.image_to_ground(line, col, height_fn=surface))
    assert np.max(np.abs(llh[:, 2] - surface(llh[:, 0], llh[:, 1]))) < SURFACE_HEIGHT_M
    l3, c3, _ = image.ground_to_image(image.image_to_ground(line, col, height_fn=surface))
    assert np.max(np.abs(l3 - line)) < ROUND_TRIP_PX and np.max(np.abs(c3 - col)) < ROUND_TRIP_PX


def test_bias_folding_is_exact_where_it_applies() -> None:
    """Folding a0, a_line (b0, b_column) into offsets and scales equals the 2 x 2 solve."""
    rng = np.random.default_rng(5)
    rpc = RPC(5000.0, 7000.0, -22.0, -51.0, 400.0, 5000.0, 7000.0, 0.1, 0.1, 500.0,
              rng.normal(0, 0.1, 20), np.r_[1.0, rng.normal(0, 1e-3, 19)], rng.normal(0, 0.1, 20), np.r_[1.0, rng.normal(0, 1e-3, 19)])
    bias = RpcBias(a0=3.0, a_line=2e-4, b0=-4.0, b_column=-1e-4)
    lon, lat, h = rpc.long_off + rng.uniform(-0.05, 0.05, 50), rpc.lat_off + rng.uniform(-0.05, 0.05, 50), rng.uniform(0, 800, 50)
    folded = bias.fold(rpc)
    fl, fc = folded.project(lon, lat, h)
    ol, oc = bias.observed(*rpc.project(lon, lat, h))
    assert np.max(np.abs(fl - ol)) < FOLDED_BIAS_PX and np.max(np.abs(fc - oc)) < FOLDED_BIAS_PX
    with pytest.raises(ValueError):
        RpcBias(a_column=1e-5).fold(rpc)


@pytest.mark.skipif("rpc" not in Image.model_fields, reason="the job schema has no images[].rpc yet (engine half of issue 17)")
def test_export_rpc_after_an_adjustment_through_gdal(tmp_path) -> None:
    """End to end: simulate RPC images with a known bias, adjust (RPC-DRIFT), export the
    refined RPC; GDAL on it reproduces the adjusted model (the report's bias on the delivered
    RPC) within 0.01 px RMS, and the true geometry within the adjustment's precision."""
    job_path, report_path, out = tmp_path / "job.json", tmp_path / "report.json", tmp_path / "refined_RPC.TXT"
    assert main(["simulate", "prism-triplet", "-o", str(job_path), "--seed", "2", "--noise-px", "0.3", "--gcps", "8",
                 "--rpc-model", "RPC-DRIFT", "--rpc-bias", "a0=15,b0=-9,a_line=5e-5,b_line=-3e-5"]) == 0
    assert main(["run", str(job_path), "-o", str(report_path)]) == 0
    job, report = json.loads(job_path.read_text()), json.loads(report_path.read_text())
    entry = job["images"][0]
    assert main(["export-rpc", str(job_path), str(report_path), "--image", entry["id"], "-o", str(out)]) == 0
    values = {p["name"]: p["value"] for p in next(e for e in report["images"] if e["id"] == entry["id"])["parameters"]}
    delivered = RPC.from_job(entry["rpc"])
    lon, lat, h = _ground_sample(delivered)
    want_l, want_c = _contract_model(gdal_rpc(delivered), values, lon, lat, h)
    with rasterio.open(tmp_path / "refined.tif", "w", driver="GTiff", width=8, height=8, count=1, dtype="uint8") as dst:
        dst.write(np.zeros((1, 8, 8), np.uint8))
    with rasterio.open(tmp_path / "refined.tif") as src:
        rows, cols = gdal_ground_to_image(src.rpcs, lon, lat, h)
    err = np.hypot(rows - GDAL_CORNER_PX - want_l, cols - GDAL_CORNER_PX - want_c)
    assert np.sqrt(np.mean(err**2)) < RMS_TOL_PX, np.sqrt(np.mean(err**2))


def test_ground_to_image_table_with_the_bias_covariance(simulated) -> None:
    """Propagated sigmas of an RPC image against the analytic derivatives of the bias
    equations: a0 moves the line by 1/(1 - a_line), a_line by line_obs/(1 - a_line) (b0, b_line
    likewise for the column with b_line's line_obs term); 1e-6 relative (central differences
    of a linear function)."""
    from solver.gis.transforms import ground_to_image_table

    job, _ = simulated
    entry = job["images"][0]
    values = {"a0": 4.0, "a_line": 1e-4, "b0": -3.0, "b_line": 0.0}
    rep = _report_entry(entry["id"], values)
    names = ["a0", "a_line", "b0", "b_line"]
    sig = np.array([0.2, 2e-5, 0.3, 1e-5])
    rep["covariance"] = {"names": names, "matrix": np.diag(sig**2).tolist()}
    image = rpc_image({**entry, "model": {"name": "RPC-DRIFT"}}, rep)
    lon, lat, h = _ground_sample(image.rpc, n=5)
    rows = [{"lon": a, "lat": b, "height": c} for a, b, c in zip(lon, lat, h)]
    out = ground_to_image_table(image, rows, sigmas=True)
    assert all("chip" not in o for o in out)
    line = np.array([o["line"] for o in out])
    k = 1.0 - values["a_line"]
    want_line = np.hypot(sig[0] / k, sig[1] * line / k)
    # column = R_c + b0 + b_line * line: b0 -> 1; b_line -> line; a0, a_line through line (b_line = 0)
    want_col = np.hypot(sig[2], sig[3] * line)
    np.testing.assert_allclose([o["sigma_line_px"] for o in out], want_line, rtol=PROPAGATED_SIGMA_REL)
    np.testing.assert_allclose([o["sigma_column_px"] for o in out], want_col, rtol=PROPAGATED_SIGMA_REL)


def _small_rpc_image(bias: dict[str, float]) -> RpcImage:
    """A 200 x 300 px RPC image of ~11 m pixels (line ~ -latitude, column ~ longitude, a mild
    height parallax and a curvature, so that the refit has work to do)."""
    def coeffs(**terms):
        v = np.zeros(20)
        for k, x in terms.items():
            v[int(k[1:])] = x
        return v

    den = coeffs(t0=1.0, t1=0.01, t2=-0.005)
    rpc = RPC(99.5, 149.5, -22.1, -51.4, 400.0, 100.0, 150.0, 0.01, 0.015, 300.0,
              coeffs(t2=-1.0, t3=0.02, t7=0.01), den, coeffs(t1=1.0, t3=0.03, t8=-0.01), den)
    return RpcImage("small", rpc, RpcBias.from_parameters(bias), "RPC-AFFINE")


def test_ortho_of_an_rpc_image_rigorous_path_against_gdal_warper(tmp_path) -> None:
    """``pba ortho`` of an RPC image: our path (the adjusted model, RPC + bias, sampled by the
    ortho kernel) and GDAL's warper on the refined RPC give the same orthoimage of a smooth
    raster: mean |difference| under 0.5 grey levels over the common pixels (docs/how-to/export-gis.md's
    rigorous-vs-RPC figure for a 4-chip image); without the bias the orthoimage's footprint
    moves."""
    from solver.gis.ortho import orthorectify

    yy, xx = np.mgrid[0:200, 0:300]
    data = (127 + 60 * np.sin(xx / 9.0) * np.cos(yy / 7.0)).astype(np.uint8)
    raster = tmp_path / "small.tif"
    with rasterio.open(raster, "w", driver="GTiff", width=300, height=200, count=1, dtype="uint8") as dst:
        dst.write(data, 1)
    bias = {"a0": 3.0, "a_column": 2e-3, "b0": -2.0, "b_line": -3e-3, "b_column": 1e-3}
    image = _small_rpc_image(bias)
    refined = refined_rpc(image.with_size(200, 300), (300.0, 500.0))
    assert refined.fit["method"] == "refit" and refined.fit["check_residuals"]["max_px"] < MAX_TOL_PX
    outs = {}
    for name, img, method, rpc in [("rig", image, "rigorous", None), ("gdal", image, "rpc", refined), ("nobias", _small_rpc_image({}), "rigorous", None)]:
        out = tmp_path / f"{name}.tif"
        orthorectify(img, raster, out, "EPSG:4326", 1e-4, 400.0, None, method, None, rpc)
        with rasterio.open(out) as src:
            outs[name] = (src.read(1).astype(float), src.transform)
    (a, ta), (b, tb), (_, tc) = outs["rig"], outs["gdal"], outs["nobias"]
    assert ta == tb and a.shape == b.shape
    both = (a > 0) & (b > 0)
    assert both.sum() > 0.5 * both.size
    assert np.mean(np.abs(a[both] - b[both])) < 0.5, np.mean(np.abs(a[both] - b[both]))
    # without the bias the footprint moves by the bias (several pixels of 1e-4 deg)
    shift_px = np.hypot(tc.c - ta.c, tc.f - ta.f) / 1e-4
    assert shift_px > 1.0, shift_px
