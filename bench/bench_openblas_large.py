"""Does OpenBLAS (the one scipy loads) factor a large matrix on several threads without crashing?
The reason for ``DENSE_PARALLEL_MAX`` in solver/engine/dense_threads.py.

Run by hand (never in CI; each size needs 8 n^2 bytes twice, 4 GB at 16,000 rows):

    .venv/bin/python bench/bench_openblas_large.py --rows 12000,15000,16000 --threads 2

For each size a fresh process builds a symmetric positive-definite matrix and factors it in place
with LAPACK's ``dpotrf`` (``scipy.linalg.lapack``, as the solver's rank check and covariance do)
on ``--threads`` BLAS threads; the line says whether it finished (and in what time) or how the
process died (a negative return code is the signal: -11 a segmentation fault, -6 an abort).
"""

from __future__ import annotations

import argparse
import subprocess
import sys

CHILD = r"""
import sys, time
import numpy as np
from scipy.linalg import lapack
from threadpoolctl import threadpool_limits
n, k = int(sys.argv[1]), int(sys.argv[2])
rng = np.random.default_rng(1)
a = np.empty((n, n))
for i in range(0, n, 2000):
    a[i : i + 2000] = rng.standard_normal((min(2000, n - i), n)) * 1e-3
a = (a + a.T) * 0.5
a[np.diag_indices(n)] += n * 1e-3 + 1.0
t = time.perf_counter()
with threadpool_limits(limits=k, user_api="blas"):
    factor, info = lapack.dpotrf(a.T, lower=1, clean=0, overwrite_a=1)
print(f"info {info}, {time.perf_counter() - t:.1f} s")
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", default="12000,15000,16000")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    for n in [int(x) for x in args.rows.split(",")]:
        out = subprocess.run([sys.executable, "-c", CHILD, str(n), str(args.threads)], capture_output=True, text=True)
        said = out.stdout.strip().splitlines()[-1] if out.stdout.strip() else ""
        state = f"finished ({said})" if out.returncode == 0 else f"died, return code {out.returncode}"
        print(f"{n:,} rows on {args.threads} threads: {state}", flush=True)


if __name__ == "__main__":
    main()
