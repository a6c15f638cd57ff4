"""Our P2 adjustment against an independent C++ Ceres program (bench/ceres_reference): the
collinearity written again in C++ (exact line search by Newton's method, differentiated by
Ceres' automatic differentiation, one block per observation), solved by Ceres from the same
start on the same exported data. Same objective, so the same minimum; the covariance at the
minimum comes from the Jacobians, so equal sigmas mean our analytic Jacobians (both evaluation
paths run the same kernels) equal the automatic ones.

The program needs g++ and Debian's libceres-dev (Eigen, glog), which ``make test`` installs for
the compiled cost functions: where those are required (PBA_REQUIRE_NATIVE=1) a failed build fails
the test instead of skipping it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from utils.scenes import block_job

from solver.api import _as_job
from solver.engine.backend import SolveControl
from solver.engine.linalg import covariance, linearise, schur
from solver.procedures.single import prepare, solve_problem
from solver.schema.settings import JobSettings

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "bench"))
from ceres_reference.reference import build, export, run  # noqa: E402

# Both solves take the same Levenberg-Marquardt steps from the same start and stop by the same
# rule; what remains is rounding (1e-10 sigma measured). A residual or Jacobian that differs
# by a convention (time scale, rotation order, sign) moves the minimum or the sigmas by far more.
SAME_MINIMUM_SIGMAS = 1e-4
SAME_SIGMA_REL = 1e-5  # the sigmas from J^T J at one minimum, by analytic and automatic Jacobians
SAME_COST_REL = 1e-6  # the minimum's chi-square / 2; printed by the program to 10 digits


@pytest.fixture(scope="module")
def reference_exe() -> Path:
    try:
        return build()
    except (subprocess.CalledProcessError, FileNotFoundError) as exc:
        detail = getattr(exc, "stderr", "") or str(exc)
        if os.environ.get("PBA_REQUIRE_NATIVE") == "1":
            pytest.fail(f"the C++ reference did not build where Ceres' headers are required: {detail[-2000:]}")
        pytest.skip(f"no C++ Ceres toolchain here: {detail[-300:]}")


@pytest.mark.parametrize("seed", [3, 4])
def test_p2_solution_and_covariance_equal_the_cpp_autodiff_program(reference_exe: Path, tmp_path: Path, seed: int) -> None:
    doc, _truth = block_job("P2", n_triplets=1, n_tie=60, n_gcp=8, n_check=4, seed=seed, state_sigma=(20.0, 0.05))
    data = tmp_path / "block.txt"
    counts = export(doc, data)
    out = tmp_path / "result.txt"
    ref = run(reference_exe, data, threads=1, out=out)
    assert ref["observations"] == counts["observations"] and ref["termination"] == "CONVERGENCE", ref
    table = np.loadtxt(out, ndmin=2)
    q_ref, sigma_ref = table[:, :14], table[:, 14:] / ref["sigma0"]

    job = _as_job(doc)
    problem = prepare(job)
    outcome = solve_problem(problem, SolveControl(None, None, JobSettings.from_options(job.options).solve.max_iterations))
    assert outcome.converged
    lin = linearise(problem)
    cov = covariance(lin, schur(lin, problem), problem)
    ours_q = np.array([img.params for img in problem.images])
    ours_sigma = np.array([np.sqrt(np.diag(cov.images)[c : c + 14]) for c in lin.layout.img_col])

    assert np.max(np.abs(ours_q - q_ref) / sigma_ref) < SAME_MINIMUM_SIGMAS
    np.testing.assert_allclose(ours_sigma, sigma_ref, rtol=SAME_SIGMA_REL)
    np.testing.assert_allclose(outcome.final_cost, ref["final_cost"], rtol=SAME_COST_REL)
