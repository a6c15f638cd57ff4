"""Self-calibration benchmark: a PRISM-like triplet (4 chips, 40 tie, 22 control, 20 check
points, true cameras with IOP errors) adjusted without IOP, with IOP (df, a0, b0 per chip), and
the full significance analysis (df, a0, b0, a1, b1). Run by hand: python bench/bench_selfcal.py
"""

from __future__ import annotations

import copy
import statistics
import sys
import time
from pathlib import Path

from solver.adjust import adjust_job
from solver.schema.job import load_job

sys.path[:0] = [str(Path(__file__).resolve().parents[1]), str(Path(__file__).resolve().parents[1] / "tests")]  # the solver package first (tests/solver is a folder of tests, not it), then tests/utils: the model-consistent scenes

from utils.scenes import block_job  # noqa: E402

TRUTH = {"df": 2.0, "a0@1": 0.03, "b0@1": -0.02, "a0@3": -0.03, "b0@4": 0.03}


def main(repeat: int = 3) -> None:
    job = block_job("K2", n_triplets=1, n_tie=40, n_gcp=22, n_check=20, seed=3, chips=4,
                    iop_truth={c: dict(TRUTH) for c in ("backward", "nadir", "forward")},
                    state_sigma=(20.0, 0.05), gcp_sigma_m=0.3)[0]
    cases = {
        "no IOP": None,
        "IOP df,a0,b0": {"estimate": ["df", "a0", "b0"], "sigmas": {"a0": None, "b0": None}},
        "significance analysis": {"estimate": ["df", "a0", "b0", "a1", "b1"], "sigmas": {"a0": None, "b0": None, "a1": None, "b1": None}, "significance_analysis": True},
    }
    adjust_job(load_job(job))  # warm-up
    for name, sc in cases.items():
        j = copy.deepcopy(job)
        j["options"]["self_calibration"] = sc
        jj = load_job(j)
        times = []
        for _ in range(repeat):
            t = time.perf_counter()
            rep = adjust_job(jj)
            times.append(time.perf_counter() - t)
        r = rep["checkpoints"]["rmse_m"]
        steps = len(rep.get("parameter_analysis", {}).get("steps", [])) or 1
        print(f"{name:<24} {statistics.median(times):7.3f} s  adjustments {steps:>2}  sigma0 {rep['adjustment']['sigma0_aposteriori']:.3f}  "
              f"check RMSE E {r['e']:.2f} N {r['n']:.2f} U {r['u']:.2f} m")


if __name__ == "__main__":
    main()
