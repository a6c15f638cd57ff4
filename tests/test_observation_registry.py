"""The observation-family registry (issue 14): the engine's stages loop over
solver.observations.registry.FAMILIES instead of naming families, so a family added there is
validated, counted and solved without touching the stages."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

import solver.engine.terms as terms
import solver.engine.validate as validate
from solver.errors import Problem as JobProblem
from solver.observations import attitude
from solver.observations.family import ObservationFamily
from solver.observations.registry import FAMILIES
from solver.schema.job import load_job

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_registry_lists_measured_attitude_with_the_whole_interface() -> None:
    assert attitude.FAMILY in FAMILIES
    names = [f.name for f in FAMILIES]
    assert len(names) == len(set(names))  # one report section per family
    for family in FAMILIES:
        for hook in ("problems", "n_observations", "terms", "refresh", "report"):
            assert callable(getattr(family, hook)), (family.name, hook)
        assert isinstance(family.direct_datum, bool)


class _Probe:
    """A family that asks for nothing but is seen by every stage."""

    name = "probe"
    direct_datum = False

    def __init__(self, problems: list[JobProblem], n: int) -> None:
        self._problems, self._n = problems, n
        self.seen_terms = 0

    def problems(self, job: Any) -> list[JobProblem]:
        return list(self._problems)

    def n_observations(self, job: Any) -> int:
        return self._n

    def terms(self, problem: Any) -> list:
        self.seen_terms += 1
        return []

    def refresh(self, problem: Any) -> float:
        return 0.0

    def report(self, problem: Any) -> dict:
        return {}


def _job() -> Any:
    return load_job(json.loads((EXAMPLES / "prism-nadir.json").read_text()))


def test_validation_loops_over_the_registry(monkeypatch: pytest.MonkeyPatch) -> None:
    before = validate.validate_job(_job())
    probe: ObservationFamily = _Probe([], 5)
    monkeypatch.setattr(validate, "FAMILIES", (*FAMILIES, probe))
    counted = validate.validate_job(_job())
    assert counted["n_observations"] == before["n_observations"] + 5
    assert counted["dof"] == before["dof"] + 5
    bad = _Probe([JobProblem("probe_problem", "refused", ("options",))], 5)
    monkeypatch.setattr(validate, "FAMILIES", (*FAMILIES, bad))
    refused = validate.validate_job(_job())
    assert not refused["valid"]
    assert [p for p in refused["problems"] if p["code"] == "probe_problem"][0]["location"] == ["options"]
    assert refused["n_observations"] == before["n_observations"]  # a refused family adds nothing


def test_terms_loop_over_the_registry(monkeypatch: pytest.MonkeyPatch) -> None:
    from solver.engine.assemble import build_problem

    probe = _Probe([], 0)
    monkeypatch.setattr(terms, "FAMILIES", (*FAMILIES, probe))
    problem = build_problem(_job())
    terms.image_terms(problem)
    assert probe.seen_terms == 1
    assert terms.refresh_image_terms(problem) == 0.0
