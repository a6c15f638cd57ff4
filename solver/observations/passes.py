"""Passes of the pass-propagated models: grouping, segments, initial state, ephemeris terms,
validation and report (the numerical integration is :mod:`solver.kernels.propagation`).

A pass is one orbit state x0 = (X, Y, Z, VX, VY, VZ) (ECEF, m and m/s) at the pass reference
epoch ``t_ref`` (the middle of the observed lines of its images, on the images' time scale).
It is one parameter block shared by the pass's images; each image carries in its constant
vector ``kc`` a segment of the trajectory (nodes every second over the image's lines plus a
margin) that the kernels recompute whenever they see another x0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from solver.errors import Problem
from solver.kernels.layout import (
    N_KEPLER_CONST,
    NODE_STEP_S,
    PASS_ATT_OFF,
    PASS_INDEX,
    PASS_NODES,
    PASS_STEP,
    PASS_T0,
    PASS_T_OFF,
    PASS_X0,
    segment_length,
)
from solver.observations.ephemeris import image_state, usable
from solver.observations.family import Count, FamilyDefaults, GroupSpec, Labelled, ReportContext
from solver.platforms import get_model
from solver.platforms.registry import PASS_STATE

if TYPE_CHECKING:  # pragma: no cover
    from solver.platforms import PlatformModel
    from solver.schema.job import Job
    from solver.state import AdjustmentState, ImageState

DEFAULT_PASS = "1"
ATTITUDE_MODES = ("camera", "image")  # model option "attitude": one set per camera of a pass / per image
MARGIN_S = 5.0  # trajectory nodes beyond the image's first/last line (Newton iterates)
STATE_NAMES = tuple(n for n, _u in PASS_STATE)
STATE_UNITS = tuple(u for _n, u in PASS_STATE)


@dataclass
class PassState:
    """One pass: its model, images, reference epoch and the estimated state (parameter block)."""

    id: str
    index: int
    model: "PlatformModel"
    images: list[int]
    t_ref_s: float
    params: np.ndarray = field(default_factory=lambda: np.zeros(6))  # ECEF state at t_ref

    @property
    def nfree(self) -> int:
        return 6


def pass_id(options: dict) -> str:
    return str(options.get("pass", DEFAULT_PASS))


def attitude_mode(options: dict) -> str:
    return str(options.get("attitude", ATTITUDE_MODES[0]))


def _attitude_blocks(entries) -> list[list[int]]:
    """Positions of the images of each attitude parameter block, from (model or None, model
    options, camera id) per image: an orbit-attitude or pass image alone, except that pass
    images with ``attitude: camera`` (the default) share one block per (pass, camera). The one
    statement of that rule: :func:`build_passes` shares the arrays by it, validation counts and
    checks by it, and measured attitude attaches to it (:mod:`solver.observations.attitude`)."""
    blocks: dict[tuple, list[int]] = {}
    for i, (model, options, camera) in enumerate(entries):
        if model is None or not model.kind.attitude_in_orbital_frame:
            continue
        if model.kind.shares_pass_orbit and attitude_mode(options) == "camera":
            key: tuple = ("camera", pass_id(options), camera)
        else:
            key = ("image", i)
        blocks.setdefault(key, []).append(i)
    return list(blocks.values())


def attitude_blocks(job: "Job") -> list[list[int]]:
    """:func:`_attitude_blocks` of the job's images with the models the document names."""

    def model_of(im):
        try:
            return get_model(im.model.name)
        except KeyError:
            return None

    return _attitude_blocks((model_of(im), im.model.options, im.camera) for im in job.images)


def image_attitude_blocks(images: list["ImageState"]) -> list[list[int]]:
    """:func:`_attitude_blocks` of a problem's images (with the models actually adjusted,
    which a model comparison may override)."""
    return _attitude_blocks((img.model, img.options, img.camera.id if img.camera else None) for img in images)


def _line_span(job_image, camera, lines_observed: list[float]) -> tuple[float, float]:
    lo = min([0.0] + lines_observed)
    hi = max([float(camera.lines or 0)] + lines_observed)
    return lo, hi


def build_passes(job: "Job", images: list["ImageState"]) -> list[PassState]:
    """Group the images of pass-propagated models into passes and extend their ``kc`` with an
    (uncomputed) trajectory segment. Call after the images are built, before the tables."""
    groups: dict[str, list["ImageState"]] = {}
    for img in images:
        if img.model.kind.shares_pass_orbit:
            groups.setdefault(pass_id(img.options), []).append(img)
    if not groups:
        return []
    observed: dict[str, list[float]] = {}
    for o in job.observations:
        observed.setdefault(o.image, []).append(float(o.line))
    passes = []
    for q, (pid, imgs) in enumerate(groups.items()):
        spans = {}
        for img in imgs:
            doc = job.images[img.index]
            lo, hi = _line_span(doc, img.camera, observed.get(img.id, []))
            lt = img.camera.line_time_s
            t0 = doc.first_line_time_s
            spans[img.index] = (t0, t0 + lo * lt, t0 + hi * lt)
        t_ref = 0.5 * (min(s[1] for s in spans.values()) + max(s[2] for s in spans.values()))
        for img in imgs:
            t0, a, b = spans[img.index]
            first = math.floor((a - t_ref - MARGIN_S) / NODE_STEP_S) * NODE_STEP_S
            n = int(math.ceil((b - t_ref + MARGIN_S - first) / NODE_STEP_S)) + 1
            kc = np.zeros(N_KEPLER_CONST + segment_length(max(n, 2)))
            kc[:N_KEPLER_CONST] = img.kc[:N_KEPLER_CONST]
            kc[PASS_T_OFF] = t0 - t_ref
            kc[PASS_INDEX] = q
            kc[PASS_NODES] = max(n, 2)
            kc[PASS_T0] = first
            kc[PASS_STEP] = NODE_STEP_S
            kc[PASS_X0 : PASS_X0 + 6] = np.nan  # not computed yet
            shared = attitude_mode(img.options) == "camera"
            kc[PASS_ATT_OFF] = kc[PASS_T_OFF] if shared else 0.0
            img.kc = kc
            img.pass_index = q
        passes.append(PassState(pid, q, imgs[0].model, [im.index for im in imgs], t_ref))
    for block in image_attitude_blocks(images):  # images sharing an attitude share one array
        for i in block[1:]:
            images[i].params = images[block[0]].params
    return passes


def attitude_groups(problem: "AdjustmentState") -> dict[int, list[str]]:
    """Image index -> ids of all images sharing its attitude block (only where shared by 2+)."""
    out = {}
    for block in image_attitude_blocks(problem.images):
        if len(block) > 1:
            for i in block:
                out[i] = [problem.images[k].id for k in block]
    return out


def refresh_segments(problem: "AdjustmentState") -> None:
    """Bring every pass image's trajectory segment up to its pass's current state."""
    from solver.kernels.propagation import ensure_segment  # numba (here and below): kernels load where a solve needs them
    for ps in getattr(problem, "passes", []):
        for i in ps.images:
            ensure_segment(problem.images[i].kc, ps.params)


def state_at(problem: "AdjustmentState", image_index: int, line: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """ECEF position and velocity of a pass image's platform at ``line`` (segments current)."""
    from solver.kernels.propagation import pass_state

    img = problem.images[image_index]
    t = img.kc[PASS_T_OFF] + line * img.camera.line_time_s
    p, v, _a, _ds, _dv = pass_state(img.kc, t, False)
    return p, v


def initialise_passes(problem: "AdjustmentState", states: dict[int, Any]) -> list[Problem]:
    """Initial pass states: the weighted or header state of the image whose first line is nearest
    the reference epoch, propagated there with the pass's own force model. ``states`` maps image
    index -> ApproxState (or None)."""
    from solver.kernels.propagation import propagate

    issues = []
    for ps in problem.passes:
        cands = [(abs(problem.images[i].kc[PASS_T_OFF]), i) for i in ps.images if states.get(i) is not None]
        if not cands:
            issues.append(
                Problem(
                    "no_initial_position",
                    f"pass {ps.id!r}: none of its images has approx_state or an ephemeris covering "
                    "first_line_time_s (one is needed to start the orbit)",
                    ("images", ps.images[0], "approx_state"),
                )
            )
            continue
        _, i = min(cands)
        st = states[i]
        y = np.concatenate([np.asarray(st.position_ecef_m, float), np.asarray(st.velocity_ecef_m_s, float)])
        kc = problem.images[i].kc
        y, _phi = propagate(y, np.eye(6), -kc[PASS_T_OFF], kc[12], kc[13], kc[14], kc[15])
        ps.params[:] = y
    refresh_segments(problem)
    return issues


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
    eph = job.options.ephemeris
    out = []
    for ps in getattr(problem, "passes", []):
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
            doc = image_state(job.images[i], job.options)
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


def pass_problems(job: "Job") -> list[Problem]:
    """Validation of the pass-propagated images: epochs, one model per pass, no lines/IOP."""

    out = []
    models: dict[str, tuple[str, int]] = {}
    for i, im in enumerate(job.images):
        try:
            model = get_model(im.model.name)
        except KeyError:
            continue
        if not model.kind.shares_pass_orbit:
            continue
        pid = pass_id(im.model.options)
        if im.first_line_time_s is None:
            out.append(
                Problem(
                    "missing_first_line_time",
                    f"image {im.id!r}: model {model.name} propagates one orbit over the pass and needs "
                    "first_line_time_s (the epoch of line 0, on the same time scale for all its images)",
                    ("images", i, "first_line_time_s"),
                )
            )
        if pid in models and models[pid][0] != model.name:
            out.append(
                Problem(
                    "mixed_pass_models",
                    f"image {im.id!r} uses {model.name} but pass {pid!r} already uses {models[pid][0]} "
                    f"(image {job.images[models[pid][1]].id!r}); one model per pass",
                    ("images", i, "model", "name"),
                )
            )
        models.setdefault(pid, (model.name, i))
        mode = attitude_mode(im.model.options)
        if mode not in ATTITUDE_MODES:
            out.append(
                Problem(
                    "invalid_model_options",
                    f"image {im.id!r}: attitude must be one of {', '.join(ATTITUDE_MODES)} (got {mode!r})",
                    ("images", i, "model", "options", "attitude"),
                )
            )
        if job.lines:
            out.append(
                Problem(
                    "unsupported",
                    f"image {im.id!r}: straight-line observations are not available with the "
                    "pass-propagated models yet (use OA-K/OA-J2 or a per-image model)",
                    ("images", i, "model", "name"),
                )
            )
    return out + _attitude_group_problems(job)


def _attitude_group_problems(job: "Job") -> list[Problem]:
    """Images sharing one attitude block (:func:`attitude_blocks`) must ask for the same model
    orders and give the same initial values as the block's first image."""

    def signature(i: int):
        im = job.images[i]
        model = get_model(im.model.name)
        orders = model.effective_orders(im.model.options) if _orders_ok(model, im.model.options) else None
        return orders, model.name

    out = []
    for block in attitude_blocks(job):
        lead = job.images[block[0]]
        for i in block[1:]:
            im = job.images[i]
            pid = pass_id(im.model.options)
            if signature(i) != signature(block[0]):
                out.append(
                    Problem(
                        "inconsistent_attitude_group",
                        f"image {im.id!r} shares the attitude of camera {im.camera!r} on pass {pid!r} with "
                        f"image {lead.id!r} but asks for other orders; give them the "
                        "same orders or use the option attitude: image",
                        ("images", i, "model", "options"),
                    )
                )
                continue
            clash = sorted(n for n in set(lead.initial) & set(im.initial) if lead.initial[n] != im.initial[n])
            if clash:
                out.append(
                    Problem(
                        "inconsistent_attitude_group",
                        f"image {im.id!r} shares the attitude of camera {im.camera!r} on pass {pid!r} with "
                        f"image {lead.id!r} but gives other initial values for "
                        f"{', '.join(clash)}; give one value (or use the option attitude: image)",
                        ("images", i, "initial"),
                    )
                )
    return out


def n_pass_state_observations(job: "Job") -> int:
    """Number of weighted state observations :func:`pass_terms` will make (for validation; the
    pass span is taken from the images' first-line epochs and line counts)."""

    eph = job.options.ephemeris
    by_samples = eph is not None and eph.sigma_position_m is not None
    groups: dict[str, list[int]] = {}
    for i, im in enumerate(job.images):
        try:
            if get_model(im.model.name).kind.shares_pass_orbit and im.first_line_time_s is not None:
                groups.setdefault(pass_id(im.model.options), []).append(i)
        except KeyError:
            continue
    n = 0
    for imgs in groups.values():
        sampled = [i for i in imgs if by_samples and usable(job.images[i])]
        if sampled:
            per = 6 if eph.sigma_velocity_m_s is not None else 3
            n += per * len(ephemeris_samples(job, sampled, 0.0, pass_line_span(job, imgs)))
        for i in imgs:
            if i in sampled:
                continue
            doc = image_state(job.images[i], job.options)
            if doc is not None and doc.sigma_position_m is not None:
                n += 6 if doc.sigma_velocity_m_s is not None else 3
    return n


def _orders_ok(model, options) -> bool:
    try:
        model.effective_orders(options)
        return True
    except ValueError:
        return False


def n_pass_unknowns(job: "Job") -> int:
    """Unknowns the passes add (6 per pass) minus the attitude parameters that images of one
    camera share (counted once, not per image, by the validation's per-image count)."""

    def valid(i: int):
        """The image's model when it propagates and its orders are valid, else None."""
        im = job.images[i]
        try:
            model = get_model(im.model.name)
        except KeyError:
            return None
        return model if model.kind.shares_pass_orbit and _orders_ok(model, im.model.options) else None

    ids = {pass_id(im.model.options) for i, im in enumerate(job.images) if valid(i) is not None}
    n = 0
    for block in attitude_blocks(job):
        members = [i for i in block if valid(i) is not None]
        if len(members) > 1:  # counted once per image by the validation: once is enough
            lead = members[0]
            n -= (len(members) - 1) * len(valid(lead).parameters(job.images[lead].model.options))
    return 6 * len(ids) + n


def parameter_names(problem: "AdjustmentState") -> list[str]:
    return [f"pass:{ps.id}/{n}" for ps in getattr(problem, "passes", []) for n in STATE_NAMES]


def passes_report(problem: "AdjustmentState", cov_block, var_factor: float) -> list[dict[str, Any]]:
    """Per pass: reference epoch, images, estimated state with sigmas and covariance (ECEF)."""
    out = []
    for ps in getattr(problem, "passes", []):
        block = cov_block(ps.index)
        sig = None if block is None else np.sqrt(np.clip(np.diag(block) * var_factor, 0.0, None))
        params = [
            {"name": n, "value": float(ps.params[k]), "sigma": None if sig is None else float(sig[k]), "unit": u, "estimated": True}
            for k, (n, u) in enumerate(zip(STATE_NAMES, STATE_UNITS))
        ]
        out.append(
            {
                "id": ps.id,
                "model": ps.model.name,
                "frame": "ECEF",
                "reference_epoch_s": ps.t_ref_s,
                "images": [problem.images[i].id for i in ps.images],
                "parameters": params,
                "covariance": None
                if block is None
                else {"names": list(STATE_NAMES), "matrix": (block * var_factor).tolist()},
            }
        )
    return out


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
    header state is not. Report section ``passes`` (the estimated pass states); a removed
    sample is flagged in ``ephemeris.images[].rejected_samples_s`` of the pass's images."""

    name = "passes"

    def check(self, job: "Job") -> tuple[list[Problem], Count]:
        issues = pass_problems(job)
        return issues, Count(n_observations=0 if issues else n_pass_state_observations(job), n_unknowns=n_pass_unknowns(job))

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

    def report(self, problem: "AdjustmentState", ctx: ReportContext) -> dict[str, Any]:
        return {"passes": passes_report(problem, lambda pi: ctx.block("pass", pi, 6), ctx.var_factor)}

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
