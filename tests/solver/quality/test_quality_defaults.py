"""Issue 15, "done when": on the simulated triplet with realistic attitude (drift and a slow
oscillation) and 4 control points with the ephemeris weighted, the default orbit-attitude and
pass models give a 3D check RMSE within twice that of full control (22 control points).

Independent evidence: the scene comes from the physical simulator (``solver.simulate``: its own
J2-J4 orbit, attitude drift with rates and an acceleration in the orbital frame, a sinusoidal
oscillation, noise), not from the models adjusted; the check points' known coordinates are its
truth. Measured over more seeds and settings in docs/quality.md (bench/bench_quality.py
defaults)."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
import pytest

from solver.adjust import adjust_job
from solver.schema.job import load_job
from solver.simulate.presets import prism_triplet
from solver.simulate.scene import SceneSettings

EPHEMERIS = {"ephemeris": {"sigma_position_m": 2.0, "sigma_velocity_m_s": 0.01}}


def _scene(gcps: int) -> dict:
    s = SceneSettings(preset="prism-triplet", seed=1, model="PASS-J2", job_options=copy.deepcopy(EPHEMERIS))
    # the simulator's default drift (rates 1e-6/1e-6/1e-5 rad/s, acceleration 1e-8 rad/s^2) and
    # a slow oscillation: 2 urad at 0.05 Hz (a 20-s period over a 6-s image: a curvature the
    # linear terms cannot follow exactly)
    s = replace(s, jitter_rad=2e-6, jitter_hz=0.05)
    assert s.attitude_rate_rad_s != (0.0, 0.0, 0.0) and s.attitude_accel_rad_s2 > 0
    return prism_triplet(s, gcps=gcps, checks=20, tie_points=40).job()


def _rmse3d(report: dict) -> float:
    pts = report["checkpoints"]["points"]
    assert len(pts) == 20
    return float(np.sqrt(np.mean([sum(p["discrepancy_m"][a] ** 2 for a in "enu") for p in pts])))


@pytest.mark.parametrize("model", ["PASS-J2", "OA-J2"])
def test_default_models_with_four_control_points_stay_within_twice_full_control(model: str) -> None:
    rmse = {}
    for gcps in (22, 4):
        job = _scene(gcps)
        for im in job["images"]:
            im["model"] = {"name": model, "options": {}}  # the model's defaults
        rep = adjust_job(load_job(job))
        rmse[gcps] = _rmse3d(rep)
    # the criterion of the issue (2x); measured on this seed 1.15 (PASS-J2) and 1.07 (OA-J2)
    assert rmse[4] < 2.0 * rmse[22], rmse
    # and full control is itself sane here (measured 2.1-3.0 m: 0.5-px noise at 2.5-m GSD plus
    # the model error of the drift): a broken scene would make the ratio meaningless
    assert rmse[22] < 5.0, rmse
