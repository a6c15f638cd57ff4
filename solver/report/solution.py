"""One adjustment at its solution, as the procedures read it (:class:`Solution`), and its report
built from it once.

The procedures that adjust more than once (:mod:`solver.procedures`) steer by what an
adjustment found: the variance factor, the estimated parameters with their sigmas, the
attitude terms the control does not determine, the check points' RMSE and discrepancy tests,
the correlations of the interior orientation. :class:`Solution` answers those with typed
values; it computes the statistics and the covariance once (:func:`solver.report.document.report_inputs`)
and builds a section of the report (:mod:`solver.report.sections`) only when asked, with the
sections before it, never twice. What a procedure adds to the report (its ``quality``
entries, warnings, the removed observations flagged) it records on the solution as
:class:`Note` s; :meth:`Solution.report` builds the remaining sections and applies the notes in
the order they were made (the innermost procedure's first).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

from solver.quality.distributions import chi2_upper_quantile
from solver.quality.flags import flag_sections
from solver.quality.tie_pairs import tie_pairs
from solver.report.document import Linearised, report_inputs
from solver.report.sections import ReportInputs, build_through, ordered
from solver.schema.job import ImageObservation, Job
from solver.state import AdjustmentState


@dataclass(frozen=True)
class Estimate:
    """One parameter as the report states it: value and sigma (a posteriori) in report units."""

    name: str
    value: float
    sigma: float | None
    unit: str
    estimated: bool


@dataclass(frozen=True)
class BlockEstimates:
    """The parameters of an image (``shared_with``: the images sharing its attitude block, itself
    included; empty when not shared) or of a camera."""

    id: str
    parameters: tuple[Estimate, ...]
    shared_with: tuple[str, ...] = ()

    def estimated(self) -> dict[str, Estimate]:
        return {p.name: p for p in self.parameters if p.estimated}


@dataclass(frozen=True)
class Undetermined:
    """An attitude term whose sigma, as an angle over half the image, exceeds the plausible limit."""

    image: str
    parameter: str
    angle_sigma_deg: float

    def as_dict(self) -> dict[str, Any]:
        return {"image": self.image, "parameter": self.parameter, "angle_sigma_deg": self.angle_sigma_deg}


@dataclass(frozen=True)
class CheckPointOutlier:
    """A check point whose discrepancy test fails at the snooping level (``quality.check_point_outliers``)."""

    point: str
    images: Any
    statistic: float
    dof: int
    critical: float
    discrepancy_m: Any

    def as_dict(self) -> dict[str, Any]:
        return {"point": self.point, "images": self.images, "statistic": self.statistic, "dof": self.dof,
                "critical": self.critical, "discrepancy_m": self.discrepancy_m}


Note = Callable[[dict[str, Any]], None]
"""A procedure's addition to the report, applied to the finished report (in place)."""


def _estimates(entry: dict[str, Any]) -> tuple[Estimate, ...]:
    return tuple(Estimate(p["name"], p["value"], p["sigma"], p["unit"], p["estimated"]) for p in entry["parameters"])


class Solution:
    """The problem at its solution, the solve's outcome and what the report is built from."""

    def __init__(self, problem: AdjustmentState, outcome: Any, elapsed_s: float, datum: Any = None, keep_linearised: bool = False) -> None:
        self.problem = problem
        self.outcome = outcome
        self.datum = datum  # solver.quality.datum.DatumAnalysis of the solve (None: not analysed)
        self._inputs: ReportInputs
        self._inputs, self._linearised = report_inputs(problem, outcome, keep_linearised)
        self._elapsed_s = elapsed_s  # validation to the solve's end, then the report's sections as they are built
        self._notes: list[Note] = []
        self._report: dict[str, Any] | None = None

    # ---- statistics --------------------------------------------------------------------------
    @property
    def job(self) -> Job:
        return self.problem.job

    @property
    def sigma0(self) -> float | None:
        """sigma0 a posteriori (None without degrees of freedom)."""
        return self._inputs.sigma0

    @property
    def dof(self) -> int:
        return self._inputs.dof

    @property
    def vtpv(self) -> float:
        """v^T P v of the whitened residuals (a-priori sigma0 = 1)."""
        return self._inputs.vtpv

    def kept_linearised(self) -> Linearised | None:
        """The kept linearisation (as :meth:`take_linearised`), read without handing it over."""
        return self._linearised

    def take_linearised(self) -> Linearised | None:
        """The linearisation the covariance came from, with its Jacobians (kept when the
        adjustment was asked to, for data snooping's tests; None otherwise or without a
        covariance), handed over once: the solution then holds it no longer."""
        linearised, self._linearised = self._linearised, None
        return linearised

    # ---- what the sections say, typed --------------------------------------------------------
    def _section(self, name: str) -> Any:
        t0 = time.perf_counter()
        build_through(self._inputs, name)
        self._elapsed_s += time.perf_counter() - t0
        return self._inputs.sections.get(name)

    def images(self) -> list[BlockEstimates]:
        """Each image's parameters, in image order."""
        return [BlockEstimates(e["id"], _estimates(e), tuple(e.get("attitude_shared_with") or ())) for e in self._section("images")]

    def cameras(self) -> list[BlockEstimates]:
        """Each camera with interior orientation: its parameters."""
        return [BlockEstimates(e["id"], _estimates(e)) for e in self._section("cameras") or []]

    def check_rmse_m(self) -> dict[str, float | None]:
        """The check points' RMSE (m) by component (e, n, u, planimetric, 3d; None: no check points)."""
        return dict(self._section("checkpoints")["rmse_m"])

    def check_rmse_3d_m(self) -> float | None:
        """The check points' 3-D RMSE (m; None: no check points)."""
        return self._section("checkpoints")["rmse_m"].get("3d")

    def predicted_check_rmse_planimetric_m(self) -> float | None:
        """The predicted planimetric RMSE of the check points (None without them or a covariance)."""
        predicted = self._section("checkpoints").get("predicted_rmse_m")
        return None if not predicted else predicted.get("planimetric")

    def check_point_outliers(self, alpha0: float) -> list[CheckPointOutlier]:
        """Check points whose discrepancy test (d^T Sigma^-1 d, chi-square) fails at ``alpha0``,
        worst first: a check point is not in the adjustment, so a blunder in its image points
        (or its known coordinates) shows only here."""
        out = []
        for it in self._section("checkpoints").get("points", []):
            t = it.get("discrepancy_test")
            if not t or not t.get("dof"):
                continue
            critical = chi2_upper_quantile(alpha0, t["dof"])
            if t["statistic"] > critical:
                out.append(CheckPointOutlier(it["id"], it.get("images"), t["statistic"], t["dof"], critical, it["discrepancy_m"]))
        return sorted(out, key=lambda o: -o.statistic / o.critical)

    def undetermined_attitude(self) -> list[Undetermined]:
        """The attitude terms the control does not determine (the report's ``implausible_sigma`` warnings)."""
        return [Undetermined(w["image"], w["parameter"], w["angle_sigma_deg"])
                for w in self._section("quality")["warnings"] if w.get("kind") == "implausible_sigma"]

    def interior_correlations(self) -> list[dict[str, Any]]:
        """The listed correlation pairs that involve an interior-orientation parameter."""
        return [p for p in self._section("correlations")["pairs"] if "IOP" in p.get("kinds", "")]

    def observation_entry(self, obs: ImageObservation) -> dict[str, Any] | None:
        """``obs``'s entry in the report's ``observations`` (its residuals in this adjustment),
        marked ``rejected``; None when it is not there."""
        for item in self._section("observations"):
            if (item["image"], item["point"], item["line"], item["column"]) == (obs.image, obs.point, obs.line, obs.column):
                return {**item, "rejected": True}
        return None

    # ---- what the procedures add -------------------------------------------------------------
    def note(self, note: Note) -> None:
        """Record an addition to the report (applied by :meth:`report`, in the order recorded)."""
        if self._report is not None:
            raise RuntimeError("the report of this solution is built already")
        self._notes.append(note)

    def prepend_warning(self, text: str, position: int = 0) -> None:
        self.note(lambda report: report["warnings"].insert(position, text))

    def append_warnings(self, texts: list[str]) -> None:
        self.note(lambda report: report["warnings"].extend(texts))

    def set_quality(self, entries: dict[str, Any]) -> None:
        """Entries of the ``quality`` section (added in order, after the ones it has)."""
        self.note(lambda report: report.setdefault("quality", {}).update(entries))

    def set_section(self, name: str, value: Any) -> None:
        """A top-level section of a procedure's (after the others)."""
        self.note(lambda report: report.__setitem__(name, value))

    def flag_removed(self, job: Job, flagged: list[dict[str, Any]]) -> None:
        """The removed image points' entries (``flagged``, marked ``rejected``) appended to
        ``observations``, every other entry marked not rejected; the families' sections flag
        theirs (:func:`solver.quality.flags.flag_sections`) and ``quality.tie_pairs`` is
        computed from ``job`` and the flagged list."""

        def apply(report: dict[str, Any]) -> None:
            for item in report["observations"]:
                item["rejected"] = False
            report["observations"] += flagged
            report["quality"]["tie_pairs"] = tie_pairs(job, report["observations"])
            flag_sections(report)

        self.note(apply)

    def add_external_points(self, external: Callable[[dict[str, Any] | None], Any]) -> None:
        """``quality.reliability.external_points`` from ``external(checkpoints section)``."""
        self.note(lambda report: report["quality"]["reliability"].__setitem__("external_points", external(report.get("checkpoints"))))

    # ---- the report --------------------------------------------------------------------------
    def report(self) -> dict[str, Any]:
        """The report (docs/report-contract.md), built once: every section, then the notes."""
        if self._report is None:
            t0 = time.perf_counter()
            build_through(self._inputs)
            report = ordered(self._inputs.sections)
            report["adjustment"]["total_time_s"] = self._elapsed_s + (time.perf_counter() - t0)
            for note in self._notes:
                note(report)
            self._report = report
        return self._report
