"""Data snooping (``options.blunder_detection``; docs/quality.md): test, remove the worst rejected
observation (group), re-adjust, and put back what passes against the final solution.

The tests, reliability and the ``quality`` report section are :mod:`solver.quality.outlier_tests`;
the job without the removed observations :mod:`solver.quality.removal` (the core's removals
and each observation family's ``without``); their flags in the families' report sections
:mod:`solver.quality.flags`. This module is the loop.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from solver.errors import JobError
from solver.procedures.single import adjust_once
from solver.quality.distributions import chi2_upper_quantile
from solver.quality.flags import flag_sections
from solver.quality.outlier_tests import entry, failing_clusters, predicted_test, reliability_section, snoop
from solver.quality.removal import INFLATE, reinstate, remove, testable, whole_points, with_candidates
from solver.quality.tie_pairs import tie_pairs
from solver.schema.job import Job

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


def snooping_adjustment(job: Job, progress, cancel, models, fraction_range: tuple[float, float]) -> dict[str, Any]:
    """Data snooping (docs/quality.md): adjust, test every observation group, remove the worst
    rejected one (with the tests it cannot be separated from) and re-adjust, until no test fails
    or ``max_rejections`` is reached; ``robust_start`` first removes, in one step, every group
    whose test fails on the residuals of a robust adjustment; ``reinstate`` then tests every
    removed observation against the final solution and puts back those that pass (re-adjusting
    and snooping again, until nothing changes). The report is that of the last adjustment, with
    the ``quality`` section and the removed image points flagged in ``observations``."""
    return _Snooping(job, progress, cancel, models, fraction_range).run()


def _removal_key(item: dict) -> tuple:
    """What identifies a removed observation across the loop's jobs (an image point by its
    measurement, a survey by its point)."""
    o = item["obs"]
    return (item["kind"], item["point"]) if o is None else (item["kind"], o.image, o.point, o.line, o.column)


def _flagged_observation(report: dict[str, Any], obs) -> dict[str, Any] | None:
    """``obs``'s entry in ``report["observations"]`` marked ``rejected``."""
    for item in report["observations"]:
        if (item["image"], item["point"], item["line"], item["column"]) == (obs.image, obs.point, obs.line, obs.column):
            return {**item, "rejected": True}
    return None


class _Snooping:
    """One data-snooping run (:func:`snooping_adjustment`): the job as it stands after the
    removals so far (``current``), the report entries, and every removal as an item (kind, obs
    (the ImageObservation, for image points), point, its report entry, its non-identifiable
    group, its flagged ``observations`` entry, whether it was reinstated)."""

    def __init__(self, job: Job, progress, cancel, models, fraction_range: tuple[float, float]) -> None:
        self.job = job
        self.bd = job.options.blunder_detection
        self.progress, self.cancel, self.models = progress, cancel, models
        self.f0, self.f1 = fraction_range
        self.step = 0
        self.current = job
        self.n_removed = 0
        self.rejected: list[dict[str, Any]] = []
        self.not_identifiable: list[dict[str, Any]] = []
        self.reinstated: list[dict[str, Any]] = []
        self.warnings: list[str] = []
        self.items: list[dict[str, Any]] = []
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

    def adjust(self, job: Job):
        """``adjust_once`` in the next slice of the progress range (halving slices)."""
        k = self.step
        self.step += 1
        window = (self.f0 + (self.f1 - self.f0) * (1.0 - 0.5**k), self.f0 + (self.f1 - self.f0) * (1.0 - 0.5 ** (k + 1)))
        return adjust_once(job, self.progress, self.cancel, self.models, window)

    def record(self, cluster, report, collateral, current: Job) -> None:
        """Enter the removed ``cluster`` (one test, or a non-identifiable group) and the
        ``collateral`` removals in the report lists and the items."""
        entries = [entry(m, removed=m.group.removal is not None) for m in cluster]
        group = None
        if len(entries) == 1:
            self.rejected.append(entries[0])
        elif entries:
            group = {"members": entries, "removed": all(e["removed"] for e in entries)}
            self.not_identifiable.append(group)
        for m, e in zip(cluster, entries):
            if m.group.removal is None:
                continue
            if m.group.family is not None:  # e.g. a line point's measured pixels (its index shifts with removals)
                e.update(m.group.family.removal_details(current, m.group.removal))
            obs = current.observations[m.group.removal[1]] if m.group.kind == "image_point" else None
            self.items.append({"kind": m.group.kind, "obs": obs, "point": e.get("point"), "entry": e, "group": group,
                               "flag": _flagged_observation(report, obs) if obs is not None else None})
        for c in collateral:
            if c.get("kind", "image_point") != "image_point":  # a family's (a line image left with fewer than two points)
                label = {k: v for k, v in c.items() if k not in ("units", "components")}
                self.rejected.append({**label, "w": None, "critical": None, "dof": 0, "estimated_error": None, "units": c["units"],
                                      "components": c["components"], "removed": True, "collateral": True})
                continue
            e = {"kind": "image_point", **c, "w": None, "critical": None, "dof": 0, "estimated_error": None,
                 "units": "px", "components": ["line", "column"], "removed": True, "collateral": True}
            self.rejected.append(e)
            obs = next(o for o in current.observations if (o.image, o.point) == (c["image"], c["point"]))
            self.items.append({"kind": "image_point", "obs": obs, "point": c["point"], "entry": e, "group": None,
                               "flag": _flagged_observation(report, obs), "collateral": True})

    def snoop_loop(self, problem, report):
        """Remove the worst failed cluster and re-adjust until no removable test fails (or
        ``max_rejections``, or the adjustment without it fails); ``action: report`` tests only."""
        bd = self.bd
        while True:
            sn = snoop(problem, bd)
            if bd.action == "report":
                return problem, report, sn
            clusters = [c for c in failing_clusters(sn, bd.separability) if c[0].group.removal]
            if not clusters:
                return problem, report, sn
            cluster = clusters[0]
            limit = self.cap(sn)
            if self.n_removed + len(cluster) > limit:
                rule = "" if bd.max_rejections is not None else f" ({RELATIVE_MAX_REJECTIONS:.0%} of the {self.n_tests} tests, at least {MIN_MAX_REJECTIONS})"
                self.stop("max_rejections", f"data snooping stopped at max_rejections = {limit}{rule}: some tests still fail", sn)
                return problem, report, sn
            nxt, collateral = remove(self.current, [m.group.removal for m in cluster if m.group.removal])
            try:
                nxt_problem, nxt_report = self.adjust(nxt)
            except JobError as exc:  # rank, unusable solution, or the job no longer valid
                self.stop("adjustment_failed", f"data snooping stopped: without the next rejected observation the adjustment fails ({exc})", sn)
                return problem, report, sn
            self.record(cluster, report, collateral, self.current)
            self.n_removed += len(cluster)
            self.current, problem, report = nxt, nxt_problem, nxt_report

    def robust_start(self) -> None:
        """Adjust with the robust loss and remove, in one step, the worst failed cluster of each
        block (image points and surveys of estimated points only)."""
        bd, job = self.bd, self.job
        robust = job.model_copy(update={"options": job.options.model_copy(update={"loss": bd.robust_start})})
        problem, report = self.adjust(robust)
        sn = snoop(problem, bd, robust=True)
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
            if any(m.group.label.get("fixed") or m.group.family is not None for m in c):
                # a fixed control point (its rays share one loss block per image in the robust
                # solve) and the image-only terms (lines, ephemeris, attitude: the loss does not
                # act on them) cannot be reinstated: the least-squares loop tests them
                continue
            if self.n_removed + len(c) > limit:
                break
            take.append(c)
            blocks.update(m.group.block for m in c)
            self.n_removed += len(c)
        if take:
            nxt, collateral = remove(job, [m.group.removal for c in take for m in c if m.group.removal])
            for c in take:
                self.record(c, report, [], job)
            self.record([], report, collateral, job)
            self.current = nxt

    def reinstate_round(self, sn):
        """Test the removed image points and surveys against the final solution (put back with
        inflated sigmas) and put back those that pass; None when nothing is put back, else the
        re-adjusted (problem, report)."""
        bd, current = self.bd, self.current
        pool = [
            it for it in self.items
            # a fixed control point's coordinates have no sigma to put back with: not reinstated
            if it["kind"] in ("image_point", "control_point") and not it.get("reinstated") and not it["entry"].get("fixed")
            and _removal_key(it) not in self.once
        ]
        whole = whole_points(current, pool)
        cands = [it for it in pool if it["point"] in whole or testable(current, it)]
        if not cands:
            return None
        try:
            aug_problem, _aug_report = self.adjust(with_candidates(current, self.job, cands))
            sn_aug = snoop(aug_problem, bd)
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
                by_key[("control_point", t.group.label["point"])] = t
        back = []
        k_img = 0
        for it in cands:
            if it["kind"] == "image_point":
                t = by_key.get(("image_point", k_img))
                k_img += 1
            else:
                t = by_key.get(("control_point", it["point"]))
            if t is None:
                continue
            test = predicted_test(sn_aug, t, INFLATE, s2, whole=it["point"] in whole)
            it["predicted"] = test
            if test["passed"]:
                back.append(it)
        if not back:
            return None
        nxt = reinstate(current, self.job, back)
        try:
            nxt_problem, nxt_report = self.adjust(nxt)
        except JobError as exc:
            self.warnings.append(f"reinstating {len(back)} observation(s) left no valid adjustment ({exc}); none reinstated")
            return None
        for it in back:
            it["reinstated"] = True
            self.once.add(_removal_key(it))
            e = it["entry"]
            if it["group"] is None:
                self.rejected.remove(e)
            else:
                e["removed"] = False
                e["reinstated"] = True
                it["group"]["removed"] = all(m["removed"] for m in it["group"]["members"])
            self.reinstated.append({**{k: v for k, v in e.items() if k not in ("removed", "reinstated")},
                                    "predicted": {k: v for k, v in it["predicted"].items()}})
            self.n_removed -= 0 if it.get("collateral") else 1
        # collateral image points whose tie point is back: they are tested in the next round
        self.current = nxt
        return nxt_problem, nxt_report

    def run(self) -> dict[str, Any]:
        bd, job = self.bd, self.job
        if bd.robust_start != "none" and bd.action == "remove" and bd.max_rejections != 0:
            self.robust_start()
        try:
            problem, report = self.adjust(self.current)
        except JobError as exc:
            if self.current is job:
                raise
            # the robust step removed too much: snoop one at a time from the whole job instead
            self.warnings.append(f"the robust start's removals left no valid adjustment ({exc}); snooping from the whole job")
            self.current, self.n_removed, self.limit = job, 0, None
            self.rejected.clear()
            self.not_identifiable.clear()
            self.items.clear()
            problem, report = self.adjust(job)
        first_report = report
        problem, report, sn = self.snoop_loop(problem, report)
        for _round in range(10):
            if not (bd.reinstate and bd.action == "remove"):
                break
            again = self.reinstate_round(sn)
            if again is None:
                break
            problem, report, sn = self.snoop_loop(*again)
        # tests still failing in the final adjustment (report only, max_rejections, not removable)
        for cluster in failing_clusters(sn, bd.separability):
            entries = [entry(m, removed=False) for m in cluster]
            if len(entries) == 1:
                self.rejected.append(entries[0])
            else:
                self.not_identifiable.append({"members": entries, "removed": False})
        return self.finish(problem, report, sn, first_report)

    def finish(self, problem, report, sn, first_report) -> dict[str, Any]:
        """The report of the last adjustment with the removed image points flagged, the
        warnings and the ``quality`` section."""
        bd, warnings = self.bd, self.warnings
        for item in report["observations"]:
            item["rejected"] = False
        report["observations"] += [it["flag"] for it in self.items if it["flag"] is not None and not it.get("reinstated")]
        n_removed = self.n_removed
        if n_removed:
            warnings.append(f"data snooping removed {n_removed} observation(s) (quality.rejected, quality.not_identifiable)")
        if self.reinstated:
            warnings.append(f"{len(self.reinstated)} removed observation(s) passed the test against the final solution and were reinstated (quality.reinstated)")
        lost = _lost_control(self.job, self.current, first_report, report)
        if lost is not None:
            pr = lost["predicted_check_rmse_m"]
            change = (
                f"; the predicted check-point RMSE (planimetric) is now {pr['after']:.3g} m (first least-squares "
                f"adjustment, with its observations and variance factor: {pr['before']:.3g} m)" if pr else ""
            )
            warnings.append(f"data snooping removed control point(s) {', '.join(lost['points'])} (survey or all image points){change}")
        outliers = _check_point_outliers(report, bd.alpha0)
        if outliers:
            warnings.append(
                f"check point(s) {', '.join(o['point'] for o in outliers)} fail the discrepancy test at alpha0 = {bd.alpha0:g}: "
                "a blunder in their image points or known coordinates is likely (check points are not in the adjustment, "
                "so data snooping cannot test them; quality.check_point_outliers)"
            )
        report["warnings"] += warnings
        report.setdefault("quality", {})
        report["quality"].update(
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
                "check_point_outliers": outliers,
                "reliability": reliability_section(sn),
                "tie_pairs": tie_pairs(self.job, report["observations"]),
            }
        )
        flag_sections(report)
        if bd.external_points:
            from solver.quality.external import external_points

            report["quality"]["reliability"]["external_points"] = external_points(
                problem, sn.structure, sn.lam0, [t.dof for t in sn.tests], report.get("checkpoints")
            )
        return report


def _check_point_outliers(report: dict[str, Any], alpha0: float) -> list[dict[str, Any]]:
    """Check points whose discrepancy test (d^T Sigma^-1 d, chi-square; docs/report-contract.md)
    fails at the snooping level ``alpha0``, worst first: a check point is not in the adjustment,
    so a blunder in its image points (or its known coordinates) shows only here."""
    out = []
    for it in report.get("checkpoints", {}).get("points", []):
        t = it.get("discrepancy_test")
        if not t or not t.get("dof"):
            continue
        critical = chi2_upper_quantile(alpha0, t["dof"])
        if t["statistic"] > critical:
            out.append({"point": it["id"], "images": it.get("images"), "statistic": t["statistic"], "dof": t["dof"],
                        "critical": critical, "discrepancy_m": it["discrepancy_m"]})
    return sorted(out, key=lambda o: -o["statistic"] / o["critical"])


def _lost_control(job: Job, final: Job, first: dict[str, Any], last: dict[str, Any]) -> dict[str, Any] | None:
    """The control points of ``job`` that data snooping took away (their survey removed, or
    no image point of theirs left in ``final``) and the predicted planimetric check-point RMSE
    of the first and the last adjustment (null without check points or covariance)."""
    rays = {o.point for o in final.observations}
    roles = {p.id: p.role for p in final.points}
    lost = [p.id for p in job.points if p.role == "gcp" and (roles.get(p.id) != "gcp" or p.id not in rays)]
    if not lost:
        return None

    def predicted(rep: dict[str, Any]) -> float | None:
        pr = rep.get("checkpoints", {}).get("predicted_rmse_m")
        return None if not pr else pr.get("planimetric")

    before, after = predicted(first), predicted(last)
    return {"points": lost, "predicted_check_rmse_m": None if before is None or after is None else {"before": before, "after": after}}
