"""DEM heights of tie points (solver.observations.dem_heights): the residual v = h_dem - h of a
point in the LGS and its derivatives along the LGS axes (the local east, north, up at the
point, the DEM's slope) against central differences, far from the LGS origin where the axes
differ from the local ones; the linearised term against its own evaluation."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS
from utils.differences import central_jacobian

from solver.geometry.dem import Dem
from solver.geometry.geodesy import LocalFrame, geodetic_to_ecef
from solver.geometry.vertical import resolve
from solver.observations.dem_heights import DemTerm, sample

STEP_M = 0.5  # inside one 1-arc-second cell (30 m): the bilinear surface is smooth there
# m/m: the DEM's slope is per metre on the ellipsoid, the point moves h above it (h / R = 1.5e-4
# of a slope of 0.4 at 950 m); the differences' truncation over 0.5 m is far below
JAC_TOL = 1e-4


def _rough_dem(lon0: float, lat0: float) -> Dem:
    d = 1.0 / 3600
    n = 600
    rng = np.random.default_rng(7)
    cols, rows = np.meshgrid(np.arange(n), np.arange(n))
    values = 400.0 + 0.15 * cols * 30 - 0.08 * rows * 30 + rng.normal(0, 4.0, (n, n))
    return Dem(values, (d, 0.0, lon0 - n * d / 2, 0.0, -d, lat0 + n * d / 2), CRS.from_epsg(4326), resolve(None, "ellipsoid"))


def test_residual_gradient_agrees_with_central_differences() -> None:
    lon0, lat0 = 5.2, 44.2
    frame = LocalFrame.at(geodetic_to_ecef(np.array([[lon0, lat0, 0.0]]))[0])
    dem = _rough_dem(lon0, lat0)
    # points 2-4 km from the origin: their local up is 0.3-0.6 mrad from the LGS's
    for lon, lat, h in ((5.225, 44.21, 600.0), (5.17, 44.185, 300.0), (5.21, 44.19, 950.0)):
        p = frame.to_lgs(geodetic_to_ecef(np.array([[lon, lat, h]]))[0])
        p[:2] += 7.3  # away from a cell edge in neither axis
        smp = sample(frame, dem, p[None, :])
        numeric = central_jacobian(lambda x: sample(frame, dem, x[None, :]).residual[0], p, STEP_M)
        np.testing.assert_allclose(smp.gradient[0], numeric, atol=JAC_TOL)
        assert smp.gradient[0][2] == pytest.approx(-1.0, abs=1e-3)  # mostly the point's own height


def test_term_is_its_linearisation() -> None:
    term = DemTerm(3, np.array([10.0, -20.0, 500.0]), 2.5, np.array([0.1, -0.05, -1.0]), 0.5)
    p = np.array([12.0, -19.0, 498.0])
    r, j = term.evaluate(p)
    a, b = term.linear_form()
    np.testing.assert_allclose(r, a @ p - b, atol=1e-12)
    np.testing.assert_allclose(j, a)
    assert r[0] == pytest.approx(0.5 * (2.5 + 0.2 - 0.05 + 2.0))


# ---- the family in an adjustment: a rigorous block (orbit and attitude measured, no control) ----

DEM_NOISE_M = 3.0


def job_dem(truth: dict, path, seed: int) -> dict:
    """The job's ``dem`` for a simulated scene: its true terrain degraded by DEM_NOISE_M of
    correlated noise (seed ``seed``), written to ``path`` and read as ``pba job --dem`` reads it."""
    from solver.importers.compose import SourceFile, dem_section
    from solver.simulate.dem import write_dem_of_truth

    write_dem_of_truth(truth, path, DEM_NOISE_M, seed)
    return dem_section(SourceFile(path.name, b"", path=str(path)), DEM_NOISE_M, None, None)


@pytest.fixture(scope="module")
def pass_triplet_with_dem(tmp_path_factory):
    """A simulated PRISM triplet (PASS-J2, ephemeris and attitude weighted, no control point)
    and a DEM degraded from its true terrain (1" cells, 3 m correlated noise, no bias)."""
    import json

    from solver.cli import main

    d = tmp_path_factory.mktemp("dem")
    out = d / "tri.json"
    assert main(["simulate", "prism-triplet", "-o", str(out), "--seed", "2", "--model", "PASS-J2",
                 "--weight-ephemeris", "2,0.01", "--gcps", "0", "--checks", "10", "--tie-points", "40"]) == 0
    job = json.loads(out.read_text())
    truth = json.loads(out.with_name("tri.truth.json").read_text())
    job["dem"] = job_dem(truth, d / "dem.tif", 2)
    return job, truth


def test_dem_heights_in_a_rigorous_block(pass_triplet_with_dem) -> None:
    """The DEM family on exact-model images (no RPC): every tie point gets its DEM height, the
    normalised residuals are about 1, the datum says the DEM takes part, and the tie points'
    heights are within their predicted sigmas of the truth."""
    import copy

    from solver.api import run

    job, truth = pass_triplet_with_dem
    rep = run(copy.deepcopy(job))
    dem = rep["dem"]
    ties = [p for p in job["points"] if p["role"] == "tie"]
    assert dem["statistics"]["n"] == len(ties) and not dem["outside"]
    # the residuals are below their sigmas by the heights' redundancy (the adjusted heights follow the
    # DEM in part): the whole adjustment's variance factor is the test of the weights
    assert 0.2 < dem["statistics"]["rms_normalised"] < 1.5
    assert 0.8 < rep["adjustment"]["sigma0_aposteriori"] < 1.25
    assert dem["cell_m"] == pytest.approx(30.9, abs=1.0)  # 1 arc second north-south
    true = {p["id"]: p for p in truth["points"]}
    z = [(t["height_m"] - true[t["id"]]["height_m"]) / t["sigma_m"][2] for t in rep["tie_points"]]
    assert np.sqrt(np.mean(np.square(z))) < 2.0


def test_the_dem_bias_test_finds_a_bias_of_three_sigma(pass_triplet_with_dem) -> None:
    """The report's test of a common DEM bias: without one it passes; the DEM raised by three
    times the test's own sigma (the orbit and attitude fix the heights too), it finds it."""
    import copy

    from solver.api import run
    from solver.geometry.dem import grid_from_job, grid_to_job

    job, _truth = pass_triplet_with_dem
    clean = run(copy.deepcopy(job))["quality"]["dem_bias"]
    assert clean["testable"] and clean["passed"], clean
    j = copy.deepcopy(job)
    dem = grid_from_job(j["dem"]["grid"])
    injected = 3.0 * clean["sigma_m"]
    dem.values = dem.values + injected
    j["dem"]["grid"] = grid_to_job(dem)
    biased = run(j)["quality"]["dem_bias"]
    assert not biased["passed"] and biased["w"] > biased["critical"], biased
    assert biased["bias_m"] == pytest.approx(clean["bias_m"] + injected, abs=0.5 * clean["sigma_m"])


def test_the_dem_bias_test_reads_the_reports_linearisation(pass_triplet_with_dem, monkeypatch) -> None:
    """The DEM-bias test of an adjustment uses the report's linearisation and the covariance's
    inverse of the reduced matrix (as data snooping does): nothing is linearised after the solve
    but the report's, and the test equals the one computed afresh at the same solution (a
    linearisation and a factor of the reduced matrix of its own)."""
    import copy

    import solver.procedures.single as single
    from solver.engine.linalg import linearise, schur
    from solver.quality.datum import dem_bias
    from solver.schema.job import load_job

    job, _truth = pass_triplet_with_dem
    calls: list[str] = []
    real_rank_check = single.assert_full_rank
    monkeypatch.setattr(single, "assert_full_rank", lambda problem: calls.append("rank check") or real_rank_check(problem))
    monkeypatch.setattr(single, "linearise", lambda problem: calls.append("linearise") or linearise(problem))
    solution = single.adjust_once(load_job(copy.deepcopy(job)))
    assert calls == ["rank check", "linearise"]  # the rank check's own linearisation, none after the solve
    assert solution.take_linearised() is None  # dropped once the test had read it
    reused = solution.report()["quality"]["dem_bias"]
    lin = linearise(solution.problem)
    fresh = dem_bias(solution.problem, lin, schur(lin, solution.problem), 0.05)
    assert reused["testable"] and fresh["testable"]
    # the heights are weakly fixed here (orbit and attitude only, sigma of the bias ~100 m): the two
    # inverses of the reduced matrix agree to ~1e-6 of that sigma (measured 1.5e-4 m in the bias)
    sigma = fresh["sigma_m"]
    assert abs(reused["bias_m"] - fresh["bias_m"]) < 1e-5 * sigma, (reused, fresh)
    assert abs(reused["sigma_m"] - sigma) < 1e-5 * sigma, (reused, fresh)
    assert abs(reused["w"] - fresh["w"]) < 1e-5, (reused, fresh)
    assert reused["passed"] == fresh["passed"]


# ---- DEM blunders: tie points on roofs or under trees (the DEM off by tens of metres there) ----

BLUNDER_M = 25.0  # the DEM off at a blundered point: 8 sigmas of a DEM height (3 m), above its MDB (15-20 m)
BLUNDER_RADIUS_M = 45.0  # cells within this of the point are off: 1.5 cells, the point on a plateau


def _blundered(job: dict, truth: dict, offsets: dict[str, float], radius_m: float = BLUNDER_RADIUS_M) -> dict:
    """``job`` with its DEM off by ``offsets[point]`` at every cell centre within ``radius_m``
    of the point's true position, and default data snooping."""
    import copy

    from solver.geometry.dem import grid_from_job, grid_to_job, metres_per_degree

    j = copy.deepcopy(job)
    dem = grid_from_job(j["dem"]["grid"])
    a, _b, c, _d, e, f = dem.transform
    rows, cols = dem.values.shape
    lon_c, lat_c = c + a * (np.arange(cols) + 0.5), f + e * (np.arange(rows) + 0.5)
    true = {p["id"]: p for p in truth["points"]}
    values = dem.values.copy()
    for pid, off in offsets.items():
        m_lon, m_lat = metres_per_degree(np.array([true[pid]["lat_deg"]]))
        dx = (lon_c - true[pid]["lon_deg"]) * m_lon[0]
        dy = (lat_c - true[pid]["lat_deg"]) * m_lat[0]
        values[np.hypot(dx[None, :], dy[:, None]) <= radius_m] += off
    dem.values = values
    j["dem"]["grid"] = grid_to_job(dem)
    j["options"] = {**j.get("options", {}), "blunder_detection": {}}
    return j


def _controlled_triplet(d, seed: int) -> tuple[dict, dict]:
    """The PASS-J2 triplet of ``seed`` with 4 control points (its horizontal datum: without
    control this block's tie points are 20-120 m off horizontally, so a DEM is sampled away
    from where the blunders are; bench/bench_dem_blunders.py) and a degraded DEM."""
    import json

    from solver.cli import main

    out = d / "tri.json"
    assert main(["simulate", "prism-triplet", "-o", str(out), "--seed", str(seed), "--model", "PASS-J2",
                 "--weight-ephemeris", "2,0.01", "--gcps", "4", "--checks", "10", "--tie-points", "40"]) == 0
    job = json.loads(out.read_text())
    truth = json.loads(out.with_name("tri.truth.json").read_text())
    job["dem"] = job_dem(truth, d / "dem.tif", 100 + seed)
    return job, truth


@pytest.fixture(scope="module")
def controlled_triplet_with_dem(tmp_path_factory):
    """:func:`_controlled_triplet` of seed 2."""
    return _controlled_triplet(tmp_path_factory.mktemp("dem_blunders"), 2)


def test_snooping_removes_the_dem_heights_of_points_on_roofs_and_trees(controlled_triplet_with_dem) -> None:
    """Four tie points whose DEM is 25 m too high (a canopy in a DSM) or too low (a roof against
    a DTM): default data snooping removes exactly those four DEM heights and no ray of theirs
    (the robust start once took a ray of such a point in its place: the DEM height pulls the
    point, the next worst test of its block is a ray), and their adjusted heights stay within
    three predicted sigmas of the truth (against the truth of the simulation, not the DEM)."""
    from solver.api import run

    job, truth = controlled_triplet_with_dem
    ties = [p["id"] for p in job["points"] if p["role"] == "tie"]
    offsets = {pid: BLUNDER_M * (1 if k % 2 == 0 else -1) for k, pid in enumerate(ties[3::8][:4])}
    rep = run(_blundered(job, truth, offsets))
    q = rep["quality"]
    removed = {r["point"] for r in q["rejected"] if r["kind"] == "dem_height" and r.get("removed", True)}
    assert removed == set(offsets), q["rejected"]
    assert not [r for r in q["rejected"] if r["kind"] != "dem_height"], q["rejected"]
    assert not q["not_identifiable"] and q["blunder_detection"]["stopped_early"] is None
    true = {p["id"]: p for p in truth["points"]}
    for p in rep["tie_points"]:
        if p["id"] in offsets:
            assert abs(p["height_m"] - true[p["id"]]["height_m"]) < 3.0 * p["sigma_m"][2], p
    rows = {p["point"]: p for p in rep["dem"]["points"]}
    used = {pid for pid, p in rows.items() if p["used"]}
    assert used.isdisjoint(offsets) and len(used) == len(ties) - len(offsets)  # the others' DEM heights all kept
    assert rep["dem"]["statistics"]["n"] == len(used)
    for pid, off in offsets.items():  # listed after the used ones, flagged, and showing the blunder
        assert rows[pid]["rejected"] and not rows[pid]["used"]
        assert abs(rows[pid]["residual_m"] - off) < 4.0 * rows[pid]["sigma_m"], rows[pid]
    assert not any(p.get("rejected") for p in rows.values() if p["used"])


@pytest.mark.parametrize("seed", [3, 4])
def test_dem_spikes_are_removed_not_the_control(tmp_path, seed) -> None:
    """The DEM 25 m off only in the cells next to four tie points (a single building or tree in
    a 30 m DEM: flanks of slope ~1 within a cell of the point): the DEM heights pull their
    points sideways and the block bends. Seed 3: when the robust start left DEM heights to the
    least-squares loop it removed two control surveys instead (P01, P02; every blundered height
    kept); it now removes a failed DEM height itself. Seed 4: removing control surveys that
    failed beside them in the same step lost three control points (the block 113 m off); they
    now wait for the least-squares loop. Both: exactly the four DEM heights, no control lost."""
    from solver.api import run

    job, truth = _controlled_triplet(tmp_path, seed)
    ties = [p["id"] for p in job["points"] if p["role"] == "tie"]
    offsets = {pid: BLUNDER_M * (1 if k % 2 == 0 else -1) for k, pid in enumerate(ties[3::8][:4])}
    q = run(_blundered(job, truth, offsets, radius_m=20.0))["quality"]
    removed = {r["point"] for r in q["rejected"] if r["kind"] == "dem_height" and r.get("removed", True)}
    assert removed == set(offsets), q["rejected"]
    assert q["lost_control"] is None and not [r for r in q["rejected"] if r["kind"] != "dem_height"], q["rejected"]


def test_a_removal_that_drops_a_tie_point_drops_it_from_the_dem_exclusions(controlled_triplet_with_dem) -> None:
    """Snooping removes a tie point's DEM height, then rays of it until it has one left: the
    core drops the point, and ``dem.excluded`` must not name it (the job would no longer be
    valid: "dem.excluded names ..., which is not a tie point", and snooping stopped there)."""
    from solver.observations.dem_heights import FAMILY
    from solver.quality.removal import remove
    from solver.schema.job import Job

    job, _truth = controlled_triplet_with_dem
    j = Job.model_validate(job)
    tie = next(p.id for p in j.points if p.role == "tie")
    j, _ = remove(j, [("dem_height", tie)])
    assert j.dem is not None and j.dem.excluded == [tie]
    rays = [k for k, o in enumerate(j.observations) if o.point == tie]
    assert len(rays) == 3
    after, collateral = remove(j, [("observation", k) for k in rays[:2]])
    assert tie not in {p.id for p in after.points} and {c["point"] for c in collateral} == {tie}
    assert after.dem is not None and after.dem.excluded == []
    problems, _count = FAMILY.check(after)
    assert not problems


# ---- the DEM bias test on an RPC block whose datum comes from the RPCs' bias priors ----

BIAS_PRIOR_PX = 2.0  # 0 +- 2 px on every bias term (pba job --bias-prior 2): the RPCs' own ground reference


@pytest.fixture(scope="module")
def rpc_triplet_with_dem(tmp_path_factory):
    """A simulated PRISM triplet as RPC images (RPC-DRIFT, the delivered RPCs without bias), no
    control point, bias priors of 0 +- 2 px on every image, and a degraded DEM (3 m noise)."""
    import json

    from solver.cli import main
    from solver.importers.compose import rpc_bias_priors

    d = tmp_path_factory.mktemp("dem_rpc")
    out = d / "tri.json"
    assert main(["simulate", "prism-triplet", "-o", str(out), "--seed", "3", "--rpc-model", "RPC-DRIFT",
                 "--gcps", "0", "--checks", "10", "--tie-points", "40"]) == 0
    job = json.loads(out.read_text())
    truth = json.loads(out.with_name("tri.truth.json").read_text())
    for im in job["images"]:
        im["bias_prior"] = rpc_bias_priors("RPC-DRIFT", im["rpc"], BIAS_PRIOR_PX)
    job["dem"] = job_dem(truth, d / "dem.tif", 3)
    return job, truth


def test_the_dem_bias_test_on_an_rpc_block_with_bias_priors(rpc_triplet_with_dem) -> None:
    """The test of a common DEM bias where the bias priors fix the heights too: it passes on the
    unbiased DEM, finds the DEM raised by three of its own sigmas, and estimates that bias
    (within half a sigma of the clean estimate plus the injection); the tie heights of the
    clean adjustment are within their predicted sigmas of the truth."""
    import copy

    from solver.api import run
    from solver.geometry.dem import grid_from_job, grid_to_job

    job, truth = rpc_triplet_with_dem
    rep = run(copy.deepcopy(job))
    clean = rep["quality"]["dem_bias"]
    assert clean["testable"] and clean["passed"], clean
    assert clean["sigma_m"] < 10.0  # the priors fix the heights to metres (not the 97 m of the orbit-only triplet)
    true = {p["id"]: p for p in truth["points"]}
    z = [(t["height_m"] - true[t["id"]]["height_m"]) / t["sigma_m"][2] for t in rep["tie_points"]]
    assert np.sqrt(np.mean(np.square(z))) < 2.0
    j = copy.deepcopy(job)
    dem = grid_from_job(j["dem"]["grid"])
    injected = 3.0 * clean["sigma_m"]
    dem.values = dem.values + injected
    j["dem"]["grid"] = grid_to_job(dem)
    biased = run(j)["quality"]["dem_bias"]
    assert not biased["passed"] and biased["w"] > biased["critical"], biased
    assert biased["bias_m"] == pytest.approx(clean["bias_m"] + injected, abs=0.5 * clean["sigma_m"])
