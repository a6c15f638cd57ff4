"""The passes of the pass-propagated models as parameter blocks (kind ``pass``): grouping,
trajectory segments, initial state, validation, names and report (section ``passes``). The
weighted states that observe them (the observation family) are :mod:`solver.observations.passes`;
the numerical integration is :mod:`solver.kernels.propagation`.

A pass is one orbit state x0 = (X, Y, Z, VX, VY, VZ) (ECEF, m and m/s) at the pass reference
epoch ``t_ref`` (the middle of the observed lines of its images, on the images' time scale).
It is one parameter block shared by the pass's images; each image carries in its constant
vector ``kc`` a segment of the trajectory (nodes every second over the image's lines plus a
margin) that the kernels recompute whenever they see another x0 (:meth:`PassKind.refresh`
brings them up to date).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from solver.blocks.kind import BlockDefaults
from solver.blocks.platform import ATTITUDE_MODES, attitude_mode, orders_ok, pass_id
from solver.errors import Problem
from solver.kernels.layout import (
    KC_ATT_BASE,
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
from solver.platforms import get_model
from solver.platforms.registry import PASS_STATE

if TYPE_CHECKING:  # pragma: no cover
    from solver.platforms import PlatformModel
    from solver.schema.job import Job
    from solver.schema.settings import BlockConfig
    from solver.state import AdjustmentState, ImageState

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


def _line_span(job_image, camera, lines_observed: list[float]) -> tuple[float, float]:
    lo = min([0.0] + lines_observed)
    hi = max([float(camera.lines or 0)] + lines_observed)
    return lo, hi


def build_passes(job: "Job", images: list["ImageState"]) -> list[PassState]:
    """Group the images of pass-propagated models into passes and extend their ``kc`` with an
    (uncomputed) trajectory segment."""
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
            kc[KC_ATT_BASE] = 0.0  # solver.blocks.platform.attach_attitude_base appends it after this segment
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
    return passes


def refresh_segments(problem: "AdjustmentState") -> None:
    """Bring every pass image's trajectory segment up to its pass's current state."""
    from solver.kernels.propagation import ensure_segment  # numba (here and below): kernels load where a solve needs them
    for ps in problem.passes:
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


def pass_problems(job: "Job") -> list[Problem]:
    """Validation of the pass-propagated images: epochs, one model per pass, their attitude option, no lines
    (the images sharing an attitude block: :mod:`solver.blocks.platform`)."""

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
    return out


def pass_images(job: "Job") -> dict[str, list[int]]:
    """The images of each pass (pass id -> image indices) among the images whose model propagates
    one orbit and that have their first line's epoch (validation counts the others' problems)."""
    groups: dict[str, list[int]] = {}
    for i, im in enumerate(job.images):
        try:
            if get_model(im.model.name).kind.shares_pass_orbit and im.first_line_time_s is not None:
                groups.setdefault(pass_id(im.model.options), []).append(i)
        except KeyError:
            continue
    return groups


def n_passes(job: "Job") -> int:
    """The passes of the job's images whose model propagates one orbit (and whose orders are valid)."""
    ids = set()
    for im in job.images:
        try:
            model = get_model(im.model.name)
        except KeyError:
            continue
        if model.kind.shares_pass_orbit and orders_ok(model, im.model.options):
            ids.add(pass_id(im.model.options))
    return len(ids)


def passes_report(problem: "AdjustmentState", cov_block, var_factor: float) -> list[dict[str, Any]]:
    """Per pass: reference epoch, images, estimated state with sigmas and covariance (ECEF)."""
    out = []
    for ps in problem.passes:
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


class PassKind(BlockDefaults):
    """The passes' orbit states: one 6-parameter block per pass, shared by its images."""

    name = "pass"

    def check(self, job: "Job") -> tuple[list[Problem], int]:
        return pass_problems(job), 6 * n_passes(job)

    def build(self, problem: "AdjustmentState", config: "BlockConfig") -> list[PassState]:
        return build_passes(problem.job, problem.images)

    def initialise(self, problem: "AdjustmentState", states: dict[int, Any]) -> list[Problem]:
        return initialise_passes(problem, states)

    def refresh(self, problem: "AdjustmentState") -> None:
        refresh_segments(problem)

    def names(self, problem: "AdjustmentState") -> list[str]:
        return [f"pass:{ps.id}/{n}" for ps in self.blocks(problem) for n in STATE_NAMES]

    def report(self, problem: "AdjustmentState", ctx: Any) -> dict[str, Any]:
        return {"passes": passes_report(problem, lambda pi: ctx.block(self.name, pi, 6), ctx.var_factor)}


KIND = PassKind()
