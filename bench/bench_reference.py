"""The service's adjustment against a C++ Ceres program on the same P2 block (run by hand, never
in CI; on a quiet machine).

    .venv/bin/python bench/bench_reference.py --observations 100000 --repeat 5

The reference (bench/ceres_reference/p2_autodiff.cc, built here with g++ against Debian's
libceres-dev) is what a Ceres user would write: one automatically differentiated block per
image observation, the exact line search by Newton's method differentiated through by the Jets,
SPARSE_SCHUR on both cores, the service's solver settings and statistical stop, and the
covariance of every image pair and every point from the Schur complement. It reads the block
that bench_scale.py generates, as exported after the service's assembly and initial values
(bench/ceres_reference/export_block.py), so both start from the same values.

Runs alternate (ours, then the reference) and the medians are printed:

* end to end: ours is ``solver.api.run`` on the job document (validation, assembly, initial
  values, rank check, solve, covariance and the default report); the reference is its whole
  process (reading its input, building, solving, covariance);
* per iteration: the solve's wall time over its iterations (ours includes building the Ceres
  problem), and the time inside Ceres (residuals, Jacobians, linear solver) over the iterations;
  then each of those three per iteration, both iteration counts, and the time per iteration
  outside them (ours: building the problem, Ceres' preprocessor, the iteration callback).

``--form time`` makes the reference use the collinearity at the observed line's time instead
(no line search: about half its Jacobian cost, a slightly different objective).

``--settings ceres`` gives the reference Ceres' default solver options instead of the service's
(initial trust region 1e4 instead of 1e12, Ceres' tolerances, no statistical stop): what a
program written without the service's tuning does from the same start.

``--start ephemeris`` starts the reference from the job's header alone (position and velocity of
the header state, nominal attitude, tie points intersected from those rays) instead of the
service's initial values: the program of the performance targets, "its own start from the
ephemeris".

``--check`` also solves the block in this process (our solve alone) and compares the adjusted
parameters with the reference's: the largest difference in units of the reference's standard
deviations (both stop when chi-square changes by less than 1e-3 twice, i.e. within a few
hundredths of a sigma of the minimum).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from ceres_reference.reference import STARTS, build, export, run  # noqa: E402


def exported(n_obs: int, seed: int, start: str = "service", layout: str = "disjoint", states: bool = True) -> tuple[Path, Path, dict[str, Any]]:
    """The job's JSON (bench_scale's block of that layout) and the reference's input written from it."""
    import bench_scale

    job = bench_scale.generate(n_obs, "P2", seed, layout, states)
    doc = json.loads(job.read_text())
    suffix = "" if start == "service" else f"-{start}"
    path = Path(tempfile.gettempdir()) / f"pba-p2-reference-{job.stem}{suffix}.txt"  # named after the job's cache: a new generator, a new export
    if not path.is_file():
        export(doc, path, start)
    return job, path, doc


def ours(job: Path) -> dict[str, Any]:
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, str(HERE / "bench_scale.py"), "--child", str(job)],
                         check=True, capture_output=True, text=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    r["process_s"] = time.perf_counter() - t0
    inside = sum(r["ceres_s"].get(k, 0.0) for k in ("residual_evaluation", "jacobian_evaluation", "linear_solver"))
    r["ceres_per_iteration_s"] = inside / max(r["iterations"], 1)
    return r


def check(doc: dict[str, Any], exe: Path, path: Path, threads: int) -> dict[str, float]:
    """Our solve and the reference's on the same block: the largest parameter difference in the
    reference's sigmas, and both sigma0."""
    from solver.api import _as_job
    from solver.engine.backend import SolveControl
    from solver.procedures.single import prepare, solve_problem
    from solver.schema.settings import JobSettings

    out = Path(tempfile.gettempdir()) / "pba-p2-reference-result.txt"
    ref = run(exe, path, threads, out)
    table = np.loadtxt(out, ndmin=2)
    job = _as_job(doc)
    problem = prepare(job)
    solve_problem(problem, SolveControl(None, None, JobSettings.from_options(job.options).solve.max_iterations))
    q_ours = np.array([img.params for img in problem.images])
    q_ref, sigma_ref = table[:, :14], table[:, 14:]
    return {"max_difference_sigma": float(np.max(np.abs(q_ours - q_ref) / sigma_ref)), "sigma0_reference": ref["sigma0"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--observations", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2, help="the reference's threads (ours: PBA_SOLVER_THREADS)")
    ap.add_argument("--check", action="store_true", help="also compare the adjusted parameters")
    ap.add_argument("--form", choices=["exact", "time"], default="exact",
                    help="the reference's residual: the exact projection (the same objective as ours) or the "
                    "collinearity at the observed line's time (cheaper, a slightly different objective)")
    ap.add_argument("--settings", choices=["service", "ceres"], default="service",
                    help="the reference's solver options: the service's (trust region 1e12, statistical stop) or "
                    "Ceres' defaults, as a Ceres user who keeps them")
    ap.add_argument("--start", choices=list(STARTS), default="service",
                    help="the reference's initial values: the service's (exported after its initial values) or "
                    "the ephemeris alone (header position and velocity, nominal attitude, tie points intersected "
                    "from those rays: what a program without the service's resection on control points starts from)")
    ap.add_argument("--connected", action="store_true", help="bench_scale's connected strip instead of the 100k P2 block of "
                    "disjoint triplets (bench_scale.py --disjoint)")
    ap.add_argument("--no-states", action="store_true", help="with --connected: header states not weighted")
    args = ap.parse_args()
    exe = build()
    job, path, doc = exported(args.observations, args.seed, args.start, "connected" if args.connected else "disjoint", not args.no_states)
    if args.check:
        print("solutions:", json.dumps(check(doc, exe, path, args.threads)), flush=True)
    mine, theirs = [], []
    for k in range(args.repeat):
        mine.append(ours(job))
        theirs.append(run(exe, path, args.threads, form=args.form, settings=args.settings))
        a, b = mine[-1], theirs[-1]
        print(f"run {k + 1}: ours {a['run_s']:.2f} s end to end ({a['process_s']:.2f} s process), {a['iterations']} it, "
              f"{a['per_iteration_s']:.3f} s/it ({a['ceres_per_iteration_s']:.3f} in Ceres), sigma0 {a['sigma0']:.4f} | "
              f"reference {b['process_s']:.2f} s process (solve {b['solve_s']:.2f}, covariance {b['covariance_s']:.2f}), "
              f"{b['iterations']} it, {b['per_iteration_s']:.3f} s/it ({b['ceres_per_iteration_s']:.3f} in Ceres), "
              f"sigma0 {b['sigma0']:.4f}", flush=True)

    def med(runs: list[dict[str, Any]], key: str) -> float:
        return statistics.median(r[key] for r in runs)

    e2e = med(mine, "run_s") / med(theirs, "process_s")
    per_it = med(mine, "per_iteration_s") / med(theirs, "per_iteration_s")
    inside = med(mine, "ceres_per_iteration_s") / med(theirs, "ceres_per_iteration_s")
    print(f"medians of {args.repeat}: end to end ours {med(mine, 'run_s'):.2f} s / reference {med(theirs, 'process_s'):.2f} s = {e2e:.2f}; "
          f"per iteration {med(mine, 'per_iteration_s'):.3f} / {med(theirs, 'per_iteration_s'):.3f} s = {per_it:.2f} "
          f"(inside Ceres {med(mine, 'ceres_per_iteration_s'):.3f} / {med(theirs, 'ceres_per_iteration_s'):.3f} s = {inside:.2f})")
    for name in ("residual_evaluation", "jacobian_evaluation", "linear_solver"):
        a = statistics.median(r["ceres_s"].get(name, 0.0) / max(r["iterations"], 1) for r in mine)
        b = statistics.median(r[f"{name}_s"] / max(r["iterations"], 1) for r in theirs)
        print(f"  {name} per iteration: ours {1e3 * a:.1f} ms / reference {1e3 * b:.1f} ms = {a / b if b else float('nan'):.2f}")
    print(f"  iterations: ours {med(mine, 'iterations'):.0f}, reference {med(theirs, 'iterations'):.0f}; "
          f"ours outside Ceres' three per iteration (problem building, callback, preprocessing) "
          f"{med(mine, 'per_iteration_s') - med(mine, 'ceres_per_iteration_s'):.3f} s, reference "
          f"{med(theirs, 'per_iteration_s') - med(theirs, 'ceres_per_iteration_s'):.3f} s; "
          f"our preprocessor {statistics.median(r['ceres_s'].get('preprocessor', 0.0) for r in mine):.2f} s")


if __name__ == "__main__":
    main()
