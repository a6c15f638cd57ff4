"""Honest outcomes (issue 13): a solve that leaves no usable solution raises
:class:`solver.errors.UnusableSolution` instead of reporting its start as an adjustment, and
correlation coefficients are always within [-1, 1] (or omitted with a warning).

The unusable solves are forced by making the real residual blocks report an evaluation failure
to Ceres (at the start, or at every trial point), so they do not depend on input validation.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import solver.engine.backend as backend
import solver.engine.linalg as linalg
import solver.errors as errors
from solver.api import compare, run
from solver.errors import JobError, RankDeficientError

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
OBSERVATION_COSTS = (backend.ImageBatchCost, backend.PointCost)


def triplet(**options: Any) -> dict[str, Any]:
    doc = json.loads((EXAMPLES / "prism-triplet.json").read_text())
    doc.setdefault("options", {}).update(options)
    return doc


def fail_every_evaluation(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every observation block reports an evaluation failure: Ceres ends with FAILURE (on the
    Python evaluation path, whose cost functions can be patched)."""
    monkeypatch.setenv("PBA_EVALUATION", "python")
    for cls in OBSERVATION_COSTS:
        monkeypatch.setattr(cls, "Evaluate", lambda self, parameters, residuals, jacobians: False)


def fail_every_trial_point(monkeypatch: pytest.MonkeyPatch) -> None:
    """Observation blocks evaluate at the start only; every step Ceres tries is rejected (Python
    evaluation path)."""
    monkeypatch.setenv("PBA_EVALUATION", "python")
    for cls in OBSERVATION_COSTS:
        original = cls.Evaluate

        def evaluate(self, parameters, residuals, jacobians, original=original):  # type: ignore[no-untyped-def]
            now = np.concatenate([np.asarray(p, dtype=float).ravel() for p in parameters])
            start = self.__dict__.setdefault("_start", now.copy())
            if not np.array_equal(now, start):
                return False
            return original(self, parameters, residuals, jacobians)

        monkeypatch.setattr(cls, "Evaluate", evaluate)


def test_a_failed_solve_raises_unusable_solution(monkeypatch: pytest.MonkeyPatch) -> None:
    fail_every_evaluation(monkeypatch)
    with pytest.raises(errors.UnusableSolution) as info:
        run(triplet())
    err = info.value
    assert isinstance(err, JobError) and err.code == "unusable_solution"
    detail = err.problems[0].detail
    assert detail["termination"] == "FAILURE" and detail["successful_iterations"] == 0
    assert any("FAILURE" in r for r in detail["reasons"])
    json.dumps(err.to_dict(), allow_nan=False)  # strict JSON: the service stores it as is


def test_a_solve_without_a_successful_iteration_is_not_usable(monkeypatch: pytest.MonkeyPatch) -> None:
    fail_every_trial_point(monkeypatch)
    with pytest.raises(errors.UnusableSolution) as info:
        run(triplet(max_iterations=3))
    detail = info.value.problems[0].detail
    # Ceres itself calls this usable (it ran out of iterations at the start point)
    assert detail["termination"] == "NO_CONVERGENCE"
    assert detail["successful_iterations"] == 0 and detail["iterations"] >= 3
    assert detail["reasons"] == [f"no successful iteration in {detail['iterations']}"]


def test_a_comparison_reports_an_unusable_model_as_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    fail_every_evaluation(monkeypatch)
    rep = compare(triplet(), ["K2"])
    assert rep["reports"]["K2"]["error"]["problems"][0]["code"] == "unusable_solution"


def test_outcome_reasons() -> None:
    def outcome(**kw: Any) -> backend.SolveOutcome:
        base = dict(
            iterations=5, termination="CONVERGENCE", converged=True, usable=True, message="",
            initial_cost=10.0, final_cost=1.0, time_s=0.0, linear_solver="DENSE_QR", successful_steps=4,
        )
        return backend.SolveOutcome(**{**base, **kw})

    assert outcome().unusable_reasons() == []
    # already at the optimum: Ceres converges at iteration 0, which is a usable answer
    assert outcome(iterations=1, successful_steps=0).unusable_reasons() == []
    assert "final cost is not finite" in " ".join(outcome(final_cost=math.nan).unusable_reasons())
    assert outcome(usable=False, termination="FAILURE").unusable_reasons()[0].startswith("Ceres termination FAILURE")


def test_examples_end_usable() -> None:
    """Every example adjusts to a converged, usable solution (no UnusableSolution raised)."""
    for path in sorted(EXAMPLES.glob("*.json")):
        if path.name.endswith(".truth.json"):
            continue
        rep = run(json.loads(path.read_text()))
        assert rep["adjustment"]["converged"], path.name


# -- correlations ----------------------------------------------------------------------------
def test_positive_definite_inverse_refuses_an_indefinite_matrix() -> None:
    indefinite = np.array([[1.0, 1.5], [1.5, 1.0]])  # eigenvalues 2.5 and -0.5
    with pytest.raises(np.linalg.LinAlgError):
        linalg.positive_definite_inverse(indefinite)
    with pytest.raises(np.linalg.LinAlgError):
        linalg.positive_definite_inverse(np.diag([1.0, 0.0]))


def test_positive_definite_inverse_is_an_inverse_with_correlations_in_range() -> None:
    rng = np.random.default_rng(3)
    # nearly collinear columns and very different scales (metres, radians, millimetres)
    a = rng.normal(size=(40, 6))
    a[:, 5] = a[:, 4] + 1e-7 * rng.normal(size=40)
    a *= np.array([1e-3, 1.0, 1e4, 1e2, 1e6, 1e6])
    s = a.T @ a
    inv = linalg.positive_definite_inverse(s)
    d = np.sqrt(np.diag(inv))
    rho = inv / np.outer(d, d)
    # a Gram matrix: Cauchy-Schwarz bounds every |rho| by 1, up to rounding (1e-12)
    assert np.all(np.abs(rho) <= 1.0 + 1e-12)
    # and it is the inverse: on the Jacobi-scaled matrix (condition ~1e14) the residual of
    # S^-1 S = I is bounded by cond * eps, about 1e-2; 0.05 guards against a wrong formula
    ds = np.sqrt(np.diag(s))
    scaled = (inv * np.outer(ds, ds)) @ (s / np.outer(ds, ds))
    assert np.max(np.abs(scaled - np.eye(6))) < 0.05


def test_correlations_stay_within_one_when_every_observation_is_at_one_pixel() -> None:
    """A self-calibration whose observations all sit at one pixel: a nearly singular normal
    matrix (the old dense inverse reported |rho| = inf here). Every coefficient reported is a
    correlation, or the report says why there are none."""
    doc = triplet(self_calibration={"estimate": ["df", "a0", "b0"]})
    for o in doc["observations"]:
        o["line"], o["column"] = 100.0, 200.0
    with pytest.raises(RankDeficientError, match="the datum is not determined"):  # refused by default (docs/datum.md)
        run(copy.deepcopy(doc))
    doc["options"]["datum"] = {"undetermined": "report"}
    rep = run(copy.deepcopy(doc))
    rhos = [p["rho"] for p in rep["correlations"]["pairs"]]
    assert all(-1.0 <= r <= 1.0 for r in rhos), max(map(abs, rhos))
    if not rhos:
        assert any("not positive definite" in w for w in rep["warnings"]), rep["warnings"]


def test_positive_definite_inverse_of_a_matrix_wider_than_its_strips() -> None:
    """The symmetric completion runs in column strips (512 wide): a size of two strips and a
    remainder, against numpy's general inverse, symmetric to rounding, ``s`` left unchanged."""
    rng = np.random.default_rng(7)
    a = rng.normal(size=(1200, 1100)) * np.geomspace(1e-3, 1e3, 1100)
    s = a.T @ a
    before = s.copy()
    inv = linalg.positive_definite_inverse(s)
    ref = np.linalg.inv(s)
    assert np.array_equal(s, before)  # the caller's matrix is not the work space
    assert np.array_equal(inv, inv.T)  # completed by copying, so exactly symmetric
    # condition ~1e2 after Jacobi scaling: both inverses agree to ~1e-12 of the largest entry; 1e-9
    # guards against a strip copied from the wrong place (errors of the size of the entries)
    scale = np.sqrt(np.outer(np.diag(ref), np.diag(ref)))
    assert np.max(np.abs(inv - ref) / scale) < 1e-9


def test_positive_definite_inverse_in_the_matrix_own_memory() -> None:
    """``overwrite``: the same inverse as into new memory, held in the caller's matrix (a large
    block's reduced matrix is inverted without a second matrix of its size)."""
    rng = np.random.default_rng(11)
    a = rng.normal(size=(900, 700)) * np.geomspace(1e-2, 1e2, 700)
    s = a.T @ a
    kept = linalg.positive_definite_inverse(s)
    inv = linalg.positive_definite_inverse(s, overwrite=True)
    assert np.shares_memory(inv, s)
    # the same operations in the same order: equal to rounding of the scaling's division (1e-12
    # of each entry's scale guards against a strip scaled twice or not at all)
    scale = np.sqrt(np.outer(np.diag(kept), np.diag(kept)))
    assert np.max(np.abs(inv - kept) / scale) < 1e-12
    assert np.array_equal(inv, inv.T)


def test_correlated_pairs_in_strips_equal_the_whole_correlation_matrix() -> None:
    """The pairs above a limit found strip by strip (rows of CORRELATION_STRIP) are those of the
    whole matrix's upper triangle, in the same order, at strip boundaries too; ``inclusive``
    keeps a coefficient equal to the limit."""
    from solver.quality.parameter_checks import CORRELATION_STRIP, correlated_pairs

    rng = np.random.default_rng(5)
    n = 2 * CORRELATION_STRIP + 37
    base = rng.normal(size=(n + 40, 30))
    a = base[:n] @ rng.normal(size=(30, n)) + 0.3 * rng.normal(size=(n, n))  # strongly correlated columns
    q = np.linalg.inv(a.T @ a + np.eye(n))
    d = np.sqrt(np.diag(q))
    rho = np.clip(q / np.outer(d, d), -1.0, 1.0)
    iu = np.triu_indices(n, k=1)
    limit = float(np.quantile(np.abs(rho[iu]), 0.98))
    want = np.flatnonzero(np.abs(rho[iu]) > limit)
    ii, jj, vals = correlated_pairs(q, limit)
    assert len(want) > 100 and np.array_equal(ii, iu[0][want]) and np.array_equal(jj, iu[1][want])
    assert np.all(ii < jj) and (ii >= CORRELATION_STRIP).any() and (ii < CORRELATION_STRIP).any()
    # the same division as the whole matrix's: equal to rounding (1e-15)
    assert np.max(np.abs(vals - rho[iu][want])) < 1e-15
    q2 = np.array([[4.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]])  # rho(0, 1) = 0.5 exactly
    assert len(correlated_pairs(q2, 0.5)[0]) == 0
    assert correlated_pairs(q2, 0.5, inclusive=True)[0].tolist() == [0]
