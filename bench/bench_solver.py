"""Solver benchmark: solve time and microseconds per observation for three block sizes.

Run by hand (never in CI): ``.venv/bin/python bench/bench_solver.py [--large-only] [--repeat N]``.
Scenes are model-consistent synthetic blocks (tests/utils/scenes.py): a single scene (~30
observations), a PRISM triplet (~300) and a strip of 20 triplets (60 images, 30k tie points,
~90k observations). Prints one line per case and the median over repeats.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

from solver.adjust import adjust_job, assert_full_rank, prepare, solve_problem
from solver.engine.backend import SolveControl
from solver.schema.job import load_job

sys.path[:0] = [str(Path(__file__).resolve().parents[1]), str(Path(__file__).resolve().parents[1] / "tests")]  # the solver package first (tests/solver is a folder of tests, not it), then tests/utils: the model-consistent scenes

from utils.scenes import block_job, single_image_job  # noqa: E402

CASES = {
    "single": lambda: single_image_job("P2", n_gcp=14, n_check=9, seed=1),
    "triplet": lambda: block_job("P2", n_triplets=1, n_tie=80, n_gcp=14, n_check=9, seed=1),
    "large": lambda: block_job("P2", n_triplets=20, n_tie=1500, n_gcp=10, n_check=5, seed=1),
    # the same with the header state as a weighted observation (20 m, 0.05 m/s), as in seed 001
    "triplet-eph": lambda: block_job("P2", n_triplets=1, n_tie=80, n_gcp=14, n_check=9, seed=1, state_sigma=(20.0, 0.05)),
    "large-eph": lambda: block_job("P2", n_triplets=20, n_tie=1500, n_gcp=10, n_check=5, seed=1, state_sigma=(20.0, 0.05)),
}


def run_case(name: str, repeat: int, full: bool) -> None:
    t = time.perf_counter()
    doc, _ = CASES[name]()
    job = load_job(doc)
    gen = time.perf_counter() - t
    n_obs = len(doc["observations"])
    solves, totals, iters = [], [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        if full:
            rep = adjust_job(job)
            totals.append(time.perf_counter() - t0)
            solves.append(rep["adjustment"]["solve_time_s"])
            iters.append(rep["adjustment"]["iterations"])
        else:
            problem = prepare(job)
            assert_full_rank(problem)
            out = solve_problem(problem, SolveControl(None, None, job.options.max_iterations))
            solves.append(out.time_s)
            totals.append(time.perf_counter() - t0)
            iters.append(out.iterations)
            print("   ", {k: round(v, 3) for k, v in out.timing_s.items()}, [round(h["cost"], 1) for h in out.history])
    s = statistics.median(solves)
    print(
        f"{name:<8} images {len(doc['images']):>3} obs {n_obs:>6}  solve {s:8.3f} s  "
        f"{1e6 * s / n_obs:8.1f} us/obs  iterations {statistics.median(iters):.0f}  "
        f"total {'(with covariance+report)' if full else '(prepare+solve)'} {statistics.median(totals):.3f} s  [generation {gen:.1f} s]"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cases", default="single,triplet,large")
    ap.add_argument("--full", action="store_true", help="whole adjust_job incl. covariance and report")
    args = ap.parse_args()
    # warm-up: load the numba kernels for every block signature (one and several images)
    run_case("single", 1, args.full)
    run_case("triplet-eph", 1, args.full)
    for name in args.cases.split(","):
        run_case(name, args.repeat if not name.startswith("large") else max(1, args.repeat // 2), args.full)


if __name__ == "__main__":
    main()
