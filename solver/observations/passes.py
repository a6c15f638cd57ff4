"""The weighted states of the pass-propagated models as an observation family: ephemeris
samples at their epochs and header states at an image's first line observe the propagated pass
state (the passes themselves, their segments, initial states, validation and report, are the
block kind :mod:`solver.blocks.passes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from solver.blocks.passes import pass_images, pass_problems
from solver.errors import Problem
from solver.kernels.layout import KC_ATT_BASE, N_KEPLER_CONST, NODE_STEP_S, PASS_NODES, PASS_STEP, PASS_T0, PASS_T_OFF, PASS_X0, segment_length
from solver.observations.ephemeris import image_state, usable
from solver.observations.family import Count, FamilyDefaults, GroupSpec, Labelled
from solver.schema.settings import JobSettings

if TYPE_CHECKING:  # pragma: no cover
    from solver.schema.job import Job
    from solver.state import AdjustmentState


@dataclass
class PassStateTerm:
    """A weighted state vector as an observation of the propagated pass state at its epoch
    (an ephemeris sample, or an image's header state at its first line): r = W (S(t; x0) - b)."""

    pass_index: int
    image_index: int  # the image whose header state this is; -1 for an ephemeris sample
    kc: np.ndarray  # private segment around the epoch (PASS_T_OFF = epoch - t_ref)
    b: np.ndarray  # (m,) observed position (and velocity), ECEF
    w: np.ndarray  # (m,) 1/sigma

    @property
    def n_residuals(self) -> int:
        return len(self.b)

    def compiled_form(self) -> tuple[str, np.ndarray, tuple[np.ndarray, ...]]:
        """The compiled path's form of this term: the C callback's name in
        :mod:`solver.kernels.callbacks` (``pass_state_callback``), its descriptor (words ``PS_*``)
        and the arrays the descriptor points into (to keep alive with the problem)."""
        b = np.ascontiguousarray(self.b, dtype=float)
        w = np.ascontiguousarray(self.w, dtype=float)
        desc = np.array([self.kc.ctypes.data, len(self.kc), len(b), b.ctypes.data, w.ctypes.data], dtype=np.int64)
        return "pass_state_callback", desc, (self.kc, b, w)

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from solver.kernels.propagation import ensure_segment, pass_state

        ensure_segment(self.kc, np.ascontiguousarray(params, dtype=float))
        p, v, _a, ds, dv = pass_state(self.kc, self.kc[PASS_T_OFF], True)
        m = len(self.b)
        val = np.concatenate([p, v])[:m]
        jac = np.vstack([ds, dv])[:m]
        return self.w * (val - self.b), self.w[:, None] * jac


EPHEMERIS_MARGIN_S = 30.0  # ephemeris samples this far outside the pass's lines still observe it


def _epoch_segment(template_kc: np.ndarray, t_rel: float) -> np.ndarray:
    """A private trajectory segment (4 nodes) around ``t_rel`` (s after the pass reference epoch)."""
    kc = np.zeros(N_KEPLER_CONST + segment_length(4))
    kc[:N_KEPLER_CONST] = template_kc[:N_KEPLER_CONST]
    kc[KC_ATT_BASE] = 0.0  # the image's attitude base is not copied (a state term has no attitude)
    kc[PASS_T_OFF] = t_rel
    kc[PASS_NODES] = 4
    kc[PASS_T0] = math.floor(t_rel) - 1.0
    kc[PASS_STEP] = NODE_STEP_S
    kc[PASS_X0 : PASS_X0 + 6] = np.nan
    return kc


def ephemeris_samples(job: "Job", images: list[int], t_ref: float, span: tuple[float, float]) -> list[tuple[float, Any]]:
    """The distinct ephemeris state vectors of a pass's images (by time_s) within the pass's
    line epochs ``span`` (absolute s) widened by EPHEMERIS_MARGIN_S: (time relative to t_ref, sample)."""
    seen: dict[float, Any] = {}
    for i in images:
        for sv in job.images[i].ephemeris:
            if span[0] - EPHEMERIS_MARGIN_S <= sv.time_s <= span[1] + EPHEMERIS_MARGIN_S:
                seen.setdefault(float(sv.time_s), sv)
    return [(t - t_ref, seen[t]) for t in sorted(seen)]


def pass_line_span(job: "Job", images: list[int]) -> tuple[float, float]:
    """First and last line epoch (absolute s) of the images: first_line_time_s and the camera's
    ``lines`` x ``line_time_s`` (the window for the ephemeris samples; validation uses the same)."""
    cams = {c.id: c for c in job.cameras}
    spans = []
    for i in images:
        im = job.images[i]
        cam = cams.get(im.camera)
        length = (cam.lines or 0) * (cam.line_time_s or 0.0) if cam is not None else 0.0
        spans.append((im.first_line_time_s, im.first_line_time_s + length))
    return min(a for a, _ in spans), max(b for _, b in spans)


def pass_terms(problem: "AdjustmentState") -> list[PassStateTerm]:
    """Weighted state observations of each pass.

    With ``options.ephemeris`` sigmas, every *distinct* ephemeris sample of the pass's images
    (by epoch; images of one pass usually carry the same samples) within the pass's lines
    +- EPHEMERIS_MARGIN_S observes the propagated state at its own epoch: observing each
    image's interpolated line-0 state instead would count the same samples once per image
    (a 60-image strip on 15 samples: 4 times). Images without a usable ephemeris but with a
    weighted ``approx_state`` observe the state at their first line.
    """

    job = problem.job
    eph = JobSettings.of(job).blocks.ephemeris
    out = []
    for ps in problem.passes:
        template = problem.images[ps.images[0]].kc
        by_samples = eph is not None and eph.sigma_position_m is not None
        sampled = [i for i in ps.images if by_samples and usable(job.images[i])]
        if sampled:
            for t_rel, sv in ephemeris_samples(job, sampled, ps.t_ref_s, pass_line_span(job, ps.images)):
                b = list(sv.position_ecef_m)
                w = [1.0 / eph.sigma_position_m] * 3
                if eph.sigma_velocity_m_s is not None:
                    b += list(sv.velocity_ecef_m_s)
                    w += [1.0 / eph.sigma_velocity_m_s] * 3
                out.append(PassStateTerm(ps.index, -1, _epoch_segment(template, t_rel), np.array(b, float), np.array(w, float)))
        for i in ps.images:
            if i in sampled:
                continue
            doc = image_state(job.images[i], eph)
            if doc is None or doc.sigma_position_m is None:
                continue
            b = list(doc.position_ecef_m)
            w = [1.0 / doc.sigma_position_m] * 3
            if doc.sigma_velocity_m_s is not None:
                b += list(doc.velocity_ecef_m_s)
                w += [1.0 / doc.sigma_velocity_m_s] * 3
            kc = problem.images[i].kc.copy()
            kc[PASS_X0 : PASS_X0 + 6] = np.nan
            out.append(PassStateTerm(ps.index, i, kc, np.array(b, float), np.array(w, float)))
    return out


def n_pass_state_observations(job: "Job") -> int:
    """Number of weighted state observations :func:`pass_terms` will make (for validation; the
    pass span is taken from the images' first-line epochs and line counts)."""

    eph = JobSettings.of(job).blocks.ephemeris
    by_samples = eph is not None and eph.sigma_position_m is not None
    groups = pass_images(job)
    n = 0
    for imgs in groups.values():
        sampled = [i for i in imgs if by_samples and usable(job.images[i])]
        if sampled:
            per = 6 if eph.sigma_velocity_m_s is not None else 3
            n += per * len(ephemeris_samples(job, sampled, 0.0, pass_line_span(job, imgs)))
        for i in imgs:
            if i in sampled:
                continue
            doc = image_state(job.images[i], eph)
            if doc is not None and doc.sigma_position_m is not None:
                n += 6 if doc.sigma_velocity_m_s is not None else 3
    return n


def _without_samples(job: "Job", removals: list[tuple]) -> "Job":
    """``job`` without the pass ephemeris samples ``("pass_sample", pass image ids, time_s)``:
    the sample goes from every image of the pass that carries it."""
    samples = [(set(r[1]), r[2]) for r in removals if r[0] == "pass_sample"]
    if not samples:
        return job
    images = []
    for im in job.images:
        drop = [t for ids, t in samples if im.id in ids]
        if drop:
            im = im.model_copy(update={"ephemeris": [sv for sv in im.ephemeris if all(abs(sv.time_s - t) > 1e-6 for t in drop)]})
        images.append(im)
    return job.model_copy(update={"images": images})


class PassFamily(FamilyDefaults):
    """Weighted states of the pass-propagated models (ephemeris samples at their epochs, header
    states at an image's first line) as an observation family: each is one test
    (``ephemeris_sample``); an ephemeris sample is removable (from every image of the pass), a
    header state is not. A removed sample is flagged in ``ephemeris.images[].rejected_samples_s``
    of the pass's images. The passes' own problems, unknowns and report section ``passes`` are
    the block kind's (:mod:`solver.blocks.passes`)."""

    name = "passes"

    def check(self, job: "Job") -> tuple[list[Problem], Count]:
        return [], Count(n_observations=0 if pass_problems(job) else n_pass_state_observations(job))

    def terms(self, problem: "AdjustmentState") -> list[Labelled]:
        return [Labelled(self, t, "pass", t.pass_index) for t in pass_terms(problem)]

    def groups(self, problem: "AdjustmentState", labelled: Labelled) -> list[GroupSpec]:
        term: PassStateTerm = labelled.term
        ps = problem.passes[term.pass_index]
        m = term.n_residuals
        removal = None
        if term.image_index >= 0:  # an image's header state: not removable
            label = {"pass": ps.id, "image": problem.images[term.image_index].id, "time_s": None}
        else:
            t = float(term.kc[PASS_T_OFF] + ps.t_ref_s)
            label = {"pass": ps.id, "time_s": t}
            removal = ("pass_sample", tuple(problem.images[i].id for i in ps.images), t)
        return [GroupSpec("ephemeris_sample", np.arange(m), label, 1.0 / term.w, "m, m/s",
                          ["x", "y", "z", "vx", "vy", "vz"][:m], -1.0, removal)]

    def without(self, job: "Job", removals: list[tuple]) -> tuple["Job", list[dict[str, Any]]]:
        return _without_samples(job, removals), []

    def flag(self, report: dict[str, Any], removed: list[dict[str, Any]]) -> None:
        """A removed pass ephemeris sample: its epoch in ``ephemeris.images[].rejected_samples_s``
        of every image of the pass that has an ephemeris entry (the list the ephemeris family
        started, earlier in the registry)."""
        eph_images = {e["image"]: e for e in (report.get("ephemeris") or {}).get("images") or []}
        pass_images = {p.get("id"): p.get("images") or [] for p in report.get("passes") or []}
        for r in removed:
            if r["kind"] != "ephemeris_sample" or r.get("time_s") is None:
                continue
            for image in pass_images.get(r.get("pass"), [r.get("image")]):
                if image in eph_images:
                    eph_images[image].setdefault("rejected_samples_s", []).append(r["time_s"])


FAMILY = PassFamily()
