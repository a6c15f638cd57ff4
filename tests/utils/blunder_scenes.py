"""Scenes with injected blunders shared by the quality tests (the same injection as
bench/bench_snooping.py ``blunders``, so a seed here is the bench's seed)."""

from __future__ import annotations

from typing import Any

import numpy as np


def prism_single_with_blunders(seed: int = 4) -> tuple[dict[str, Any], set[str]]:
    """prism-single of the independent simulator (model K2), four image blunders of 5-30 px on
    control image points and one more control point's survey moved 10-30 m; the job and the
    ids of the points with a blunder."""
    from solver.simulate import presets
    from solver.simulate.scene import SceneSettings

    job = presets.prism_single(SceneSettings(preset="prism-single", seed=seed, model="K2")).job()
    rng = np.random.default_rng(1000 + seed)
    roles = {p["id"]: p["role"] for p in job["points"]}
    injected: set[str] = set()
    used: set[str] = set()
    for i in rng.permutation([i for i, o in enumerate(job["observations"]) if roles[o["point"]] != "check"]):
        o = job["observations"][i]
        if len(injected) >= 4 or o["point"] in used:
            continue
        used.add(o["point"])
        mag, ang = rng.uniform(5, 30), rng.uniform(0, 2 * np.pi)
        o["line"] += mag * np.cos(ang)
        o["column"] += mag * np.sin(ang)
        injected.add(o["point"])
    gcps = [p for p in job["points"] if p["role"] == "gcp" and p.get("sigma_m") and p["id"] not in used]
    p = gcps[int(rng.permutation(len(gcps))[0])]
    mag, ang = rng.uniform(10, 30), rng.uniform(0, 2 * np.pi)
    p["coordinates"][0] += mag * np.cos(ang) / (111320.0 * np.cos(np.radians(p["coordinates"][1])))
    p["coordinates"][1] += mag * np.sin(ang) / 110540.0
    injected.add(p["id"])
    return job, injected
