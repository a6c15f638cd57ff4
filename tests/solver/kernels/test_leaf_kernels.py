"""The leaf kernels (``LEAF`` options in solver/kernels/layout.py: numba's reference counting
off) keep their rule: no array returned, and nothing allocated that is not freed again.

numba without its runtime does not count references to a kernel's array arguments; that is the
point (an atomic increment and decrement per array per call), and it is safe only while such a
kernel neither returns an array (the caller would release a reference nobody took: a buffer freed
while still in use) nor receives one from a call (its reference would never be released: a leak).
Both checks run in a fresh process on a scratch copy of the package (its kernel cache empty, so
that every kernel the projections reach is compiled there and its signature can be read), with
numba's allocation statistics on.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]

_PROBE = r"""
import gc, json, sys
import numpy as np
sys.path[:0] = [sys.argv[1], sys.argv[2] + "/tests"]
from numba import types
from numba.core.registry import CPUDispatcher
from numba.core.runtime import rtsys
from utils.scenes import single_image_job
from solver.adjust import prepare
from solver.schema.job import load_job
from solver.kernels import IOP_OPTICAL, N_IOP, project, project_cam
import solver.kernels.blocks, solver.kernels.platform, solver.kernels.projection, solver.kernels.propagation, solver.kernels.rotation

calls = []
for model in ("P2", "K2", "OA-J2"):
    job, _ = single_image_job(model, seed=5, pitch_deg=-23.8)
    problem = prepare(load_job(job))
    img = problem.images[0]
    coef = img.coef()
    iop = np.zeros(N_IOP)
    iop[: len(IOP_OPTICAL)] = [0.004, -0.003, 1.5, 2e-6, 3e-10, 1e-4]
    for k in range(0, len(problem.obs.img), 7):
        p = problem.points[problem.obs.pt[k]].xyz
        oc = problem.obs.oc[k]
        for want in (False, True):
            calls.append(lambda p=p, oc=oc, want=want: project(img.kind, coef, img.kc, p, oc, want))
            calls.append(lambda p=p, oc=oc, want=want: project_cam(img.kind, coef, img.kc, p, oc, iop, 1, 25.7, want))
for call in calls:  # compile everything first
    call()
gc.collect()
before = rtsys.get_allocation_stats()
finite = 0
for _ in range(20):
    for call in calls:
        out = call()
        finite += bool(np.isfinite(out[1]) and np.isfinite(out[5]).all())
        del out
gc.collect()
after = rtsys.get_allocation_stats()

leaves, returning_arrays = [], []
def has_array(t):
    if isinstance(t, types.Array):
        return True
    if isinstance(t, types.BaseTuple):
        return any(has_array(x) for x in t.types)
    return False
for module in (solver.kernels.blocks, solver.kernels.platform, solver.kernels.projection, solver.kernels.propagation,
               solver.kernels.rotation):
    for name, obj in vars(module).items():
        if isinstance(obj, CPUDispatcher) and obj.targetoptions.get("_nrt") is False and obj.__module__ == module.__name__:
            for sig in obj.nopython_signatures:
                leaves.append(name)
                if has_array(sig.return_type):
                    returning_arrays.append(f"{name}: {sig}")
print(json.dumps({"calls": len(calls) * 20, "finite": finite,
                  "alloc": after.alloc - before.alloc, "free": after.free - before.free,
                  "mi_alloc": after.mi_alloc - before.mi_alloc, "mi_free": after.mi_free - before.mi_free,
                  "leaves": sorted(set(leaves)), "returning_arrays": returning_arrays}))
"""


def test_leaf_kernels_return_no_array_and_leak_nothing(tmp_path):
    copy = tmp_path / "root"
    shutil.copytree(ROOT / "solver", copy / "solver", ignore=shutil.ignore_patterns("__pycache__"))
    env = dict(os.environ, NUMBA_NRT_STATS="1", NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(copy))
    out = subprocess.run([sys.executable, "-c", _PROBE, str(copy), str(ROOT)], env=env, capture_output=True, text=True,
                         timeout=900, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["finite"] == got["calls"]  # every projection converged: the paths below were all taken
    # the projections of three kinds, with and without interior orientation and derivatives,
    # reach the leaves of every step (camera state, frames, gradients); all were compiled here
    for name in ("_camera_state", "_image_camera_vector", "_oa_frames_into", "_coef_gradients_into", "_oa_state_gradients",
                 "_rotation_into", "_orbital_frame_rate_into", "_derivative_factors", "_projection_terms", "_kepler_terms_into"):
        assert name in got["leaves"], (name, got["leaves"])
    assert got["returning_arrays"] == []
    # the kernels allocate (work arrays, outputs) and free all of it: not one allocation left over
    assert got["alloc"] > got["calls"]
    assert got["alloc"] == got["free"]
    assert got["mi_alloc"] == got["mi_free"]
