"""Parsimony of the platform models (``options.parsimony``; docs/models.md): drop the time
terms that are not significant, one at a time, each with the F test of that constraint
(:func:`solver.quality.parameter_checks.constraint_decision`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from solver.engine.validate import ValidatedJob, job_of
from solver.errors import RankDeficientError
from solver.platforms import ELEMENTS, coef_index, get_model
from solver.procedures.single import Adjust
from solver.quality.parameter_checks import constraint_decision
from solver.report.solution import Solution
from solver.schema.job import Job
from solver.schema.settings import JobSettings


@dataclass(frozen=True)
class _Term:
    """A time term the analysis may drop: the highest-order term (order >= 1) of an element of
    an attitude block (its images), its estimate and sigma (report units) and |estimate| / sigma."""

    images: list[str]
    element: str
    order: int
    parameter: str
    value: float
    sigma: float
    unit: str
    ratio: float

    @property
    def key(self) -> tuple[tuple[str, ...], str, int]:
        return tuple(self.images), self.element, self.order


def _platform_terms(job: Job, solution: Solution) -> list[_Term]:
    """The highest-order time term (order >= 1) of every element of every attitude block, with
    |estimate| / sigma: the terms the parsimony analysis may drop (lowering that order by one)."""
    out = []
    seen: set[tuple[tuple[str, ...], str]] = set()
    for im_doc, est in zip(job.images, solution.images()):
        model = get_model(im_doc.model.name)
        if not model.order_option:
            continue
        orders = model.effective_orders(im_doc.model.options)
        specs = model.parameters(im_doc.model.options)
        values = est.estimated()
        block = tuple(sorted(est.shared_with or [im_doc.id]))
        for e in model.order_elements():
            k = orders[ELEMENTS.index(e)]
            if k < 1 or (block, e) in seen:
                continue
            seen.add((block, e))
            spec = next(s for s in specs if s.index == coef_index(e, k))
            p = values.get(spec.name)
            if p is None or not p.sigma:
                continue
            out.append(_Term(list(block), e, k, spec.name, p.value, p.sigma, p.unit, abs(p.value) / p.sigma))
    return out


def _lower_order(job: Job, images: list[str], element: str) -> Job:
    """``job`` with the order of ``element`` lowered by one in the models of ``images``."""
    new_images = []
    for im in job.images:
        if im.id in images:
            model = get_model(im.model.name)
            orders = dict(zip(ELEMENTS, model.effective_orders(im.model.options)))
            mine = {e: orders[e] for e in model.order_elements()}
            mine[element] -= 1
            opts = {**im.model.options, "orders": mine}
            im = im.model_copy(update={"model": im.model.model_copy(update={"options": opts})})
        new_images.append(im)
    return job.model_copy(update={"images": new_images})


def _vtpv(solution: Solution) -> tuple[float, int]:
    s0 = solution.sigma0 or 0.0
    return s0 * s0 * solution.dof, solution.dof


def parsimony_analysis(job: Job | ValidatedJob, adjust: Adjust, progress) -> Solution:
    """Significance analysis of the platform terms (``options.parsimony``; docs/models.md):
    adjust; take the time term (attitude rate, polynomial term of order >= 1, the highest of its
    element) with the smallest |estimate| / sigma below the threshold; re-adjust without it and
    accept when the F test of that constraint (the increase of v^T P v against sigma0^2) passes,
    else keep it and try the next. Every step is reported in ``quality.parsimony``; the solution
    is that of the last accepted adjustment (``adjust``: the adjustment with the analysis off)."""
    job = job_of(job)
    par = JobSettings.from_options(job.options).procedures.parsimony
    current = job.model_copy(update={"options": job.options.model_copy(update={"parsimony": None})})
    solution = adjust(current, (0.0, 0.5))
    steps: list[dict[str, Any]] = []
    kept: set[tuple[tuple[str, ...], str, int]] = set()
    dropped: list[str] = []
    for step in range(1, 200):
        if len(dropped) >= par.max_steps:
            break
        terms = [t for t in _platform_terms(current, solution) if t.ratio < par.threshold and t.key not in kept]
        if not terms:
            break
        t = min(terms, key=lambda x: x.ratio)
        trial = _lower_order(current, t.images, t.element)
        lo = 1.0 - 0.5 ** (step + 1)
        try:
            candidate: Solution | None = adjust(trial, (lo, 1.0 - 0.5 ** (step + 2)))
        except RankDeficientError:
            candidate = None
        v0, dof0 = _vtpv(solution)
        test, accept = None, False
        if candidate is not None:
            v1, _dof1 = _vtpv(candidate)
            test, accept = constraint_decision(v1 - v0, 1, v0, dof0, par.alpha)
        name = f"{'+'.join(t.images)}/{t.parameter}"
        shown = candidate or solution
        steps.append(
            {
                "step": step,
                "term": {**asdict(t), "name": name},
                "test": test,
                "decision": "dropped" if accept else "kept",
                "sigma0": shown.sigma0,
                "check_rmse_3d_m": shown.check_rmse_3d_m(),
            }
        )
        if accept:
            current, solution = trial, candidate
            dropped.append(name)
        else:
            kept.add(t.key)
    solution.set_quality({"parsimony": {
        "rule": (
            f"drop, one at a time, the highest time term of an attitude or polynomial element whose "
            f"|estimate| < {par.threshold:g} sigma, when the F test of holding it (alpha {par.alpha:g}) passes"
        ),
        "steps": steps,
        "dropped": dropped,
        "orders": {im.id: dict(zip(ELEMENTS, get_model(im.model.name).effective_orders(im.model.options))) for im in current.images},
    }})
    if progress is not None:
        progress(1.0, "parsimony analysis done", {})
    return solution
