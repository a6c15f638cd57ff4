"""The datum analysis before the solve (solver.quality.datum) on a simulated RPC triplet
(independent simulator, RPC-SHIFT images with a known bias, tie points only):

- the sigmas of the seven directions of the tie points agree with the inverse of the whole
  normal matrix (dense, points not eliminated): independent of the Schur algebra;
- the held-bias case (one image's bias held, the others free: the height is determined only
  by the rays' divergence) is refused with the direction named, or adjusted and reported;
- bias priors on every image define the datum, and the report says so;
- an image with only tie points is named as such.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from solver.api import run
from solver.engine.assemble import parameter_names
from solver.engine.linalg import linearise, schur
from solver.errors import RankDeficientError
from solver.procedures.single import prepare
from solver.quality.datum import DIRECTIONS, analyse_datum
from solver.schema.job import load_job

DENSE_REL = 1e-6  # the Schur route against the dense inverse: rounding of a well-conditioned 200-square matrix
HELD_SIGMA_M = 1e-3  # px: "held" bias terms (a prior this tight)
PRIOR_PX = 10.0


@pytest.fixture(scope="module")
def rpc_triplet() -> dict:
    from solver.simulate import presets
    from solver.simulate.rpc import RpcSettings
    from solver.simulate.scene import SceneSettings

    s = SceneSettings(preset="prism-triplet", seed=1, rpc=RpcSettings("RPC-SHIFT", {"a0": 5.0, "b0": -3.0}))
    return presets.prism_triplet(s, gcps=6, checks=10, tie_points=60).job()


def _with_priors(job: dict, sigmas: list[float | None], gcps: bool = False) -> dict:
    j = copy.deepcopy(job)
    if not gcps:
        gcp_ids = {p["id"] for p in j["points"] if p["role"] == "gcp"}
        j["points"] = [p for p in j["points"] if p["id"] not in gcp_ids]
        j["observations"] = [o for o in j["observations"] if o["point"] not in gcp_ids]
    for im, sigma in zip(j["images"], sigmas):
        if sigma is not None:
            im["bias_prior"] = {"a0": {"value": 0.0, "sigma": sigma}, "b0": {"value": 0.0, "sigma": sigma}}
    return j


def test_direction_sigmas_equal_the_dense_inverse(rpc_triplet) -> None:
    problem = prepare(load_job(_with_priors(rpc_triplet, [PRIOR_PX] * 3)))
    lin = linearise(problem)
    analysis = analyse_datum(problem, lin, schur(lin, problem), parameter_names(problem), 100.0)
    jac = lin.sparse_jacobian().toarray()
    cov = np.linalg.inv(jac.T @ jac)
    lay = lin.layout
    ties = [p for p in problem.points if p.role == "tie" and p.estimated]
    xyz = np.array([p.xyz for p in ties])
    c = xyz.mean(axis=0)
    x, y = xyz[:, 0] - c[0], xyz[:, 1] - c[1]
    radius = np.sqrt(np.mean(x**2 + y**2))
    cols = np.array([lay.pt_col[p.index] for p in ties])
    g = np.zeros((lay.n_params, len(DIRECTIONS)))
    g[cols + 2, 2] = 1.0 / len(ties)  # the mean height
    g[cols + 2, 3] = x / np.sum(x**2) * np.ptp(x)  # the heights' slope east times the extent
    g[cols, 5], g[cols + 1, 5] = -y / np.sum(x**2 + y**2) * radius, x / np.sum(x**2 + y**2) * radius
    dense = np.sqrt(np.einsum("ik,ij,jk->k", g, cov, g))
    got = {d["direction"]: d["sigma_m"] for d in analysis.directions}
    for k in (2, 3, 5):
        assert got[DIRECTIONS[k][0]] == pytest.approx(dense[k], rel=DENSE_REL)
    assert not analysis.undetermined
    assert analysis.defined_by == ["the RPCs' bias priors (3 images: prism-backward, prism-nadir, prism-forward)"]


def test_held_bias_is_refused_with_the_height_named(rpc_triplet) -> None:
    job = _with_priors(rpc_triplet, [HELD_SIGMA_M, None, None])
    with pytest.raises(RankDeficientError) as err:
        run(job)
    problem = err.value.problems[0]
    assert problem.code == "datum_undetermined"
    assert "a common height shift of all tie points is not determined" in problem.message
    assert "--dem" in problem.message and "--bias-prior" in problem.message
    undetermined = {u["direction"]: u for u in problem.detail["undetermined"]}
    assert undetermined["shift_height"]["sigma_m"] > 100.0
    # the free images' offsets move with it; the held image's do not
    assert undetermined["shift_height"]["parameters"]
    assert not any(p.startswith("prism-backward/") for p in undetermined["shift_height"]["parameters"])

    job["options"] = {"datum": {"undetermined": "report"}}
    report = run(job)
    assert report["warnings"][0].startswith("the datum is not determined: ")
    assert "shift_height" in {u["direction"] for u in report["quality"]["datum"]["undetermined"]}


def test_control_defines_the_datum_and_a_tie_only_image_is_named(rpc_triplet) -> None:
    job = _with_priors(rpc_triplet, [None, None, None], gcps=True)
    gcps = {p["id"] for p in job["points"] if p["role"] == "gcp"}
    job["observations"] = [o for o in job["observations"] if not (o["image"] == "prism-forward" and o["point"] in gcps)]
    report = run(job)
    datum = report["quality"]["datum"]
    assert datum["defined_by"][0].startswith("6 control points")
    tied = {i["image"]: i["tied_by"] for i in datum["images"]}
    assert tied["prism-forward"].startswith("tie points only")
    assert not tied["prism-nadir"].startswith("tie points only")
    assert not datum["undetermined"] and "remedies" not in datum


@pytest.mark.parametrize("sigmas", [[PRIOR_PX] * 3, [HELD_SIGMA_M, None, None]], ids=["priors", "held-bias"])
def test_the_factor_made_in_the_reduced_matrix_memory_changes_no_analysis(rpc_triplet, sigmas) -> None:
    """``schur(..., rebuildable=True)`` (the adjustment's rank stage): the Cholesky factor takes
    S's own memory and S is computed again only where a path needs it (a weak direction's
    parameters, a singular S's eigen-analysis). The datum analysis and the rank check are those
    of the parts that keep S: a full-rank block and a weak height (held bias). The singular S
    is in tests/solver/engine/test_linalg.py."""
    from solver.engine.linalg import check_rank

    problem = prepare(load_job(_with_priors(rpc_triplet, sigmas)))
    lin = linearise(problem)
    names = parameter_names(problem)
    kept = schur(lin, problem)
    s_before = kept.s.copy()
    consumed = schur(lin, problem, rebuildable=True)
    consumed.factor()
    assert consumed.s.size == 0 and consumed.n_reduced == len(s_before)  # the factor took S's memory
    want = analyse_datum(problem, lin, kept, names, 100.0).to_report()
    got = analyse_datum(problem, lin, consumed, names, 100.0).to_report()
    assert [u["direction"] for u in got["undetermined"]] == [u["direction"] for u in want["undetermined"]]
    assert [u.get("parameters") for u in got["undetermined"]] == [u.get("parameters") for u in want["undetermined"]]
    for a, b in zip(got["directions"], want["directions"], strict=True):
        # the same factor of the same matrix: equal to rounding (1e-9 relative)
        assert (a["sigma_m"] is None) == (b["sigma_m"] is None)
        if a["sigma_m"] is not None:
            assert a["sigma_m"] == pytest.approx(b["sigma_m"], rel=1e-9)
    rank_kept, rank_consumed = check_rank(kept, names, fast=True), check_rank(consumed, names, fast=True)
    assert rank_consumed.deficient == rank_kept.deficient
    assert [n for n, _ in rank_consumed.null_parameters] == [n for n, _ in rank_kept.null_parameters]
    assert rank_consumed.condition == pytest.approx(rank_kept.condition, rel=1e-6)
    # S computed again is the S the factor consumed (the same sums in the same order; 1e-12 of
    # the largest entry guards against a wrong matrix, not rounding)
    again = consumed.reduced()
    assert np.max(np.abs(again - s_before)) <= 1e-12 * np.max(np.abs(s_before))
