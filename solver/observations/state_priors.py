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
from typing import TYPE_CHECKING, Any

import numpy as np

from solver.blocks.platform_values import is_kepler
from solver.errors import Problem
from solver.observations.ephemeris import ephemeris_problems, ephemeris_report, image_state
from solver.observations.family import Count, FamilyDefaults, GroupSpec, Labelled, ReportContext
from solver.platforms import coef_index, get_model
from solver.schema.settings import JobSettings
from solver.state import AdjustmentState, ImageState

if TYPE_CHECKING:
    from solver.schema.job import Job

STATE_COMPONENTS = ["x", "y", "z", "vx", "vy", "vz"]


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

    def linear_form(self) -> tuple[np.ndarray, np.ndarray]:
        return self.w[:, None] * self.a, self.w * self.b


def state_prior(problem: AdjustmentState, img: ImageState) -> StatePrior | None:
    """The weighted state observation of ``img``, or None if the job gives no sigma."""
    doc = image_state(problem.job.images[img.index], JobSettings.of(problem.job).blocks.ephemeris)  # header or ephemeris
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
    given = problem.job.images[img.index].bias_prior if img.camera is None else {}  # an RPC image
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


def _count(job: "Job") -> tuple[list[Problem], Count]:
    """Ephemeris problems and the weighted states and RPC bias priors validation counts (an
    image whose model is unknown or whose options are refused is left to validation)."""
    problems: list[Problem] = []
    n = 0
    datum: set[str] = set()
    if any(im.bias_prior for im in job.images):
        datum.add("control")  # an RPC image's a-priori bias values: its own ground reference
    for i, im in enumerate(job.images):
        try:
            model = get_model(im.model.name)
        except KeyError:
            continue
        if im.rpc is not None:  # an RPC image (validation refuses an RPC model without its RPC)
            n += len(im.bias_prior)
            continue
        problems += ephemeris_problems(im, i)
        try:
            names = {p.name for p in model.parameters(im.model.options)}
        except (ValueError, TypeError, KeyError):
            continue
        state = image_state(im, JobSettings.of(job).blocks.ephemeris)  # approx_state or the interpolated ephemeris
        if state is None or state.sigma_position_m is None:
            continue
        datum.add("states")
        # the image's own position parameters (a pass model has none: its states observe the
        # pass, solver.observations.passes)
        n += sum(1 for name in ("X0", "Y0", "Z0") if name in names)
        if state.sigma_velocity_m_s is not None:
            n += sum(1 for name in ("ux", "uy", "uz", "X1", "Y1", "Z1") if name in names)
    return problems, Count(n_observations=n, datum=frozenset(datum))


def _without_states(job: "Job", removals: list[tuple]) -> "Job":
    """``job`` without the weighted line-0 state of the images ``("state_prior", image id)``: the
    state the solver used (header or interpolated ephemeris) stays as the image's unweighted
    ``approx_state`` (it still initialises the model), its ephemeris goes."""
    gone = {r[1] for r in removals if r[0] == "state_prior"}
    if not gone:
        return job
    images = []
    for im in job.images:
        if im.id in gone:
            state = image_state(im, JobSettings.of(job).blocks.ephemeris)
            state = state.model_copy(update={"sigma_position_m": None, "sigma_velocity_m_s": None})
            im = im.model_copy(update={"approx_state": state, "ephemeris": []})
        images.append(im)
    return job.model_copy(update={"images": images})


class EphemerisFamily(FamilyDefaults):
    """Weighted line-0 states (header ``approx_state`` sigmas or the interpolated ephemeris with
    ``options.ephemeris`` sigmas) and RPC bias priors, as an observation family: a weighted state
    is one test (``ephemeris_sample``, removable: the state stays unweighted), a bias prior is not
    tested; report section ``ephemeris`` (flags: ``images[].rejected_samples_s``, filled by the
    passes family, and ``rejected_states``)."""

    name = "ephemeris"

    def check(self, job: "Job") -> tuple[list[Problem], Count]:
        return _count(job)

    def terms(self, problem: AdjustmentState) -> list[Labelled]:
        return [Labelled(self, p, "image", p.image_index) for p in all_state_priors(problem)]

    def groups(self, problem: AdjustmentState, labelled: Labelled) -> list[GroupSpec]:
        term = labelled.term
        if isinstance(term, BiasPrior):  # a-priori RPC bias values: not tested, like IOP priors
            return []
        m = term.n_residuals
        image = problem.images[term.image_index].id
        return [GroupSpec("ephemeris_sample", np.arange(m), {"image": image, "time_s": None}, 1.0 / term.w, "m, m/s",
                          STATE_COMPONENTS[:m], -1.0, ("state_prior", image))]

    def report(self, problem: AdjustmentState, ctx: ReportContext) -> dict[str, Any]:
        return {"ephemeris": ephemeris_report(problem)}

    def without(self, job: "Job", removals: list[tuple]) -> tuple["Job", list[dict[str, Any]]]:
        return _without_states(job, removals), []

    def flag(self, report: dict[str, Any], removed: list[dict[str, Any]]) -> None:
        """``ephemeris.rejected_states``: the images whose weighted line-0 state was removed (the
        state stays as the image's unweighted approximate state and its ephemeris goes, so the
        image has no entry in ``ephemeris.images`` any more); ``ephemeris.images[].rejected_samples_s``
        starts empty (a pass's removed samples: :mod:`solver.observations.passes`)."""
        ephemeris = report.get("ephemeris")
        if not isinstance(ephemeris, dict):
            return
        for e in ephemeris.get("images") or []:
            e["rejected_samples_s"] = []
        ephemeris["rejected_states"] = [
            r.get("image") for r in removed if r["kind"] == "ephemeris_sample" and r.get("time_s") is None
        ]


FAMILY = EphemerisFamily()
