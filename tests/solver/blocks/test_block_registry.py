"""The parameter-block registry (solver/blocks/registry.py): every kind of parameter block is one
module and one registry line, and the stages walk ``registry.BLOCK_KINDS``.

The done-when of that design: a new kind of block, and the observation family on it, are each
their module and one registry line. ``_ClockKind`` below is such a kind, written the way a new
module would be: a per-image time offset (one parameter, seconds) with readings of it as its
family (``_ClockReadings``: weighted direct observations, one of them a blunder), schema fields
in a ``Job`` subclass, both registry lines put in by ``monkeypatch``. No stage is changed, and
the kind is validated, counted, assembled, laid out, solved, named, reported, and its blunder
reading rejected and removed by data snooping (with and without its robust reweighting start).

A second fake family acts on the ground points (``point`` blocks: a height reading per tie
point, the shape of heights taken from a DEM): its rows join the point's normal block and its
reliability block, and a blunder among them is removed.

The independent evidence: a block observed only by its readings is estimated as their weighted
mean, with the standard deviation of a weighted mean (sigma0 a posteriori times
1 / sqrt(sum of weights)); nothing of the adjustment computes either that way.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import BaseModel, ConfigDict, Field
from tolerances import SAME_NUMBER_REL

from solver.adjust import adjust_job, prepare
from solver.blocks import registry as blocks
from solver.blocks.kind import BlockDefaults
from solver.engine.assemble import parameter_names
from solver.engine.linalg import layout, linearise
from solver.engine.validate import validate_job
from solver.errors import Problem
from solver.observations import registry as families
from solver.observations.family import Count, FamilyDefaults, GroupSpec, Labelled
from solver.schema.job import Job, load_job

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
BLUNDER_SIGMAS = 40.0  # far beyond Baarda's 3.29 at alpha0 = 0.001
# the estimate of a block observed only by its readings: a weighted mean computed two ways (the
# solve stops at Ceres' tolerances, ~1e-10 relative here)
WEIGHTED_MEAN_REL = 1e-6
HOOKS = ("check", "build", "blocks", "addressed", "initialise", "refresh", "names", "report")


def test_registry_lists_every_kind_with_the_whole_interface() -> None:
    assert [k.name for k in blocks.BLOCK_KINDS] == ["image", "camera", "pass", "point"]
    assert [k.eliminated for k in blocks.BLOCK_KINDS] == [False, False, False, True]
    for kind in blocks.BLOCK_KINDS:
        for hook in HOOKS:
            assert callable(getattr(kind, hook)), (kind.name, hook)


# ---- the fake kind and its family: "modules", schema fields, registry lines -------------------


class Reading(BaseModel):
    """A reading of an image's time offset (s) with its sigma (s)."""

    model_config = ConfigDict(extra="forbid")
    image: str
    value_s: float
    sigma_s: float = Field(gt=0)


class ClockJob(Job):
    """The job with the fake kind's schema field."""

    clock_readings: list[Reading] = Field(default_factory=list)


@dataclass
class ClockBlock:
    """One image's time offset (s)."""

    index: int
    image: int
    params: np.ndarray

    @property
    def nfree(self) -> int:
        return 1


class _ClockKind(BlockDefaults):
    """A per-image time offset, one block per image that has readings."""

    name = "clock"

    @staticmethod
    def _images(job: Any) -> list[str]:
        known = {im.id for im in job.images}
        return list(dict.fromkeys(r.image for r in getattr(job, "clock_readings", []) if r.image in known))

    def check(self, job: Any) -> tuple[list[Problem], int]:
        known = {im.id for im in job.images}
        issues = [
            Problem("clock_unknown_image", f"clock reading {k} refers to unknown image {r.image!r}", ("clock_readings", k, "image"))
            for k, r in enumerate(getattr(job, "clock_readings", []))
            if r.image not in known
        ]
        return issues, len(self._images(job))

    def build(self, problem: Any, config: Any) -> list[ClockBlock]:
        index = {im.id: im.index for im in problem.images}
        return [ClockBlock(k, index[i], np.zeros(1)) for k, i in enumerate(self._images(problem.job))]

    def initialise(self, problem: Any, states: dict[int, Any]) -> list[Problem]:
        for block in self.blocks(problem):  # the first reading of the image
            first = next(r for r in problem.job.clock_readings if r.image == problem.images[block.image].id)
            block.params[:] = first.value_s
        return []

    def names(self, problem: Any) -> list[str]:
        return [f"{problem.images[b.image].id}/dt" for b in self.blocks(problem)]

    def report(self, problem: Any, ctx: Any) -> dict[str, Any]:
        items = []
        for b in self.blocks(problem):
            cov = ctx.block(self.name, b.index, 1)
            sigma = None if cov is None else math.sqrt(cov[0, 0] * ctx.var_factor)
            items.append({"image": problem.images[b.image].id, "value_s": float(b.params[0]), "sigma_s": sigma, "rejected": []})
        return {"clocks": items}


class _ReadingTerm:
    """r = (dt - value) / sigma, one row."""

    n_residuals = 1

    def __init__(self, value: float, sigma: float) -> None:
        self.value, self.sigma = value, sigma

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.array([(params[0] - self.value) / self.sigma]), np.array([[1.0 / self.sigma]])


class _ClockReadings(FamilyDefaults):
    name = "clock_readings"

    def check(self, job: Any) -> tuple[list[Problem], Count]:
        known = {im.id for im in job.images}
        return [], Count(n_observations=sum(1 for r in getattr(job, "clock_readings", []) if r.image in known))

    def terms(self, problem: Any) -> list[Labelled]:
        block_of = {problem.images[b.image].id: b.index for b in problem.blocks.get("clock", [])}
        return [
            Labelled(self, _ReadingTerm(r.value_s, r.sigma_s), "clock", block_of[r.image], k)
            for k, r in enumerate(getattr(problem.job, "clock_readings", []))
            if r.image in block_of
        ]

    def groups(self, problem: Any, labelled: Labelled) -> list[GroupSpec]:
        r = problem.job.clock_readings[labelled.tag]
        label = {"image": r.image, "value_s": r.value_s}
        return [GroupSpec("clock_reading", np.arange(1), label, np.array([r.sigma_s]), "s", ["dt"], -1.0, ("clock_reading", labelled.tag))]

    def without(self, job: Any, removals: list[tuple]) -> tuple[Any, list[dict[str, Any]]]:
        gone = {r[1] for r in removals if r[0] == "clock_reading"}
        if not gone:
            return job, []
        return job.model_copy(update={"clock_readings": [r for k, r in enumerate(job.clock_readings) if k not in gone]}), []

    def flag(self, report: dict[str, Any], removed: list[dict[str, Any]]) -> None:
        for item in report.get("clocks") or []:
            item["rejected"] = [r["value_s"] for r in removed if r["kind"] == "clock_reading" and r["image"] == item["image"]]


CLOCK_KIND = _ClockKind()
CLOCK_READINGS = _ClockReadings()


@pytest.fixture
def with_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(blocks, "BLOCK_KINDS", (*blocks.BLOCK_KINDS[:-1], CLOCK_KIND, blocks.BLOCK_KINDS[-1]))  # the kind's line
    monkeypatch.setattr(families, "FAMILIES", (*families.FAMILIES, CLOCK_READINGS))  # the family's line


def _nadir() -> dict[str, Any]:
    return json.loads((EXAMPLES / "prism-nadir.json").read_text())


READING_OFFSETS = (0.3, -0.5, 0.2, BLUNDER_SIGMAS)  # in sigmas, the last a blunder
TRUE_OFFSET_S, READING_SIGMA_S = 0.004, 0.001


def _clock_job(robust_start: str) -> ClockJob:
    doc = _nadir()
    image = doc["images"][0]["id"]
    readings = [{"image": image, "value_s": TRUE_OFFSET_S + o * READING_SIGMA_S, "sigma_s": READING_SIGMA_S} for o in READING_OFFSETS]
    options = {**(doc.get("options") or {}), "blunder_detection": {"robust_start": robust_start}}
    return ClockJob.model_validate({**doc, "clock_readings": readings, "options": options})


def test_a_fake_kind_is_counted_assembled_and_laid_out(with_clock: None) -> None:
    doc = _nadir()
    job = _clock_job("none")
    before, after = validate_job(load_job(doc)), validate_job(job)
    assert after["valid"]
    assert after["n_unknowns"] == before["n_unknowns"] + 1 and after["n_observations"] == before["n_observations"] + 4
    bad = validate_job(job.model_copy(update={"clock_readings": [Reading(image="nowhere", value_s=0.0, sigma_s=1.0)]}))
    assert [p["location"] for p in bad["problems"] if p["code"] == "clock_unknown_image"] == [["clock_readings", 0, "image"]]

    problem = prepare(job)
    (block,) = problem.blocks["clock"]
    assert block.params[0] == pytest.approx(TRUE_OFFSET_S + READING_OFFSETS[0] * READING_SIGMA_S, rel=SAME_NUMBER_REL)  # initialised
    lay = layout(problem)
    plain = layout(prepare(load_job(doc)))
    # after the passes (none here), before the points: the points' columns move by one
    assert lay.column("clock", 0) == plain.n_img_params and lay.n_params == plain.n_params + 1
    names = parameter_names(problem)
    assert names[lay.column("clock", 0)] == f"{doc['images'][0]['id']}/dt" and len(names) == lay.n_img_params
    lin = linearise(problem)
    assert sum(1 for t in lin.terms if t.family is CLOCK_READINGS) == 4


@pytest.mark.parametrize("robust_start", ["none", "huber"])
def test_a_fake_kind_is_solved_reported_and_its_blunder_removed(with_clock: None, robust_start: str) -> None:
    job = _clock_job(robust_start)
    report = adjust_job(job)

    rejected = [r for r in report["quality"]["rejected"] if r["kind"] == "clock_reading"]
    assert len(rejected) == 1 and rejected[0]["removed"]
    assert math.isclose(rejected[0]["value_s"], TRUE_OFFSET_S + BLUNDER_SIGMAS * READING_SIGMA_S, rel_tol=SAME_NUMBER_REL)
    groups = [g for g in report["quality"]["reliability"]["groups"] if g["kind"] == "clock_reading"]
    assert len(groups) == 3  # the readings left are tested: each has redundancy 2/3 (three equal weights)
    assert all(g["redundancy"][0] == pytest.approx(2 / 3, rel=1e-6) for g in groups)

    (clock,) = report["clocks"]
    kept = [TRUE_OFFSET_S + o * READING_SIGMA_S for o in READING_OFFSETS[:3]]
    assert clock["value_s"] == pytest.approx(float(np.mean(kept)), rel=WEIGHTED_MEAN_REL)  # the weighted mean (equal weights)
    s0 = report["adjustment"]["sigma0_aposteriori"]
    assert clock["sigma_s"] == pytest.approx(s0 * READING_SIGMA_S / math.sqrt(3), rel=WEIGHTED_MEAN_REL)
    assert clock["rejected"] == [rejected[0]["value_s"]]  # flagged by its family in the kind's section


def test_without_the_registry_lines_the_fake_is_ignored() -> None:
    doc = _nadir()
    job = _clock_job("none")
    assert validate_job(job)["n_unknowns"] == validate_job(load_job(doc))["n_unknowns"]
    assert "clock" not in prepare(job).blocks


# ---- a family on the ground points: heights per tie point ------------------------------------


class Height(BaseModel):
    model_config = ConfigDict(extra="forbid")
    point: str
    up_m: float  # LGS up (m), as a DEM's height converted would be
    sigma_m: float = Field(gt=0)


class HeightJob(Job):
    heights: list[Height] = Field(default_factory=list)


class _HeightTerm:
    n_residuals = 1

    def __init__(self, up: float, sigma: float) -> None:
        self.up, self.sigma = up, sigma

    def evaluate(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.array([(params[2] - self.up) / self.sigma]), np.array([[0.0, 0.0, 1.0 / self.sigma]])


class _Heights(FamilyDefaults):
    name = "heights"

    def check(self, job: Any) -> tuple[list[Problem], Count]:
        return [], Count(n_observations=len(getattr(job, "heights", [])))

    def terms(self, problem: Any) -> list[Labelled]:
        index = {p.id: p.index for p in problem.points}
        return [Labelled(self, _HeightTerm(h.up_m, h.sigma_m), "point", index[h.point], k) for k, h in enumerate(getattr(problem.job, "heights", []))]

    def groups(self, problem: Any, labelled: Labelled) -> list[GroupSpec]:
        h = problem.job.heights[labelled.tag]
        return [GroupSpec("height", np.arange(1), {"point": h.point}, np.array([h.sigma_m]), "m", ["u"], -1.0, ("height", labelled.tag))]

    def without(self, job: Any, removals: list[tuple]) -> tuple[Any, list[dict[str, Any]]]:
        gone = {r[1] for r in removals if r[0] == "height"}
        return (job.model_copy(update={"heights": [h for k, h in enumerate(job.heights) if k not in gone]}) if gone else job), []


HEIGHTS = _Heights()
HEIGHT_SIGMA_M = 0.5
HEIGHT_BLUNDER_M = 60.0  # 120 sigmas of the reading


def test_a_family_on_the_points_joins_their_normal_and_reliability_blocks(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(families, "FAMILIES", (*families.FAMILIES, HEIGHTS))
    doc = json.loads((EXAMPLES / "prism-triplet.json").read_text())
    plain = adjust_job(load_job({**doc, "options": {**(doc.get("options") or {}), "blunder_detection": None}}))
    ties = [p for p in plain["tie_points"]][:6]
    # each tie's height read at its adjusted value; the last one a blunder
    heights = [{"point": t["id"], "up_m": t["lgs_m"][2] + (HEIGHT_BLUNDER_M if k == len(ties) - 1 else 0.0), "sigma_m": HEIGHT_SIGMA_M}
               for k, t in enumerate(ties)]
    job = HeightJob.model_validate({**doc, "heights": heights, "options": {**(doc.get("options") or {}), "blunder_detection": {"robust_start": "none"}}})

    problem = prepare(job)
    lin = linearise(problem)
    on_points = [c for t, c in zip(lin.terms, lin.term_col) if t.family is HEIGHTS]
    assert len(on_points) == len(ties) and all(c >= lin.layout.n_img_params for c in on_points)  # the points' columns

    report = adjust_job(job)
    rejected = [r for r in report["quality"]["rejected"] if r["kind"] == "height"]
    assert [r["point"] for r in rejected] == [ties[-1]["id"]] and rejected[0]["removed"]
    groups = [g for g in report["quality"]["reliability"]["groups"] if g["kind"] == "height"]
    assert len(groups) == len(ties) - 1
    # a 0.5 m height against a triplet's intersection (sigma_u of metres): mostly checked by nothing else
    assert all(0.0 < g["redundancy"][0] < 1.0 for g in groups)
    up = {t["id"]: t["lgs_m"][2] for t in report["tie_points"]}
    sig = {t["id"]: t["sigma_m"][2] for t in plain["tie_points"]}
    for t in ties[:-1]:  # read at the adjusted value: the point stays within its own sigma
        assert abs(up[t["id"]] - t["lgs_m"][2]) < sig[t["id"]]
