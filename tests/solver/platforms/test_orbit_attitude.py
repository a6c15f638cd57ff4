"""Orbit-attitude models on the physical simulator: the fitted state stays physical."""

from __future__ import annotations

import copy
import importlib.util
from pathlib import Path

import numpy as np

from solver.adjust import adjust_job
from solver.schema.job import load_job

_spec = importlib.util.spec_from_file_location("exp", Path(__file__).parents[3] / "scripts" / "experiments_orbit_models.py")
exp = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(exp)


def test_orbit_attitude_velocity_is_physical_where_position_rotation_is_not():
    job, truth = exp.simulate(2)
    results = {}
    for model in ("K2", "OA-K"):
        j = copy.deepcopy(job)
        for im in j["images"]:
            im["model"] = {"name": model, "options": {}}
        rep = adjust_job(load_job(j))
        results[model] = (rep, *exp.state_errors(rep, truth))
    k2, _dp_k2, dv_k2 = results["K2"]
    oa, _dp_oa, dv_oa = results["OA-K"]
    # bounds 1.5 x the worst of simulate(1..4) (measured 2026-11-23; this test uses seed 2)
    # both fit the images and the check points alike (sigma0 difference 0.003-0.006)
    assert abs(k2["adjustment"]["sigma0_aposteriori"] - oa["adjustment"]["sigma0_aposteriori"]) < 0.01
    assert oa["checkpoints"]["rmse_m"]["planimetric"] < 1.85  # 0.82-1.23 m
    # the position-rotation model absorbs the attitude's rotation with the orbit into the velocity
    assert dv_k2 > 530.0  # 798-801 m/s
    assert dv_oa < 15.0  # 5.8-10.3 m/s
    # and the reported velocity sigma of the orbit-attitude model covers its error
    im = oa["images"][1]
    sig = np.array([p["sigma"] for p in im["parameters"] if p["name"] in ("ux", "uy", "uz")])
    assert dv_oa < 1.8 * np.linalg.norm(sig)  # error / |sigma| 0.69-1.21


def test_ephemeris_as_observations_is_consistent_only_with_orbit_attitude():
    """Weighted state vectors (10 m, 0.05 m/s): K2 fights them (sigma0 ~560); OA-K comes close
    to them but does not pass the chi-square test on most scenes (sigma0 1.05-1.78 over
    simulate(1..4), chi2 passed on seed 3 only; 1.78 on this test's seed 2)."""
    job, truth = exp.simulate(2)
    out = {}
    for model in ("K2", "OA-K"):
        j = copy.deepcopy(job)
        for im in j["images"]:
            im["model"] = {"name": model, "options": {}}
        rep = adjust_job(load_job(exp.with_ephemeris(j)))
        out[model] = (rep, *exp.state_errors(rep, truth))
    k2, oa = out["K2"][0], out["OA-K"][0]
    # bounds about 1.5 x the worst of simulate(1..4), measured 2026-11-23
    assert k2["adjustment"]["sigma0_aposteriori"] > 370  # 556-575
    assert oa["adjustment"]["sigma0_aposteriori"] < 2  # 1.05-1.78: close, not a chi-square pass
    assert oa["checkpoints"]["rmse_m"]["planimetric"] < 3.0  # 1.2-2.8 m (2.77 m on seed 2)
    assert out["OA-K"][1] < 12.5 and out["OA-K"][2] < 0.31  # position 3.5-8.3 m, velocity 0.05-0.20 m/s
