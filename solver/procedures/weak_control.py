"""The rule by which the default procedure acts when the control does not determine an attitude
term (``options.weak_control``, default ``"act"``; docs/models.md section 13).

The report calls an attitude term of an orbit-attitude or pass model undetermined when its
sigma, as an angle over half the image, exceeds the plausible limit
(``options.quality_warnings.attitude_sigma_deg``, 0.1 degree:
:func:`solver.quality.parameter_checks.implausible_sigmas`). With weak control (a few control points
in one band of a long strip, no attitude samples) the attitude of the oblique images is such,
and its rates, extrapolated along the strip, put the check points tens to hundreds of metres
off.

The rule: adjust; for every image whose control spans a band (less than half of its lines)
and whose attitude has an undetermined term, hold the time terms of its attitude (every
element of its attitude block down to its constant: a constant attitude is the least the
control must determine) and adjust again, once. Both conditions: a flag alone also comes from
sigmas the data need not shrink (a pass attitude's constant at the pass epoch, away from the
image, under well-spread control), and there the full model is right. Terms still undetermined
are ones the control cannot determine: the report names them in its warnings and in
``quality.weak_control`` (with the terms that called for the rule, the orders it set, the
check-point RMSE before and after). The true attitude's rates are then not modelled: what they
move the ground along the strip is in the check points, not in the predicted precision.
When the control of an image spans less than half of its lines (a band), the report says so
in its warnings and in ``quality.weak_control.control_extent``, whether or not a term was
flagged: beyond the band the orientation is extrapolated. ``"warn"``: only the warnings, as
before. Off when ``options.parsimony`` is given and in model comparisons.

Tried and not kept (a PASS-J2 triplet, four control points in the first fifth of the strip,
full control 2.5 m): lowering only the flagged elements left the pitch rate (0.9999 correlated
with the pitch, yet under the 0.1-degree limit) and ended at 12.6 m; the significance analysis
of the platform terms (``options.parsimony``) held three rates and kept the others, whose wild
estimates passed for significant, and ended at 101 m; this rule ends at 6.0 m. An F test of
holding the rates (as the significance analysis does) cannot guard the rule: on that layout it rejects holding them (F = 76 against 2.1: the tie
points along the whole strip see the truth's rates relative between the images) although the
rates' absolute values, extrapolated from the band, are what puts the check points 131 m off.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from solver.engine.validate import ValidatedJob, job_of
from solver.errors import JobError, RankDeficientError
from solver.platforms import ELEMENTS, get_model
from solver.procedures.single import Adjust
from solver.quality.datum import datum_problem
from solver.report.solution import Solution
from solver.schema.job import Job
from solver.schema.settings import JobSettings

RULE = ("when an attitude term's sigma over half the image exceeds options.quality_warnings.attitude_sigma_deg "
        "(the control does not determine it), hold that image's attitude (its attitude block's) at its constants "
        "and adjust again, once")


def _constant_attitude(job: Job, solution: Solution, images: set[str]) -> Job:
    """``job`` with the attitude elements of the blocks of ``images`` held at their constants."""
    blocks = {im.id: set(im.shared_with or [im.id]) for im in solution.images()}
    chosen = set().union(*(blocks.get(i, {i}) for i in images))
    new_images = []
    for im in job.images:
        model = get_model(im.model.name)
        if im.id in chosen and model.order_option:
            orders = dict(zip(ELEMENTS, model.effective_orders(im.model.options)))
            mine = {e: min(orders[e], 0) for e in model.order_elements()}
            im = im.model_copy(update={"model": im.model.model_copy(update={"options": {**im.model.options, "orders": mine}})})
        new_images.append(im)
    return job.model_copy(update={"images": new_images})


def _orders(job: Job, images: set[str]) -> dict[str, dict[str, int]]:
    out = {}
    for im in job.images:
        model = get_model(im.model.name)
        if im.id in images and model.order_option:
            out[im.id] = {e: o for e, o in zip(ELEMENTS, model.effective_orders(im.model.options)) if e in model.order_elements()}
    return out


BAND_FRACTION = 0.5  # control spanning less than this fraction of an image's lines is a band


@dataclass(frozen=True)
class ControlExtent:
    """The first and last line of an image's control-point observations (None: no control
    point) and the fraction of its lines between them."""

    lines: list[float] | None
    fraction: float

    def as_dict(self) -> dict[str, Any]:
        return {"lines": self.lines, "fraction": self.fraction}


def control_extent(job: Job) -> dict[str, ControlExtent]:
    """Per image with a camera: the first and last line of its control-point observations and
    the fraction of its lines between them (one pass over the observations)."""
    gcps = {p.id for p in job.points if p.role == "gcp"}
    cams = {c.id: c for c in job.cameras}
    lo: dict[str, float] = {}
    hi: dict[str, float] = {}
    for o in job.observations:
        if o.point in gcps:
            lo[o.image] = min(lo.get(o.image, o.line), o.line)
            hi[o.image] = max(hi.get(o.image, o.line), o.line)
    out: dict[str, ControlExtent] = {}
    for im in job.images:
        cam = cams.get(im.camera) if im.camera else None
        if cam is None or not cam.lines:
            continue
        if im.id not in lo:
            out[im.id] = ControlExtent(None, 0.0)
            continue
        out[im.id] = ControlExtent([float(lo[im.id]), float(hi[im.id])], (hi[im.id] - lo[im.id]) / cam.lines)
    return out


def _narrow(extent: dict[str, ControlExtent]) -> dict[str, ControlExtent]:
    """The images whose control spans a band. An image without any control point is not one:
    its orientation comes from elsewhere (the other images' control through tie points, or the
    measured orbit and attitude of direct georeferencing)."""
    return {i: e for i, e in extent.items() if e.lines is not None and e.fraction < BAND_FRACTION}


def _band_warning(job: Job) -> tuple[dict[str, ControlExtent], str | None]:
    extent = control_extent(job)
    narrow = _narrow(extent)
    if not narrow or not extent:
        return extent, None
    shown = ", ".join(f"{i} {e.fraction:.0%}" + (f" (lines {e.lines[0]:.0f}-{e.lines[1]:.0f})" if e.lines else "")
                      for i, e in sorted(narrow.items()))
    return extent, (f"weak control: the control spans a band of the images' lines ({shown}): the attitude rates "
                    "are not determined by it, so beyond the band the orientation is extrapolated and the check points "
                    "there can be off by more than the predicted precision")


def weak_control_rule(job: Job | ValidatedJob, adjust: Adjust, progress) -> Solution:
    """Adjust ``job`` under the rule of the module docstring (``adjust``: the adjustment with the
    rule off) and return the last solution, with ``quality.weak_control`` when it acted."""
    original = job_of(job)
    # the datum analysis reports (not refuses) the first adjustment: weak control leaves the
    # attitude's rates, and so the block's tilts, undetermined, which is what the rule acts on
    own_datum = JobSettings.of(original).blocks.datum
    first_datum = own_datum.model_copy(update={"undetermined": "report"})
    plain = original.model_copy(update={"options": original.options.model_copy(update={"weak_control": "warn", "datum": first_datum})})
    # only the procedures' own options differ: validated as the job was
    solution = adjust(job.with_job(plain) if isinstance(job, ValidatedJob) else plain, (0.0, 0.5))
    extent_of, band = _band_warning(plain)
    narrow = set(_narrow(extent_of))
    extent = {i: e.as_dict() for i, e in extent_of.items()}
    flagged = [f for f in solution.undetermined_attitude() if f.image in narrow]
    datum = solution.datum
    if not flagged and datum is not None and datum.undetermined and own_datum.undetermined == "refuse":
        raise RankDeficientError([datum_problem(datum.to_report())])
    if not flagged:
        if band:
            solution.prepend_warning(band)
            solution.set_quality({"weak_control": {"rule": RULE, "undetermined": [], "action": "none",
                                                   "control_extent": extent, "ended": "no attitude term undetermined"}})
        return solution
    images = {f.image for f in flagged}
    trial = _constant_attitude(plain, solution, images)
    trial = trial.model_copy(update={"options": trial.options.model_copy(update={"datum": own_datum})})
    section: dict[str, Any] = {"rule": RULE, "undetermined": [f.as_dict() for f in flagged], "orders": _orders(trial, {i.id for i in trial.images}),
                               "control_extent": extent, "check_rmse_3d_m_before": solution.check_rmse_3d_m()}
    try:
        final = adjust(trial, (0.5, 1.0))
    except JobError as exc:
        if exc.code == "datum_undetermined" and own_datum.undetermined == "refuse":
            raise  # the rule could not make the datum determined: the job's refusal stands
        solution.set_quality({"weak_control": {**section, "action": "none",
                                               "ended": f"the adjustment with constant attitude failed: {exc.problems[0].message[:160]}"}})
        return solution
    remaining = final.undetermined_attitude()
    final.set_quality({"weak_control": {
        **section,
        "action": "attitude held at its constants in " + ", ".join(sorted(images)) + " (and their attitude blocks)",
        "check_rmse_3d_m_after": final.check_rmse_3d_m(),
        "still_undetermined": [f.as_dict() for f in remaining],
        "ended": ("every attitude term determined" if not remaining else
                  "terms still undetermined: the control cannot determine them (add control or attitude data)"),
    }})
    names = ", ".join(sorted({f"{f.image}/{f.parameter}" for f in flagged}))
    final.prepend_warning(f"weak control: the control did not determine {names}: the attitude of "
                          f"{', '.join(sorted(images))} was held at its constants and adjusted again "
                          "(quality.weak_control); its rates are not modelled")
    if band:
        final.prepend_warning(band, 1)
    if remaining:
        final.prepend_warning("weak control: " + ", ".join(sorted({f"{f.image}/{f.parameter}" for f in remaining}))
                              + " remain undetermined: the control cannot determine them; add control or attitude data", 1)
    if progress is not None:
        progress(1.0, "weak-control rule done", {})
    return final
