"""Weighted observations of an image's platform state (header or ephemeris values).

The position at line 0 and the velocity of every platform model are linear in its parameters:

* polynomial models (LGS): S(0) = (X0, Y0, Z0); dS/dt(0) = (X1, Y1, Z1) / (dt/dtau);
* Kepler/J2 models (ECEF): S(0) = (X0, Y0, Z0); dS/dt(0) = (ux, uy, uz).

So the prior is ``r = W (A p - b)`` with a constant selection matrix ``A`` (6 x nfree), the
observed state ``b`` expressed in the model's frame, and ``W`` = diag(1/sigma). The same
(A, b, W) feed Ceres and the covariance (one place for the equation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solver.observations.ephemeris import image_state
from solver.platforms import coef_index
from solver.state import AdjustmentState, ImageState, is_kepler


@dataclass
class StatePrior:
    image_index: int
    a: np.ndarray  # (m, nfree)
    b: np.ndarray  # (m,)
    w: np.ndarray  # (m,) 1/sigma

    @property
    def n_residuals(self) -> int:
        return len(self.b)

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.w * (self.a @ params - self.b), self.w[:, None] * self.a


def state_prior(problem: AdjustmentState, img: ImageState) -> StatePrior | None:
    """The weighted state observation of ``img``, or None if the job gives no sigma."""
    doc = image_state(problem.job.images[img.index], problem.job.options)  # header or ephemeris
    if doc is None or doc.sigma_position_m is None:
        return None
    r = np.array(doc.position_ecef_m, dtype=float)
    v = np.array(doc.velocity_ecef_m_s, dtype=float)
    if is_kepler(img):
        pos, vel, vscale = r, v, 1.0
    else:
        pos = problem.frame.to_lgs(r)
        vel = problem.frame.vector_to_lgs(v)
        vscale = img.camera.line_time_s / img.tau_per_line  # dt/dtau
    where = {int(j): q for q, j in enumerate(img.free_idx)}
    rows_a, rows_b, rows_w = [], [], []
    for e, name in enumerate("XYZ"):
        k0 = coef_index(name, 0)
        if k0 in where:
            row = np.zeros(img.nfree)
            row[where[k0]] = 1.0
            rows_a.append(row)
            rows_b.append(pos[e])
            rows_w.append(1.0 / doc.sigma_position_m)
    if doc.sigma_velocity_m_s is not None:
        for e, name in enumerate("XYZ"):
            k1 = coef_index(name, 1)
            if k1 in where:
                row = np.zeros(img.nfree)
                row[where[k1]] = 1.0 / vscale
                rows_a.append(row)
                rows_b.append(vel[e])
                rows_w.append(1.0 / doc.sigma_velocity_m_s)
    if not rows_a:
        return None
    return StatePrior(img.index, np.array(rows_a), np.array(rows_b), np.array(rows_w))


class BiasPrior(StatePrior):
    """Weighted a-priori values of an RPC image's bias parameters (same algebra as the state)."""


def bias_prior(problem: AdjustmentState, img: ImageState) -> StatePrior | None:
    """Weighted a-priori values of an RPC image's bias parameters (``images[].bias_prior``,
    report units: px, px/px): ``r = (p_k - value) / sigma`` per named parameter."""
    given = problem.job.images[img.index].bias_prior if not img.model.kind.has_camera else {}
    if not given:
        return None
    col = {s.name: q for q, s in enumerate(img.model.parameters(img.options))}
    rows_a, rows_b, rows_w = [], [], []
    for name, prior in given.items():
        row = np.zeros(img.nfree)
        row[col[name]] = 1.0
        rows_a.append(row)
        rows_b.append(prior.value)
        rows_w.append(1.0 / prior.sigma)
    return BiasPrior(img.index, np.array(rows_a), np.array(rows_b), np.array(rows_w))


def all_state_priors(problem: AdjustmentState) -> list[StatePrior]:
    """Weighted platform states and RPC bias priors, image by image."""
    out = []
    for img in problem.images:
        for p in (state_prior(problem, img), bias_prior(problem, img)):
            if p is not None:
                out.append(p)
    return out
