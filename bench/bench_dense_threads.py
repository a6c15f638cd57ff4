"""Dense factorisations on one and on several BLAS threads, on an idle machine and beside busy
processes (the reason for solver/engine/dense_threads.py).

Run by hand (never in CI):

    .venv/bin/python bench/bench_dense_threads.py                  # the machine as it is
    .venv/bin/python bench/bench_dense_threads.py --busy 2         # beside 2 processes doing BLAS work

For each size: the Cholesky factor and inverse (LAPACK dpotrf + dpotri, what the covariance of
the reduced system does) of a random positive-definite matrix, medians of several runs, on 1
thread and on every core; then the number of threads the solver's rule picks at that moment.
``--busy K`` starts K processes that multiply 800-square matrices in a loop (as other workers'
solves would) and stops them at the end.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _burn(stop: mp.Event) -> None:  # type: ignore[valid-type]
    import numpy as np

    a = np.random.default_rng(0).standard_normal((800, 800))
    while not stop.is_set():
        a = np.tanh(a @ a.T * 1e-3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="420,1200,2400,5400")
    ap.add_argument("--busy", type=int, default=0, help="competing BLAS processes")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    import numpy as np
    from scipy.linalg import lapack

    from solver.engine import dense_threads

    stop = mp.Event()
    burners = [mp.Process(target=_burn, args=(stop,), daemon=True) for _ in range(args.busy)]
    for p in burners:
        p.start()
    time.sleep(1.0 if burners else 0.0)
    cores = len(os.sched_getaffinity(0))
    rng = np.random.default_rng(1)
    try:
        for n in [int(v) for v in args.sizes.split(",")]:
            a = rng.standard_normal((n, n))
            s = a @ a.T + n * np.eye(n)
            row = [f"{n:6d} rows"]
            for threads in sorted({1, cores}):
                times = []
                with dense_threads.limited(threads):
                    for _ in range(args.repeat if n < 3000 else max(2, args.repeat // 2)):
                        w = np.asfortranarray(s)
                        t0 = time.perf_counter()
                        f, _ = lapack.dpotrf(w, lower=1, overwrite_a=1)
                        lapack.dpotri(f, lower=1, overwrite_c=1)
                        times.append(time.perf_counter() - t0)
                row.append(f"{threads} thread{'s' if threads > 1 else ''}: median {statistics.median(times):.4f} s (max {max(times):.4f})")
            row.append(f"rule picks {dense_threads.threads_for(n)}")
            print("  ".join(row), f"load {os.getloadavg()[0]:.1f}", flush=True)
    finally:
        stop.set()
        for p in burners:
            p.join(5)


if __name__ == "__main__":
    main()
