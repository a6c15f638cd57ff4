"""Linear-solver benchmark: Ceres' Schur solvers on the same problem, alternated in one process.

Run by hand (never in CI):

    .venv/bin/python bench/bench_linear_solver.py --observations 100000
    .venv/bin/python bench/bench_linear_solver.py --observations 300000 --solvers SPARSE_SCHUR,DENSE_SCHUR --repeat 3
    .venv/bin/python bench/bench_linear_solver.py --observations 300000 --solvers ITERATIVE_SCHUR:SCHUR_JACOBI

The job is bench_scale.py's (a connected strip by default, the same cached JSON). Each solve
starts from freshly prepared initial values and differs from the service's only in Ceres'
``linear_solver_type`` (and ``preconditioner_type`` after a colon); the solvers run in turn
(A B C A B C ...) so that a machine whose speed drifts (other processes) treats them alike.
Printed per solve: iterations, final cost, the solve's wall and CPU seconds, and Ceres' own
split (residuals, Jacobians, linear solver, preprocessor); then per solver the medians. A
solver that changes the iterations or the final cost (relative 1e-9) is flagged: only a choice
that reaches the same solution in the same iterations is a pure speed choice.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path[:0] = [str(Path(__file__).resolve().parents[1]), str(Path(__file__).resolve().parent)]

DEFAULT_SOLVERS = "SPARSE_SCHUR,DENSE_SCHUR"


def solve_with(doc: dict[str, Any], spec: str) -> dict[str, Any]:
    """One solve of ``doc`` from its initial values with the linear solver ``spec`` (TYPE[:PRECONDITIONER])."""
    from bench_scale import _linear_solver  # the override bench_scale's --linear-solver applies

    from solver.engine import backend
    from solver.procedures.single import prepare, solve_problem
    from solver.schema.job import load_job
    from solver.schema.settings import JobSettings

    problem = prepare(load_job(doc))
    options = backend.ceres_options
    _linear_solver(backend, spec)
    try:
        control = backend.SolveControl(None, None, JobSettings.from_options(problem.job.options).solve.max_iterations)
        w0, c0 = time.perf_counter(), time.process_time()
        outcome = solve_problem(problem, control)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    finally:
        backend.ceres_options = options
    return {"solver": spec, "used": outcome.linear_solver, "iterations": outcome.iterations, "final_cost": outcome.final_cost,
            "wall_s": wall, "cpu_s": cpu, "ceres_s": dict(outcome.timing_s), "load": os.getloadavg()[0]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--observations", type=int, default=100000)
    ap.add_argument("--model", default="P2")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--disjoint", action="store_true", help="bench_scale's disjoint layout instead of the connected strip")
    ap.add_argument("--solvers", default=DEFAULT_SOLVERS, help="comma-separated TYPE[:PRECONDITIONER] (Ceres' names)")
    ap.add_argument("--repeat", type=int, default=2, help="rounds of the alternation")
    args = ap.parse_args()
    import bench_scale

    path = bench_scale.generate(args.observations, args.model, args.seed, "disjoint" if args.disjoint else "connected", True)
    doc = json.loads(path.read_text())
    print(f"{path}: {len(doc['observations'])} observations, {len(doc['images'])} images", flush=True)
    solvers = args.solvers.split(",")
    runs: dict[str, list[dict[str, Any]]] = {s: [] for s in solvers}
    for _ in range(args.repeat):
        for spec in solvers:
            r = solve_with(doc, spec)
            runs[spec].append(r)
            inside = " ".join(f"{k} {v:.2f}" for k, v in r["ceres_s"].items())
            print(f"  {spec:<36} [{r['used']}, load {r['load']:.1f}] {r['iterations']} iterations, final cost {r['final_cost']!r}, "
                  f"solve {r['wall_s']:.2f} s wall {r['cpu_s']:.2f} s CPU (in Ceres: {inside})", flush=True)
    ref = runs[solvers[0]][0]
    print("medians:")
    for spec, rs in runs.items():
        same = all(r["iterations"] == ref["iterations"] and abs(r["final_cost"] - ref["final_cost"]) <= 1e-9 * abs(ref["final_cost"]) for r in rs)

        def med(f) -> float:
            return statistics.median(f(r) for r in rs)

        print(f"  {spec:<36} solve {med(lambda r: r['wall_s']):.2f} s wall {med(lambda r: r['cpu_s']):.2f} s CPU, "
              f"linear solver {med(lambda r: r['ceres_s']['linear_solver']):.2f} s, "
              f"{'same iterations and final cost as ' + solvers[0] if same else 'DIFFERENT iterations or final cost'}")


if __name__ == "__main__":
    main()
