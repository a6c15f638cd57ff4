"""Interior orientation (self-calibration) of the cameras: the priors and the export.

The cameras' parameters are blocks of their own (:mod:`solver.blocks.cameras`: which are
estimated, their checks, unknowns and report). Some are weighted (seed 001: a0, b0 with
1.5 px, a1, b1 with 300 ppm); a camera reused with ``iop_use = "weighted"`` adds its exported
values and covariance as a weighted observation of the same parameters. Both are this family's
terms.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from solver.blocks.cameras import CameraState, build_cameras, validate_self_calibration
from solver.errors import Problem
from solver.observations.family import Count, FamilyDefaults, Labelled
from solver.schema.job import Job


def n_iop_priors(job: Job) -> int:
    """Weighted IOP pseudo-observations of a valid job (the unknowns: :mod:`solver.blocks.cameras`)."""
    n_obs = 0
    for st in build_cameras(job):
        n_obs += int(np.sum(np.isfinite(st.sigma)))
        if st.reuse_cov is not None:
            n_obs += len(st.reuse_cov[0])
    return n_obs


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
    """Interior orientation as an observation family: the priors on the cameras' estimated IOP
    (weighted defaults, a reused camera's covariance), not tested. The cameras' blocks, their
    checks, unknowns and report section ``cameras`` are the block kind's
    (:mod:`solver.blocks.cameras`)."""

    name = "interior"

    def check(self, job: Job) -> tuple[list[Problem], Count]:
        if validate_self_calibration(job):  # the camera block kind reports them
            return [], Count()
        return [], Count(n_observations=n_iop_priors(job))

    def terms(self, problem) -> list[Labelled]:
        return [Labelled(self, p, "camera", p.camera_index) for p in camera_priors(problem.cameras)]


FAMILY = InteriorFamily()
