"""Orbit-attitude models on the physical simulator: the fitted state stays physical."""

from __future__ import annotations

import copy
import importlib.util
from pathlib import Path

import numpy as np

from solver.adjust import adjust_job
from solver.job import load_job

_spec = importlib.util.spec_from_file_location("exp", Path(__file__).parents[1] / "scripts" / "experiments_orbit_models.py")
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
    # both fit the images and the check points alike
    assert abs(k2["adjustment"]["sigma0_aposteriori"] - oa["adjustment"]["sigma0_aposteriori"]) < 0.1
    assert oa["checkpoints"]["rmse_m"]["planimetric"] < 2.5
    # the position-rotation model absorbs the attitude's rotation with the orbit into the velocity
    assert dv_k2 > 300.0
    assert dv_oa < 30.0
    # and the reported velocity sigma of the orbit-attitude model covers its error
    im = oa["images"][1]
    sig = np.array([p["sigma"] for p in im["parameters"] if p["name"] in ("ux", "uy", "uz")])
    assert dv_oa < 4 * np.linalg.norm(sig) + 1.0


def test_ephemeris_as_observations_is_consistent_only_with_orbit_attitude():
    """Weighted state vectors (10 m, 0.05 m/s): K2 fights them, OA-K agrees with them."""
    job, truth = exp.simulate(2)
    out = {}
    for model in ("K2", "OA-K"):
        j = copy.deepcopy(job)
        for im in j["images"]:
            im["model"] = {"name": model, "options": {}}
        rep = adjust_job(load_job(exp.with_ephemeris(j)))
        out[model] = (rep, *exp.state_errors(rep, truth))
    k2, oa = out["K2"][0], out["OA-K"][0]
    assert k2["adjustment"]["sigma0_aposteriori"] > 50
    assert oa["adjustment"]["sigma0_aposteriori"] < 2
    assert oa["checkpoints"]["rmse_m"]["planimetric"] < 3.0
    assert out["OA-K"][1] < 30 and out["OA-K"][2] < 1.0  # position (m) and velocity (m/s) errors
