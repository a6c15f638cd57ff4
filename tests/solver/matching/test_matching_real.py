"""``pba match`` on real satellite images: two Pleiades pairs with their vendor RPCs
(tests/data/matching/README.md: CNES shareloc, Apache-2.0).

There is no truth for real images, so the evidence is the adjustment's: the matched ties of
each pair, adjusted with the bias-compensated RPC model RPC-SHIFT (bias priors of 10 px, no
control), must pass the chi-square test of the variance factor with sigma0 near 1. That is,
the ``sigma_px`` the matching states is the precision its ties really have across the epipolar
direction (the only direction two images check).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio

from solver import api
from solver.cli import main
from solver.geometry.rpc import RPC
from solver.importers.measurements_csv import read_measurements

pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")]

DATA = Path(__file__).parents[2] / "data" / "matching"
# sigma0 of the adjustment of the matched ties within this band around 1: the stated sigma_px
# agrees with the scatter of the matches (the chi-square test's own bounds at ~100-500 dof
# are about 0.85-1.15)
SIGMA0_BAND = (0.85, 1.15)
BIAS_PRIOR_PX = 10.0  # a-priori sigma of each image's RPC shift (Pleiades: ~10 m, 0.5 m pixels)
MIN_TIE_POINTS = 50
DEM = DATA.parent / "dem" / "srtm_ventoux.tif"  # SRTM (EGM96 heights) of the Ventoux area
# (first image, second image, the terrain's height range MIN,MAX for --heights)
PAIRS = {
    "ventoux": ("ventoux_left", "ventoux_right", "400,700"),  # SRTM: 440-550 m + geoid ~50 m
    "gizeh": ("gizeh_img1", "gizeh_img2", None),
}
# the matching's options: the Ventoux pair's range from the DEM, Giza's the RPCs' whole range
# (10-270 m) by default
OPTIONS = {"ventoux": ["--dem", str(DEM), "--dem-vertical", "egm96"], "gizeh": []}


def _rpc_job(ids: list[str], measurements: list[dict], options: dict | None = None) -> dict:
    """An RPC-SHIFT job of the images' delivered RPCs (their sidecars) with the matched ties."""
    images = []
    for i in ids:
        with warnings.catch_warnings(), rasterio.open(DATA / f"{i}.tif") as ds:
            warnings.simplefilter("ignore")
            rpc = RPC.from_gdal(ds.rpcs.to_gdal())
        prior = {"value": 0.0, "sigma": BIAS_PRIOR_PX}
        images.append({"id": i, "model": {"name": "RPC-SHIFT"}, "rpc": rpc.to_job(), "bias_prior": {"a0": prior, "b0": prior}})
    return {
        "schema_version": "1.0", "name": "real-pair", "cameras": [], "images": images,
        "points": [{"id": p, "role": "tie"} for p in sorted({m["point"] for m in measurements})],
        "observations": measurements, "options": options or {},
    }


@pytest.fixture(scope="module", params=sorted(PAIRS))
def matched_pair(request, tmp_path_factory):
    a, b, _heights = PAIRS[request.param]
    d = tmp_path_factory.mktemp(request.param)
    out, summary = d / "ties.csv", d / "summary.json"
    argv = ["match", str(DATA / f"{a}.tif"), str(DATA / f"{b}.tif"), "-o", str(out), "--summary", str(summary), "-q"]
    assert main(argv + OPTIONS[request.param]) == 0
    return request.param, [a, b], read_measurements(out.read_text(), "ties.csv"), json.loads(summary.read_text())


def test_real_pair_is_matched(matched_pair):
    name, ids, measurements, summary = matched_pair
    assert summary["tie_points"] >= MIN_TIE_POINTS, summary
    lo, hi = summary["height_range_m"]
    if name == "ventoux":  # the DEM's heights under the images (SRTM 440-600 m + the geoid's 50 m) +- 50 m
        assert 380.0 < lo < 500.0 and 600.0 < hi < 720.0, (lo, hi)
    else:  # the RPCs' whole range: offset 140 m +- scale 130 m
        assert (lo, hi) == (pytest.approx(10.0), pytest.approx(270.0))
        # ties over the whole overlap (86 % of the grid): measured 63 % and 61 % of the cells, where
        # SIFT run on every tile's decimated window covered 17 % and 19 % (the same few features)
        assert all(im["cells_covered"] > 0.5 for im in summary["images"]), summary["images"]
    assert {m["image"] for m in measurements} == set(ids)
    (pair,) = summary["pairs"]
    assert pair["tie_points"] == summary["tie_points"]
    # the two variances written add up to the measured scatter about the epipolar curves
    sigmas = {m["image"]: m["sigma_px"] for m in measurements}
    assert np.hypot(sigmas[ids[0]], sigmas[ids[1]]) == pytest.approx(pair["scatter_px"], abs=0.002)


GRID = 16  # the matching's default grid: its thinning cells


def _cells(line: np.ndarray, col: np.ndarray, lines: int, columns: int) -> np.ndarray:
    """The (GRID x GRID) cell of each position, as a flat index (row * GRID + column)."""
    return np.clip((line * GRID / lines).astype(int), 0, GRID - 1) * GRID + np.clip((col * GRID / columns).astype(int), 0, GRID - 1)


def _true_overlap_cells(a: str, b: str, step: float = 4.0, template_px: float = 12.0) -> np.ndarray:
    """(GRID, GRID) cells of image a of which at least half lies inside image b on the real
    terrain: a's pixels (every ``step``) carried to the DEM along their rays (the height
    iterated to the DEM's under the ground point), projected into b with b's RPC and kept when
    a correlation template (``template_px``) fits inside b. Independent of the matching: only
    the RPCs and the DEM."""
    from solver.geometry.dem import read_dem
    from solver.geometry.geodesy import ecef_to_geodetic
    from solver.matching.orientation import images_from_rpcs

    (ia, ib), _ = images_from_rpcs([str(DATA / f"{a}.tif"), str(DATA / f"{b}.tif")])
    dem = read_dem(DEM, "egm96")
    line, col = (v.ravel() for v in np.meshgrid(np.arange(step / 2, ia.lines, step), np.arange(step / 2, ia.columns, step), indexing="ij"))
    h = np.full(line.shape, 500.0)
    for _ in range(10):
        lon, lat = ecef_to_geodetic(ia.model.image_to_ground(line, col, height_m=h))[:, :2].T
        h = dem.height(lon, lat)
    bl, bc, _chip = ib.model.ground_to_image(ia.model.image_to_ground(line, col, height_m=h))
    inside = (bl >= template_px) & (bl <= ib.lines - 1 - template_px) & (bc >= template_px) & (bc <= ib.columns - 1 - template_px)
    ci = _cells(line, col, ia.lines, ia.columns)
    share = np.bincount(ci, weights=inside, minlength=GRID * GRID) / np.bincount(ci, minlength=GRID * GRID)
    return (share >= 0.5).reshape(GRID, GRID)


def test_real_ties_cover_the_true_overlap(tmp_path):
    """Ventoux with the defaults (the RPCs' whole range, 190-1,960 m; the terrain is near 500 m,
    under the RPCs' height offset of 1,075 m): the ties fall over the part of the first image
    that the second sees on the real terrain (from the SRTM crop and the RPCs alone), not only in
    a band of it. The overlap's edge moves 0.67 px per metre of height here: tiles chosen at one
    height of the range would leave it without ties."""
    a, b, _heights = PAIRS["ventoux"]
    out = tmp_path / "ties.csv"
    assert main(["match", str(DATA / f"{a}.tif"), str(DATA / f"{b}.tif"), "-o", str(out), "-q"]) == 0
    measurements = read_measurements(out.read_text(), "ties.csv")
    true = _true_overlap_cells(a, b)
    assert 40 <= true.sum() <= 120, int(true.sum())  # measured 65 of 256 cells (lines ~350-500 of 500)
    p = np.array([[m["line"], m["column"]] for m in measurements if m["image"] == a])
    has = np.zeros(GRID * GRID, bool)
    has[_cells(p[:, 0], p[:, 1], 500, 500)] = True  # the crops are 500 x 500
    has = has.reshape(GRID, GRID)
    print(f"true overlap: {int(true.sum())} cells, {int((has & true).sum())} with ties, ties in {int((has & ~true).sum())} other cells")
    # measured 58 of the 65 cells (89 %; the empty ones are two columns of dark forest), and
    # ties in 2 other cells, each beside the true overlap
    assert (has & true).sum() >= 0.8 * true.sum(), (int((has & true).sum()), int(true.sum()))
    rows = np.flatnonzero(true.any(axis=1))
    assert np.all(has[rows].any(axis=1)), "a row of the true overlap without ties"
    assert not has[: rows.min() - 1].any(), "ties where the second image does not see the terrain"


def test_rpc_adjustment_of_real_ties_passes_chi_square(matched_pair):
    """RPC-SHIFT adjustment of the matched ties: the chi-square test passes and sigma0 is near 1."""
    name, ids, measurements, _summary = matched_pair
    report = api.run(_rpc_job(ids, measurements))
    adj = report["adjustment"]
    assert adj["chi2"]["passed"], (name, adj["sigma0_aposteriori"], adj["chi2"])
    assert SIGMA0_BAND[0] < adj["sigma0_aposteriori"] < SIGMA0_BAND[1], (name, adj["sigma0_aposteriori"])


def test_job_from_rpc_images_alone_gets_matched_ties(tmp_path):
    """``pba job --rpc ... --match ...``: a job composed from RPC images alone (no measurement
    yet) guides the matching by its delivered RPCs; the ties join the job. Without bias priors
    or control its datum is undefined (exit 1); ``--bias-prior`` makes the RPCs' own ground
    reference the datum, and the adjusted tie heights agree with the public SRTM DEM of the area
    (tests/data/dem, EGM96 converted) within the predicted sigma of their common height."""
    from solver.geometry.dem import read_dem

    a, b, heights = PAIRS["ventoux"]
    out = tmp_path / "job.json"
    argv = ["job", "--rpc", f"{a}={DATA / a}.tif", "--rpc", f"{b}={DATA / b}.tif", "--rpc-model", "RPC-SHIFT",
            "--match", f"{a}={DATA / a}.tif", "--match", f"{b}={DATA / b}.tif", "--match-heights", heights, "-o", str(out)]
    assert main(argv) == 1  # without bias priors or control the composed job's datum is undefined
    job = json.loads(out.read_text())
    ties = [p for p in job["points"] if p["role"] == "tie"]
    assert len(ties) >= MIN_TIE_POINTS
    assert {o["image"] for o in job["observations"]} == {a, b}
    assert main(argv + ["--bias-prior", str(BIAS_PRIOR_PX)]) == 0  # matched again: the same ties
    job = json.loads(out.read_text())
    report = api.run(job)
    assert report["adjustment"]["chi2"]["passed"]
    datum = report["quality"]["datum"]
    assert datum["defined_by"] == [f"the RPCs' bias priors (2 images: {a}, {b})"] and not datum["undetermined"]
    sigma_u = next(d["sigma_m"] for d in datum["directions"] if d["direction"] == "shift_height")
    # measured: 20 m (0.5 m pixels, 10 px priors, a base-to-height ratio of about 0.25)
    assert 5.0 < sigma_u < 50.0
    dem = read_dem(DATA.parent / "dem" / "srtm_ventoux.tif", "egm96")
    t = report["tie_points"]
    h_dem = dem.sample(np.array([p["lon_deg"] for p in t]), np.array([p["lat_deg"] for p in t]))[0]
    diff = np.array([p["height_m"] for p in t]) - h_dem
    # measured: mean +2.7 m, standard deviation 8.1 m over 235 ties (SRTM's 90 m cells on a 0.28 slope)
    assert abs(float(np.mean(diff))) < 2.0 * sigma_u
    assert float(np.std(diff)) < 15.0
