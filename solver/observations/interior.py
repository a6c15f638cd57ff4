"""Interior orientation (self-calibration) of the cameras: parameters, priors, report, export.

Equations in docs/models.md section 8 and :func:`solver.kernels.camera_model`. Every camera has
a full IOP vector (``N_IOP``): the optical parameters ``x0, y0, df, k1, k2, sy`` then, per chip
in the order of ``camera.chips``, ``a0, b0, a1, b1, delta`` (named ``a0@<chip id>``). Values
come from ``camera.iop`` (default 0). ``options.self_calibration`` chooses which are estimated:
they form one Ceres parameter block per camera, shared by all images of that camera; the
master chip's parameters stay fixed; some are weighted (seed 001: a0, b0 with 1.5 px,
a1, b1 with 300 ppm). A camera reused with ``iop_use = "weighted"`` adds its exported values and
covariance as a weighted observation of the same parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from solver.errors import Problem
from solver.kernels.layout import MAX_CHIPS
from solver.observations.cameras import CameraState, build_cameras, chip_ids, default_master_chip, expand_estimate
from solver.observations.family import Count, FamilyDefaults, Labelled, ReportContext
from solver.schema.job import Job

UNITS = {"x0": "mm", "y0": "mm", "df": "mm", "k1": "mm^-2", "k2": "mm^-4", "sy": "1",
         "a0": "mm", "b0": "mm", "a1": "1", "b1": "1", "delta": "rad"}


def validate_self_calibration(job: Job) -> list[tuple[str, str, tuple]]:
    """(code, message, location) of every self-calibration problem."""
    out = []
    sc = job.options.self_calibration
    if sc is None:
        # the kernels' IOP vector holds MAX_CHIPS chips: a camera with more chips can be used
        # without interior orientation only (its chips' offsets are in each observation's constants)
        return [("too_many_chips", f"camera {cam.id!r} has interior-orientation values (iop) and more than {MAX_CHIPS} chips",
                 ("cameras",)) for cam in job.cameras if cam.iop and len(chip_ids(cam)) > MAX_CHIPS]
    ids = {c.id for c in job.cameras}
    for cid in sc.cameras or []:
        if cid not in ids:
            out.append(("unknown_camera", f"self_calibration names unknown camera {cid!r}", ("options", "self_calibration", "cameras")))
    for cam in job.cameras:
        if len(chip_ids(cam)) > MAX_CHIPS:
            out.append(("too_many_chips", f"camera {cam.id!r} has more than {MAX_CHIPS} chips", ("cameras",)))
            continue
        master = sc.master_chip.get(cam.id)
        if master is not None and master not in chip_ids(cam):
            out.append(("unknown_chip", f"master chip {master!r} is not a chip of camera {cam.id!r}", ("options", "self_calibration", "master_chip")))
        try:
            expand_estimate(sc.estimate, cam, master or default_master_chip(cam))
        except ValueError as exc:
            out.append(("unknown_iop", str(exc), ("options", "self_calibration", "estimate")))
    for k in sc.sigmas:
        if k not in UNITS:
            out.append(("unknown_iop", f"unknown interior-orientation parameter {k!r} in sigmas", ("options", "self_calibration", "sigmas")))
    return out


def n_iop_unknowns(job: Job) -> tuple[int, int]:
    """(estimated IOP, weighted IOP pseudo-observations) of a valid job."""
    n_unk = n_obs = 0
    for st in build_cameras(job):
        n_unk += st.nfree
        n_obs += int(np.sum(np.isfinite(st.sigma)))
        if st.reuse_cov is not None:
            n_obs += len(st.reuse_cov[0])
    return n_unk, n_obs


@dataclass
class CameraPrior:
    """Weighted observations of a camera's free IOP: ``r = W (p[pos] - mean)`` (W = chol^-T)."""

    camera_index: int
    pos: np.ndarray
    mean: np.ndarray
    w: np.ndarray  # (m, m) whitening matrix
    nfree: int

    @property
    def n_residuals(self) -> int:
        return len(self.pos)

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        jac = np.zeros((len(self.pos), self.nfree))
        jac[:, self.pos] = self.w
        return self.w @ (params[self.pos] - self.mean), jac

    def linear_form(self) -> tuple[np.ndarray, np.ndarray]:
        a = np.zeros((len(self.pos), self.nfree))
        a[:, self.pos] = self.w
        return a, self.w @ self.mean


def camera_priors(cameras: list[CameraState]) -> list[CameraPrior]:
    out = []
    for st in cameras:
        weighted = np.flatnonzero(np.isfinite(st.sigma))
        if len(weighted):
            out.append(CameraPrior(st.index, weighted, st.base[st.free_idx[weighted]].copy(), np.diag(1.0 / st.sigma[weighted]), st.nfree))
        if st.reuse_cov is not None:
            pos, mean, cov = st.reuse_cov
            chol = np.linalg.cholesky(cov)
            out.append(CameraPrior(st.index, pos, mean, np.linalg.inv(chol), st.nfree))
    return out


def cameras_report(cameras: list[CameraState], cov_block, var_factor: float) -> list[dict[str, Any]]:
    """Report entries of the cameras with interior orientation (values, sigmas, covariance).

    ``cov_block(camera_index)`` returns the camera's free-parameter covariance (a-priori scale)
    or None. Shape follows what the service's camera library reads: ``iop`` {name: value} and
    ``iop_covariance`` {names, matrix}.
    """
    out = []
    for st in cameras:
        if not st.has_iop:
            continue
        vals = st.values()
        cov = cov_block(st.index) if st.nfree else None
        free_names = [st.names[i] for i in st.free_idx]
        params = []
        for q, name in enumerate(st.names):
            est = name in free_names
            sigma = None
            if est and cov is not None:
                sigma = float(math.sqrt(max(cov[free_names.index(name), free_names.index(name)] * var_factor, 0.0)))
            if est or vals[q] != 0.0:
                base = name.split("@")[0]
                params.append({
                    "name": name,
                    "value": float(vals[q]),
                    "sigma": sigma,
                    "unit": UNITS[base],
                    "estimated": est,
                    "significant": None if sigma is None else bool(abs(vals[q]) >= sigma),
                })
        out.append({
            "id": st.id,
            "master_chip": st.master_chip,
            "parameters": params,
            "iop": {p["name"]: p["value"] for p in params},
            "iop_covariance": None if cov is None else {"names": free_names, "matrix": (cov * var_factor).tolist()},
        })
    return out


class NoEstimatedCamera(LookupError):
    """The job has no such camera, or its report no estimated interior orientation of it."""


def camera_from_report(job: dict[str, Any], report: dict[str, Any], camera_id: str) -> dict[str, Any]:
    """A camera definition for reuse: the job's camera ``camera_id`` (every field it has:
    ``id``, ``ref``, ``iop_use``, the focal plane and chips) with the interior orientation the
    report estimated for it (values in mm merged over the job's, and the report's covariance,
    mm², or none: a covariance the job carried describes other values).

    Reads ``report["cameras"]``: ``[{"id", "iop": {name: value}, "iop_covariance": {"names",
    "matrix"}}]``. Raises :class:`NoEstimatedCamera` (a sentence saying which) when the job has
    no such camera or the report estimated none for it (not a self-calibration job).
    """
    cam = next((c for c in job.get("cameras", []) if isinstance(c, dict) and c.get("id") == camera_id), None)
    if cam is None:
        raise NoEstimatedCamera(f"the job has no camera {camera_id!r}")
    entry = next(
        (c for c in report.get("cameras") or [] if isinstance(c, dict) and c.get("id") == camera_id), None
    )
    if not entry or not entry.get("iop"):
        raise NoEstimatedCamera(
            f"the report has no estimated interior orientation for camera {camera_id!r} "
            "(was it a self-calibration job?)"
        )
    out = {k: v for k, v in cam.items() if k not in ("iop", "iop_covariance")}
    out["iop"] = {**(cam.get("iop") or {}), **entry["iop"]}
    if entry.get("iop_covariance"):
        out["iop_covariance"] = entry["iop_covariance"]
    return out


class InteriorFamily(FamilyDefaults):
    """Interior orientation as an observation family: the cameras' estimated IOP (unknowns of
    their own block) and their priors (weighted defaults, a reused camera's covariance), not
    tested; report section ``cameras``."""

    name = "interior"

    def check(self, job: Job) -> tuple[list[Problem], Count]:
        issues = [Problem(code, msg, loc) for code, msg, loc in validate_self_calibration(job)]
        if issues:
            return issues, Count()
        n_unk, n_obs = n_iop_unknowns(job)
        return [], Count(n_observations=n_obs, n_unknowns=n_unk)

    def terms(self, problem) -> list[Labelled]:
        return [Labelled(self, p, "camera", p.camera_index) for p in camera_priors(problem.cameras)]

    def report(self, problem, ctx: ReportContext) -> dict[str, Any]:
        def block(ci: int):
            return ctx.block("camera", ci, problem.cameras[ci].nfree)

        return {"cameras": cameras_report(problem.cameras, block, ctx.var_factor)}


FAMILY = InteriorFamily()
