"""The C++ Ceres reference (``p2_autodiff.cc`` beside this file): its input written from a P2
job's assembled problem, its build and its run. Used by bench/bench_reference.py and by the test
that compares the two solutions (tests/solver/engine/test_ceres_reference.py).

What is exported is data, not physics: the local frame's observation constants (line, column,
sigma, focal length, pixel size, principal point, column centre, tau per line; see
:mod:`solver.kernels.layout`), each image's 24 polynomial coefficients with the indices of the
free ones and their start values, the ground points (LGS, m) with their control sigmas, and the
state priors as (A, b, w) rows. The reference evaluates the collinearity itself.

Format (whitespace separated, one record per line)::

    PBA-P2 1
    images N
    nfree base[24] free_idx[nfree] start[nfree] m (A[m x nfree] b[m] w[m])      (per image)
    points M
    estimated role x y z kx ky kz sx sy sz        (role 0 tie, 1 control, 2 check; k/s nan if none)
    observations K
    image point oc[9]                              (observations of check points left out)
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

SOURCE = Path(__file__).resolve().parent / "p2_autodiff.cc"

ROLE_CODE = {"tie": 0, "gcp": 1, "check": 2}


def _row(values: Any) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(values))


STARTS = ("service", "ephemeris")


def ephemeris_start(problem) -> None:
    """Replace the service's initial attitude by the one a program holding only the ephemeris
    would take (in place): the position from the header state as before, the nominal attitude
    (flight direction and the camera's mounting pitch from the platform's vertical, no resection
    on the control points), zero
    rates; then the tie points intersected again from those rays."""
    from solver.engine.initialize import _nominal_attitude, intersect_estimated_points
    from solver.observations.ephemeris import image_state
    from solver.platforms import ANGLES, ELEMENTS, HELD, coef_index

    for img, im_doc in zip(problem.images, problem.job.images):
        state = image_state(im_doc, problem.job.options)
        v = None if state is None else np.array(state.velocity_ecef_m_s, dtype=float)
        orders = img.model.effective_orders(img.options)
        held = any(orders[ELEMENTS.index(e)] == HELD for e in ANGLES)  # then the LGS vertical, as the service
        r = None if state is None or held else np.array(state.position_ecef_m, dtype=float)
        for e, value in zip(ANGLES, _nominal_attitude(img, problem.frame, v, r)):
            if orders[ELEMENTS.index(e)] == HELD:
                continue
            for order in range(4):  # the angle and its rates
                img.base[coef_index(e, order)] = value if order == 0 else 0.0
        img.params[:] = img.base[img.free_idx]
    intersect_estimated_points(problem)


def export(doc: dict[str, Any], path: Path, start: str = "service") -> dict[str, int]:
    """Assemble ``doc`` as the solver does and write the reference's input, starting from the
    service's initial values (``start="service"``) or from the ephemeris alone (:func:`ephemeris_start`)."""
    from solver.api import _as_job
    from solver.observations.state_priors import state_prior
    from solver.procedures.single import prepare

    problem = prepare(_as_job(doc))
    if start == "ephemeris":
        ephemeris_start(problem)
    lines = ["PBA-P2 1", f"images {len(problem.images)}"]
    for img in problem.images:
        if img.model.name != "P2":
            raise ValueError(f"image {img.id}: the reference implements P2 only, not {img.model.name}")
        prior = state_prior(problem, img)
        parts = [str(img.nfree), _row(img.base), " ".join(str(int(i)) for i in img.free_idx), _row(img.params)]
        if prior is None:
            parts.append("0")
        else:
            parts += [str(prior.n_residuals), _row(prior.a), _row(prior.b), _row(prior.w)]
        lines.append(" ".join(parts))
    lines.append(f"points {len(problem.points)}")
    nan3 = np.full(3, np.nan)
    for p in problem.points:
        known = p.known_lgs if p.known_lgs is not None else nan3
        sigma = p.sigma_m if p.sigma_m is not None else nan3
        lines.append(f"{int(p.estimated)} {ROLE_CODE[p.role]} {_row(p.xyz)} {_row(known)} {_row(sigma)}")
    keep = np.flatnonzero(problem.adjusted_mask)
    lines.append(f"observations {len(keep)}")
    obs = problem.obs
    for i in keep:
        lines.append(f"{int(obs.img[i])} {int(obs.pt[i])} {_row(obs.oc[i])}")
    path.write_text("\n".join(lines) + "\n")
    return {"images": len(problem.images), "points": len(problem.points), "observations": int(len(keep))}


def build() -> Path:
    """The reference's binary, compiled once per source version into the temporary directory
    (g++, Debian's libceres-dev with Eigen and glog); CalledProcessError when it cannot."""
    digest = hashlib.sha256(SOURCE.read_bytes()).hexdigest()[:12]
    exe = Path(tempfile.gettempdir()) / f"pba-p2-autodiff-{digest}"
    if not exe.is_file():
        tmp = exe.with_suffix(".partial")
        cmd = ["g++", "-std=c++17", "-O3", "-march=native", "-DNDEBUG", "-I/usr/include/eigen3", str(SOURCE),
               "-o", str(tmp), "-lceres", "-lglog"]
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        tmp.replace(exe)
    return exe


def run(exe: Path, path: Path, threads: int = 2, out: Path | None = None, form: str = "exact",
        settings: str = "service") -> dict[str, Any]:
    """One run of the reference on an exported block: its JSON line, with ``wall_s`` (this call's
    wall time) and ``ceres_per_iteration_s`` (residuals, Jacobians and linear solver per iteration)."""
    cmd = [str(exe), str(path), "--threads", str(threads), "--form", form, "--settings", settings]
    cmd += ["--out", str(out)] if out else []
    t0 = time.perf_counter()
    res = subprocess.run(cmd, check=True, capture_output=True, text=True)
    r = json.loads(res.stdout.strip().splitlines()[-1])
    r["wall_s"] = time.perf_counter() - t0
    inside = r["residual_evaluation_s"] + r["jacobian_evaluation_s"] + r["linear_solver_s"]
    r["ceres_per_iteration_s"] = inside / max(r["iterations"], 1)
    return r
