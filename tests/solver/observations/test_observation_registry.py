"""The observation-family registry (solver/observations/registry.py): every observation other
than the core (image points, control points) belongs to a family there, and the stages walk
``registry.FAMILIES`` instead of naming families.

The done-when of that design: a new family is its module, its schema fields and one registry
line. ``_Fixes`` below is such a family, written the way a new module would be (weighted direct
observations of one platform parameter of an image, ``fixes[]`` in the job), with its schema
fields in a ``Job`` subclass and its registry line put in by ``monkeypatch``; no stage is
changed, and the fake is validated, counted, solved, tested by data snooping (a blunder among
its observations is rejected and removed), reported and flagged.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import BaseModel, ConfigDict, Field
from tolerances import SAME_NUMBER_REL

from solver.adjust import adjust_job, prepare
from solver.engine.linalg import linearise
from solver.engine.validate import validate_job
from solver.errors import Problem
from solver.observations import registry
from solver.observations.family import Count, FamilyDefaults, GroupSpec, Labelled, ObservationFamily, ReportContext
from solver.schema.job import Job, load_job

BLUNDER_ESTIMATE_REL = 0.3  # the estimated error of a rejected fix vs the blunder: the other fixes and the rays hold the parameter
WRITTEN_OFFSET_SIGMA = 1e-6  # offsets of the values as written, in sigmas (rounding of large values)

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
HOOKS = ("check", "terms", "refresh", "groups", "report", "without", "removal_details", "flag")


def test_registry_lists_every_family_with_the_whole_interface() -> None:
    names = [f.name for f in registry.FAMILIES]
    assert names == ["ephemeris", "attitude", "lines", "passes", "interior", "dem"]
    for family in registry.FAMILIES:
        for hook in HOOKS:
            assert callable(getattr(family, hook)), (family.name, hook)


# ---- the fake family: "module", schema fields, registry line ----------------------------------


class Fix(BaseModel):
    """A measured value of one parameter of an image's model (report units) with its sigma."""

    model_config = ConfigDict(extra="forbid")
    image: str
    parameter: str
    value: float
    sigma: float = Field(gt=0)


class FixJob(Job):
    """The job with the fake family's schema fields."""

    fixes: list[Fix] = Field(default_factory=list)


class _FixTerm:
    """r = (p[col] - value) / sigma (internal units), one row."""

    n_residuals = 1

    def __init__(self, col: int, nfree: int, value: float, sigma: float) -> None:
        self.col, self.value, self.sigma = col, value, sigma
        self.jac = np.zeros((1, nfree))
        self.jac[0, col] = 1.0 / sigma

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.array([(params[self.col] - self.value) / self.sigma]), self.jac


def _spec(img: Any, name: str) -> tuple[int, Any]:
    """(free column, parameter spec) of parameter ``name`` of image state ``img``."""
    spec = next(s for s in img.model.parameters(img.options) if s.name == name)
    return [int(j) for j in img.free_idx].index(spec.index), spec


class _Fixes(FamilyDefaults):
    name = "fixes"

    def check(self, job: Any) -> tuple[list[Problem], Count]:
        images = {im.id for im in job.images}
        issues = [
            Problem("fix_unknown_image", f"fix {k} refers to unknown image {f.image!r}", ("fixes", k, "image"))
            for k, f in enumerate(getattr(job, "fixes", []))
            if f.image not in images
        ]
        return issues, Count(n_observations=0 if issues else len(getattr(job, "fixes", [])))

    def terms(self, problem: Any) -> list[Labelled]:
        out = []
        for k, f in enumerate(getattr(problem.job, "fixes", [])):
            img = next(im for im in problem.images if im.id == f.image)
            col, spec = _spec(img, f.parameter)
            term = _FixTerm(col, img.nfree, f.value / spec.to_report, f.sigma / abs(spec.to_report))
            out.append(Labelled(self, term, "image", img.index, k))
        return out

    def groups(self, problem: Any, labelled: Labelled) -> list[GroupSpec]:
        f = problem.job.fixes[labelled.tag]
        label = {"image": f.image, "parameter": f.parameter, "value": f.value}
        return [GroupSpec("fix", np.arange(1), label, np.array([f.sigma]), "report units", ["value"], -1.0, ("fix", labelled.tag))]

    def report(self, problem: Any, ctx: ReportContext) -> dict[str, Any]:
        items = []
        for lab in self.terms(problem):
            r, _j = lab.term.evaluate(problem.images[lab.index].params)
            f = problem.job.fixes[lab.tag]
            items.append({"image": f.image, "parameter": f.parameter, "value": f.value, "residual": float(-r[0] * f.sigma)})
        return {"fixes": {"items": items, "rejected": []}}

    def without(self, job: Any, removals: list[tuple]) -> tuple[Any, list[dict[str, Any]]]:
        gone = {r[1] for r in removals if r[0] == "fix"}
        if not gone:
            return job, []
        return job.model_copy(update={"fixes": [f for k, f in enumerate(job.fixes) if k not in gone]}), []

    def flag(self, report: dict[str, Any], removed: list[dict[str, Any]]) -> None:
        section = report.get("fixes")
        if section is not None:
            section["rejected"] = [{"image": r["image"], "value": r["value"]} for r in removed if r["kind"] == "fix"]


FAKE: ObservationFamily = _Fixes()


@pytest.fixture
def with_fake(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(registry, "FAMILIES", (*registry.FAMILIES, FAKE))  # the one registry line


def _nadir() -> dict[str, Any]:
    return json.loads((EXAMPLES / "prism-nadir.json").read_text())


BLUNDER_SIGMAS = 40.0  # far beyond Baarda's 3.29 at alpha0 = 0.001 even at redundancy 0.3


def _fix_job(doc: dict[str, Any], value: float, sigma: float, name: str, image: str) -> FixJob:
    """Four fixes of ``name``: three within a sigma of ``value``, one ``BLUNDER_SIGMAS`` off."""
    offsets = [0.3, -0.5, 0.2, BLUNDER_SIGMAS]
    fixes = [{"image": image, "parameter": name, "value": value + o * sigma, "sigma": sigma} for o in offsets]
    doc = {**doc, "fixes": fixes, "options": {**(doc.get("options") or {}), "blunder_detection": {"robust_start": "none"}}}
    return FixJob.model_validate(doc)


def test_a_fake_family_is_validated_counted_solved_snooped_and_reported(with_fake: None) -> None:
    doc = _nadir()
    plain = adjust_job(load_job(doc))
    image = plain["images"][0]
    param = next(p for p in image["parameters"] if p["estimated"] and p["sigma"])
    name, value, sigma = param["name"], param["value"], param["sigma"]
    job = _fix_job(doc, value, sigma, name, image["id"])

    # validated and counted: four more observation equations, no more unknowns
    before, after = validate_job(load_job(doc)), validate_job(job)
    assert after["valid"] and after["n_observations"] == before["n_observations"] + 4
    assert after["n_unknowns"] == before["n_unknowns"]
    bad = validate_job(job.model_copy(update={"fixes": [Fix(image="nowhere", parameter=name, value=value, sigma=sigma)]}))
    assert not bad["valid"] and [p["location"] for p in bad["problems"] if p["code"] == "fix_unknown_image"] == [["fixes", 0, "image"]]

    # solved: the linearisation carries the family's rows, placed on the image's block
    problem = prepare(job)
    lin = linearise(problem)
    assert sum(1 for t in lin.terms if t.family is FAKE) == 4
    assert len(lin.residuals) == len(linearise(prepare(load_job(doc))).residuals) + 4

    # snooped: the blunder is the one fix rejected and removed; the others stay
    report = adjust_job(job)
    rejected = [r for r in report["quality"]["rejected"] if r["kind"] == "fix"]
    assert len(rejected) == 1 and rejected[0]["removed"]
    assert math.isclose(rejected[0]["value"], value + BLUNDER_SIGMAS * sigma, rel_tol=SAME_NUMBER_REL)
    assert rejected[0]["w"] > rejected[0]["critical"]
    # the estimated error: about the blunder (the other fixes and the rays hold the parameter)
    assert rejected[0]["estimated_error"][0] == pytest.approx(BLUNDER_SIGMAS * sigma, rel=BLUNDER_ESTIMATE_REL)
    groups = [g for g in report["quality"]["reliability"]["groups"] if g["kind"] == "fix"]
    assert len(groups) == 3  # the remaining fixes have their reliability numbers
    assert all(0.0 < g["redundancy"][0] < 1.0 for g in groups)

    # reported and flagged: its section has the three fixes left, small residuals, the flag
    section = report["fixes"]
    offsets = [(f["value"] - value) / sigma for f in section["items"]]
    assert offsets == pytest.approx([0.3, -0.5, 0.2], abs=WRITTEN_OFFSET_SIGMA)
    assert all(abs(f["residual"]) < 2 * sigma for f in section["items"])
    assert section["rejected"] == [{"image": image["id"], "value": value + BLUNDER_SIGMAS * sigma}]
    assert report["adjustment"]["n_observations"] == plain["adjustment"]["n_observations"] + 3


def test_without_the_registry_line_the_fake_is_ignored() -> None:
    """The same job with the family not registered: its fields are carried, nothing counts them."""
    doc = _nadir()
    job = _fix_job(doc, 0.0, 1.0, "X0", doc["images"][0]["id"])
    assert validate_job(job)["n_observations"] == validate_job(load_job(doc))["n_observations"]
