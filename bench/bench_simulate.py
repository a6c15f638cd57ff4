"""Simulator benchmark: generating a strip of 20 PRISM triplets (60 images) with 30000 tie
points and writing its job document (the time tests/solver/simulate/test_simulate_scene.py used to assert,
< 30 s, now measured here). Run by hand: python bench/bench_simulate.py
"""

from __future__ import annotations

import statistics
import time

from solver.simulate import presets
from solver.simulate.scene import SceneSettings


def main(repeat: int = 3) -> None:
    times = []
    for seed in range(1, repeat + 1):
        t = time.perf_counter()
        job = presets.strip(SceneSettings(preset="strip", seed=seed), triplets=20, tie_points=30000).job()
        times.append(time.perf_counter() - t)
    print(f"strip 60 images, 30000 tie points: median {statistics.median(times):.1f} s over {repeat} "
          f"({len(job['observations'])} observations)")


if __name__ == "__main__":
    main()
