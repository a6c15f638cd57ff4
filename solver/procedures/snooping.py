"""Data snooping (``options.blunder_detection``; docs/quality.md): test, remove the worst rejected
observation (group), re-adjust, and put back what passes against the final solution.

The tests, reliability and the ``quality`` report section are :mod:`solver.quality.outlier_tests`;
the job without the removed observations :mod:`solver.quality.removal` (the core's removals
and each observation family's ``without``); their flags in the families' report sections
:mod:`solver.quality.flags`. This module is the loop: it reads the adjustments' solutions
(:class:`solver.report.solution.Solution`) and notes on the last one what the report adds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solver.engine.validate import ValidatedJob, job_of
from solver.errors import JobError
from solver.procedures.single import adjust_once
from solver.quality.outlier_tests import (
    collateral_entries,
    entry,
    failing_clusters,
    predicted_decision,
    reliability_section,
    snoop,
)
from solver.quality.removal import INFLATE, Candidate, reinstate, remove, testable, whole_points, with_candidates
from solver.report.solution import Solution
from solver.schema.job import Job
from solver.schema.settings import JobSettings

# The limit of removals when ``max_rejections`` is not given: a share of the tests (observation
# groups), so that a large tie set is not cut short at a small fixed number (docs/quality.md).
RELATIVE_MAX_REJECTIONS = 0.05
MIN_MAX_REJECTIONS = 20


def rejection_limit(max_rejections: int | None, n_tests: int) -> int:
    """The most removals allowed: ``max_rejections`` when given, else
    :data:`RELATIVE_MAX_REJECTIONS` of the ``n_tests`` tests of the whole job, at least
    :data:`MIN_MAX_REJECTIONS`."""
    if max_rejections is not None:
        return max_rejections
    return max(MIN_MAX_REJECTIONS, int(RELATIVE_MAX_REJECTIONS * n_tests))


def snooping_adjustment(job: Job | ValidatedJob, progress, cancel, models, fraction_range: tuple[float, float]) -> Solution:
    """Data snooping (docs/quality.md): adjust, test every observation group, remove the worst
    rejected one (with the tests it cannot be separated from) and re-adjust, until no test fails
    or ``max_rejections`` is reached; ``robust_start`` first removes, in one step, every group
    whose test fails on the residuals of a robust adjustment; ``reinstate`` then tests every
    removed observation against the final solution and puts back those that pass (re-adjusting
    and snooping again, until nothing changes). The solution is that of the last adjustment,
    noted with the ``quality`` section and the removed image points flagged in ``observations``."""
    return _Snooping(job, progress, cancel, models, fraction_range).run()


@dataclass
class _Cluster:
    """A non-identifiable group's report entry and whether each of its members is removed."""

    entry: dict[str, Any]
    removed: list[bool]


@dataclass
class _Removal(Candidate):
    """A removed observation: what :class:`~solver.quality.removal.Candidate` puts back, its report
    entry (written here, never read), its non-identifiable cluster and its place there, its
    flagged ``observations`` entry, and what became of it."""

    entry: dict[str, Any] = field(default_factory=dict)
    cluster: _Cluster | None = None
    member: int = -1
    flag: dict[str, Any] | None = None
    fixed: bool = False  # a fixed control point's: no sigma to put it back with
    collateral: bool = False
    reinstated: bool = False
    predicted: dict[str, Any] | None = None

    def key(self) -> tuple:
        """What identifies it across the loop's jobs (an image point by its measurement, a survey by its point)."""
        o = self.obs
        return (self.kind, self.point) if o is None else (self.kind, o.image, o.point, o.line, o.column)


class _Snooping:
    """One data-snooping run (:func:`snooping_adjustment`): the job as it stands after the
    removals so far (``current``), the report entries, and every removal as a :class:`_Removal`."""

    def __init__(self, job: Job | ValidatedJob, progress, cancel, models, fraction_range: tuple[float, float]) -> None:
        self.handed = job  # the job as handed (validated or not): the first adjustment takes it
        self.job = job_of(job)
        self.bd = JobSettings.from_options(self.job.options).procedures.blunder_detection
        self.progress, self.cancel, self.models = progress, cancel, models
        self.f0, self.f1 = fraction_range
        self.step = 0
        self.current = self.job
        self.n_removed = 0
        self.rejected: list[dict[str, Any]] = []
        self.not_identifiable: list[dict[str, Any]] = []
        self.reinstated: list[dict[str, Any]] = []
        self.warnings: list[str] = []
        self.items: list[_Removal] = []
        self.once: set[tuple] = set()  # reinstated once: not again (no oscillation)
        self.limit: int | None = None  # the most removals (rejection_limit), from the whole job's tests
        self.n_tests = 0
        self.stopped_early: dict[str, Any] | None = None

    def cap(self, sn) -> int:
        """The most removals allowed (set from the first tests: those of the whole job)."""
        if self.limit is None:
            self.limit, self.n_tests = rejection_limit(self.bd.max_rejections, len(sn.tests)), len(sn.tests)
        return self.limit

    def stop(self, reason: str, message: str, sn) -> None:
        """Record why the removals stopped before every removable test passed."""
        self.warnings.append(message)
        failing = sum(1 for t in sn.tests if t.failed)
        self.stopped_early = {"reason": reason, "message": message, "failing_tests": failing}

    def adjust(self, job: Job) -> Solution:
        """``adjust_once`` in the next slice of the progress range (halving slices); the job as
        it was handed (validated) while no removal changed it."""
        k = self.step
        self.step += 1
        window = (self.f0 + (self.f1 - self.f0) * (1.0 - 0.5**k), self.f0 + (self.f1 - self.f0) * (1.0 - 0.5 ** (k + 1)))
        return adjust_once(self.handed if job is self.job else job, self.progress, self.cancel, self.models, window, keep_linearised=True)

    def record(self, cluster, solution: Solution, collateral, current: Job) -> None:
        """Enter the removed ``cluster`` (one test, or a non-identifiable group) and the
        ``collateral`` removals in the report lists and the items."""
        removable = [m.group.removal is not None for m in cluster]
        entries = [entry(m, removed=r) for m, r in zip(cluster, removable)]
        group = None
        if len(entries) == 1:
            self.rejected.append(entries[0])
        elif entries:
            group = _Cluster({"members": entries, "removed": all(removable)}, list(removable))
            self.not_identifiable.append(group.entry)
        for k, (m, e) in enumerate(zip(cluster, entries)):
            if m.group.removal is None:
                continue
            if m.group.family is not None:  # e.g. a line point's measured pixels (its index shifts with removals)
                e.update(m.group.family.removal_details(current, m.group.removal))
            obs = current.observations[m.group.removal[1]] if m.group.kind == "image_point" else None
            self.items.append(_Removal(m.group.kind, obs, m.group.point, entry=e, cluster=group, member=k,
                                       flag=solution.observation_entry(obs) if obs is not None else None, fixed=m.group.fixed))
        for c in collateral_entries(collateral):
            self.rejected.append(c.entry)
            if not c.image_point:  # a family's (a line image left with fewer than two points)
                continue
            obs = next(o for o in current.observations if (o.image, o.point) == (c.image, c.point))
            self.items.append(_Removal("image_point", obs, c.point, entry=c.entry, flag=solution.observation_entry(obs), collateral=True))

    def snoop_loop(self, solution: Solution):
        """Remove the worst failed cluster and re-adjust until no removable test fails (or
        ``max_rejections``, or the adjustment without it fails); ``action: report`` tests only."""
        bd = self.bd
        while True:
            sn = snoop(solution.problem, bd, linearised=solution.take_linearised())
            if bd.action == "report":
                return solution, sn
            clusters = [c for c in failing_clusters(sn, bd.separability) if c[0].group.removal]
            if not clusters:
                return solution, sn
            cluster = clusters[0]
            limit = self.cap(sn)
            if self.n_removed + len(cluster) > limit:
                rule = "" if bd.max_rejections is not None else f" ({RELATIVE_MAX_REJECTIONS:.0%} of the {self.n_tests} tests, at least {MIN_MAX_REJECTIONS})"
                self.stop("max_rejections", f"data snooping stopped at max_rejections = {limit}{rule}: some tests still fail", sn)
                return solution, sn
            nxt, collateral = remove(self.current, [m.group.removal for m in cluster if m.group.removal])
            try:
                nxt_solution = self.adjust(nxt)
            except JobError as exc:  # rank, unusable solution, or the job no longer valid
                self.stop("adjustment_failed", f"data snooping stopped: without the next rejected observation the adjustment fails ({exc})", sn)
                return solution, sn
            self.record(cluster, solution, collateral, self.current)
            self.n_removed += len(cluster)
            self.current, solution = nxt, nxt_solution

    def robust_start(self) -> None:
        """Adjust with the robust loss and remove, in one step, the worst failed cluster of each
        block (image points and surveys of estimated points only)."""
        bd, job = self.bd, self.job
        robust = job.model_copy(update={"options": job.options.model_copy(update={"loss": bd.robust_start})})
        solution = self.adjust(robust)
        sn = snoop(solution.problem, bd, robust=True, linearised=solution.take_linearised())
        limit = self.cap(sn)
        clusters = [c for c in failing_clusters(sn, bd.separability) if c[0].group.removal]
        take = []
        blocks: set[int] = set()
        for c in clusters:
            # one cluster per block (the rays of a point and its survey): a blunder smears into
            # the residuals of the other rays of its point, whose tests then fail with it; the
            # next worst of the same block waits for the least-squares loop
            if c[0].group.block in blocks:
                continue
            if any(m.group.fixed or (m.group.family is not None and m.group.kind != "dem_height") for m in c):
                # a fixed control point (its rays share one loss block per image in the robust
                # solve) and the image-only terms (lines, ephemeris, attitude: the loss does not
                # act on them) cannot be reinstated: the least-squares loop tests them. Their
                # block waits too (the next worst test of the block is not removed in its place)
                blocks.update(m.group.block for m in c)
                continue
            # a point's DEM height (a roof, a tree, water) goes here, with its own robust loss:
            # left to the least-squares loop it pulls its point sideways on a steep DEM flank,
            # the block bends and control surveys fail in its place (docs/datum.md)
            if self.n_removed + len(c) > limit:
                break
            take.append(c)
            blocks.update(m.group.block for m in c)
            self.n_removed += len(c)
        if any(m.group.kind == "dem_height" for c in take for m in c):
            # DEM heights off by tens of metres bend the block: control surveys failing beside
            # them wait for the least-squares loop, which tests them again without those heights
            dropped = [c for c in take if any(m.group.kind == "control_point" for m in c)]
            take = [c for c in take if c not in dropped]
            self.n_removed -= sum(len(c) for c in dropped)
        if take:
            nxt, collateral = remove(job, [m.group.removal for c in take for m in c if m.group.removal])
            for c in take:
                self.record(c, solution, [], job)
            self.record([], solution, collateral, job)
            self.current = nxt

    def reinstate_round(self, sn):
        """Test the removed image points and surveys against the final solution (put back with
        inflated sigmas) and put back those that pass; None when nothing is put back, else the
        re-adjusted solution."""
        bd, current = self.bd, self.current
        pool = [
            it for it in self.items
            # a fixed control point's coordinates have no sigma to put back with: not reinstated
            if it.kind in ("image_point", "control_point") and not it.reinstated and not it.fixed and it.key() not in self.once
        ]
        whole = whole_points(current, pool)
        cands = [it for it in pool if it.point in whole or testable(current, it)]
        if not cands:
            return None
        try:
            augmented = self.adjust(with_candidates(current, self.job, cands))
            sn_aug = snoop(augmented.problem, bd, linearised=augmented.take_linearised())
        except (JobError, np.linalg.LinAlgError) as exc:
            self.warnings.append(f"the reinstatement test of the removed observations failed ({exc}); none reinstated")
            return None
        n_obs = len(current.observations)
        s2 = (sn.vtpv / sn.dof, sn.dof) if bd.variance == "estimated" and sn.dof > 0 else None
        by_key = {}
        for t in sn_aug.tests:
            if t.group.kind == "image_point" and t.group.removal[1] >= n_obs:
                by_key[("image_point", t.group.removal[1] - n_obs)] = t
            elif t.group.kind == "control_point":
                by_key[("control_point", t.group.point)] = t
        back = []
        k_img = 0
        for it in cands:
            if it.kind == "image_point":
                t = by_key.get(("image_point", k_img))
                k_img += 1
            else:
                t = by_key.get(("control_point", it.point))
            if t is None:
                continue
            it.predicted, passed = predicted_decision(sn_aug, t, INFLATE, s2, whole=it.point in whole)
            if passed:
                back.append(it)
        if not back:
            return None
        nxt = reinstate(current, self.job, back)
        try:
            nxt_solution = self.adjust(nxt)
        except JobError as exc:
            self.warnings.append(f"reinstating {len(back)} observation(s) left no valid adjustment ({exc}); none reinstated")
            return None
        for it in back:
            it.reinstated = True
            self.once.add(it.key())
            e = it.entry
            if it.cluster is None:
                self.rejected.remove(e)
            else:
                e["removed"] = False
                e["reinstated"] = True
                it.cluster.removed[it.member] = False
                it.cluster.entry["removed"] = all(it.cluster.removed)
            self.reinstated.append({**{k: v for k, v in e.items() if k not in ("removed", "reinstated")}, "predicted": dict(it.predicted)})
            self.n_removed -= 0 if it.collateral else 1
        # collateral image points whose tie point is back: they are tested in the next round
        self.current = nxt
        return nxt_solution

    def run(self) -> Solution:
        bd, job = self.bd, self.job
        if bd.robust_start != "none" and bd.action == "remove" and bd.max_rejections != 0:
            self.robust_start()
        try:
            solution = self.adjust(self.current)
        except JobError as exc:
            if self.current is job:
                raise
            # the robust step removed too much: snoop one at a time from the whole job instead
            self.warnings.append(f"the robust start's removals left no valid adjustment ({exc}); snooping from the whole job")
            self.current, self.n_removed, self.limit = job, 0, None
            self.rejected.clear()
            self.not_identifiable.clear()
            self.items.clear()
            solution = self.adjust(job)
        first = solution
        solution, sn = self.snoop_loop(solution)
        for _round in range(10):
            if not (bd.reinstate and bd.action == "remove"):
                break
            again = self.reinstate_round(sn)
            if again is None:
                break
            solution, sn = self.snoop_loop(again)
        # tests still failing in the final adjustment (report only, max_rejections, not removable)
        for cluster in failing_clusters(sn, bd.separability):
            entries = [entry(m, removed=False) for m in cluster]
            if len(entries) == 1:
                self.rejected.append(entries[0])
            else:
                self.not_identifiable.append({"members": entries, "removed": False})
        return self.finish(solution, sn, first)

    def finish(self, solution: Solution, sn, first: Solution) -> Solution:
        """The last adjustment's solution, noted with the removed image points flagged, the
        warnings and the ``quality`` section."""
        bd, warnings = self.bd, self.warnings
        n_removed = self.n_removed
        if n_removed:
            warnings.append(f"data snooping removed {n_removed} observation(s) (quality.rejected, quality.not_identifiable)")
        if self.reinstated:
            warnings.append(f"{len(self.reinstated)} removed observation(s) passed the test against the final solution and were reinstated (quality.reinstated)")
        lost_points = _lost_control(self.job, self.current)
        lost = None
        if lost_points:
            before, after = first.predicted_check_rmse_planimetric_m(), solution.predicted_check_rmse_planimetric_m()
            known = before is not None and after is not None
            lost = {"points": lost_points, "predicted_check_rmse_m": {"before": before, "after": after} if known else None}
            change = (
                f"; the predicted check-point RMSE (planimetric) is now {after:.3g} m (first least-squares "
                f"adjustment, with its observations and variance factor: {before:.3g} m)" if known else ""
            )
            warnings.append(f"data snooping removed control point(s) {', '.join(lost_points)} (survey or all image points){change}")
        outliers = solution.check_point_outliers(bd.alpha0)
        if outliers:
            names = ", ".join(o.point for o in outliers)
            warnings.append(
                f"check point(s) {names} fail the discrepancy test at alpha0 = {bd.alpha0:g}: "
                "a blunder in their image points or known coordinates is likely (check points are not in the adjustment, "
                "so data snooping cannot test them; quality.check_point_outliers)"
            )
        solution.append_warnings(warnings)
        solution.set_quality(
            {
                "blunder_detection": {
                    "test": "baarda" if bd.variance == "apriori" else "pope",
                    "alpha0": bd.alpha0,
                    "beta": bd.beta,
                    "action": bd.action,
                    "max_rejections": self.cap(sn),
                    "max_rejections_rule": "given" if bd.max_rejections is not None else
                    f"{RELATIVE_MAX_REJECTIONS:.0%} of the tests, at least {MIN_MAX_REJECTIONS}",
                    "stopped_early": self.stopped_early,
                    "robust_start": bd.robust_start,
                    "reinstate": bd.reinstate,
                    "separability": bd.separability,
                    "n_removed": n_removed,
                    "adjustments": self.step,
                },
                "rejected": self.rejected,
                "not_identifiable": self.not_identifiable,
                "reinstated": self.reinstated,
                "lost_control": lost,
                "check_point_outliers": [o.as_dict() for o in outliers],
                "reliability": reliability_section(sn),
            }
        )
        solution.flag_removed(self.job, [it.flag for it in self.items if it.flag is not None and not it.reinstated])
        if bd.external_points:
            from solver.quality.external import external_points

            problem, structure, lam0, dofs = solution.problem, sn.structure, sn.lam0, [t.dof for t in sn.tests]
            solution.add_external_points(lambda checkpoints: external_points(problem, structure, lam0, dofs, checkpoints))
        return solution


def _lost_control(job: Job, final: Job) -> list[str]:
    """The control points of ``job`` that data snooping took away: their survey removed, or no
    image point of theirs left in ``final``."""
    rays = {o.point for o in final.observations}
    roles = {p.id: p.role for p in final.points}
    return [p.id for p in job.points if p.role == "gcp" and (roles.get(p.id) != "gcp" or p.id not in rays)]
