"""The projection kernel alone: microseconds per image observation on one core, residuals only and
with the Jacobians, over every observation of bench_scale.py's connected strip.

Run by hand (never in CI), on a quiet machine:

    .venv/bin/python bench/bench_kernels.py                            # P2, 100,000 observations
    .venv/bin/python bench/bench_kernels.py --model OA-J2 --observations 30000
    .venv/bin/python bench/bench_kernels.py --model PASS-J2 --strip    # the simulator's strip (the pass models need it)
    .venv/bin/python bench/bench_kernels.py --save a.npy               # keep the lines, columns and a derivative
    .venv/bin/python bench/bench_kernels.py --compare a.npy            # ... and compare another tree's with them

The loop calls ``project_observation`` (what the observation blocks call for each record) with
the image's current coefficients, as ``solver.engine.linalg.linearise`` does, and keeps each
result so that nothing is optimised away. The medians of ``--repeat`` passes are printed (the
first pass, which loads or compiles the kernels, is not timed). ``--compare`` prints the largest
differences of line, column and three derivatives against a file of ``--save``: run it in two
trees to check a change of the kernels leaves the numbers as they were.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parents[1]), str(Path(__file__).resolve().parent)]

import numpy as np  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--observations", type=int, default=100_000)
    ap.add_argument("--model", default="P2")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--strip", action="store_true", help="bench_scale's --strip block (any model) instead of the connected strip")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--save", type=Path, default=None)
    ap.add_argument("--compare", type=Path, default=None)
    args = ap.parse_args()

    import bench_scale
    from numba import njit

    from solver.engine.packed_tables import current_tables, records
    from solver.kernels.layout import IT_BASE, IT_FREE, IT_KIND, IT_NFREE, KC_START, REC_IMAGE, REC_OC, REC_PASS_SLOT
    from solver.kernels.projection import project_observation
    from solver.procedures.single import prepare
    from solver.schema.job import load_job

    path = bench_scale.generate(args.observations, args.model, args.seed, "strip" if args.strip else "connected", True)
    problem = prepare(load_job(json.loads(Path(path).read_text())))
    sel = np.flatnonzero(problem.adjusted_mask)
    img_tab, _cam_tab, img_p, _cam_p = current_tables(problem)
    rec = records(problem, sel)
    pts = np.ascontiguousarray(np.array([p.xyz for p in problem.points], dtype=float).reshape(-1, 3))
    obs_pt = np.ascontiguousarray(problem.obs.pt[sel])

    @njit(nogil=True)
    def every_observation(rec, img_tab, img_p, pts, obs_pt, want, out):
        for i in range(rec.shape[0]):
            r = rec[i]
            im = int(r[REC_IMAGE])
            it = img_tab[im]
            coef = it[IT_BASE:KC_START].copy()
            for j in range(int(it[IT_NFREE])):
                coef[int(it[IT_FREE + j])] = img_p[im, j]
            got = project_observation(int(it[IT_KIND]), coef, it[KC_START:], pts[obs_pt[i]], r[REC_OC:REC_PASS_SLOT], coef[:0], 0,
                                      0.0, want)
            out[i, 0] = got[1]
            out[i, 1] = got[2]
            if want:
                out[i, 2] = got[3][0]
                out[i, 3] = got[4][1]
                out[i, 4] = got[5][2]

    out = np.zeros((rec.shape[0], 5))
    n = rec.shape[0]
    print(f"{args.model}: {n:,} observations, {len(problem.images)} images")
    for want in (False, True):
        every_observation(rec, img_tab, img_p, pts, obs_pt, want, out)
        times = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            every_observation(rec, img_tab, img_p, pts, obs_pt, want, out)
            times.append(time.perf_counter() - t)
        label = "with Jacobians" if want else "residuals only"
        print(f"  {label}: median {statistics.median(times) * 1e6 / n:.3f} us per observation "
              f"(min {min(times) * 1e6 / n:.3f}, {args.repeat} passes)")
    if args.save:
        np.save(args.save, out)
    if args.compare:
        ref = np.load(args.compare)
        diff = np.abs(out - ref).max(axis=0)
        print(f"  largest difference against {args.compare}: line {diff[0]:.3g} px, column {diff[1]:.3g} px, "
              f"derivatives {diff[2]:.3g}, {diff[3]:.3g}, {diff[4]:.3g}")


if __name__ == "__main__":
    main()
