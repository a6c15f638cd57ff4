"""The job's ``options`` read as the solver's four settings objects (solver/schema/settings.py):
every option lands in exactly one of them, the values pass through unchanged, and the
deprecated ``kernel`` is still accepted but marked deprecated in the published schema."""

from __future__ import annotations

import dataclasses

from solver.schema.job import SolverOptions
from solver.schema.settings import BlockConfig, JobSettings, ProcedureConfig, SolveSettings, StatisticsConfig

GROUPS = (SolveSettings, BlockConfig, StatisticsConfig, ProcedureConfig)
DERIVED = {"significance_analysis"}  # read from options.self_calibration (also in BlockConfig)


def test_every_option_lands_in_exactly_one_group() -> None:
    fields = [f.name for g in GROUPS for f in dataclasses.fields(g) if f.name not in DERIVED]
    assert len(fields) == len(set(fields))
    assert set(fields) == set(SolverOptions.model_fields) - {"kernel"}


def test_values_pass_through() -> None:
    doc = {"max_iterations": 7, "loss": "huber", "loss_scale": 2.5, "control": "fixed", "alpha": 0.01,
           "covariance": False, "models": ["P1", "P2"], "self_calibration": {"estimate": ["df"], "significance_analysis": True},
           "parsimony": {"threshold": 3}}
    s = JobSettings.from_options(SolverOptions.model_validate(doc))
    assert (s.solve.max_iterations, s.solve.loss, s.solve.loss_scale) == (7, "huber", 2.5)
    assert s.blocks.control == "fixed" and s.blocks.self_calibration.estimate == ["df"]
    assert (s.statistics.alpha, s.statistics.covariance) == (0.01, False)
    assert s.procedures.models == ("P1", "P2") and s.procedures.significance_analysis
    assert s.procedures.parsimony.threshold == 3 and s.procedures.blunder_detection is None


def test_the_kernel_option_is_deprecated_but_accepted() -> None:
    assert SolverOptions.model_validate({"kernel": "python"}).model_dump()["kernel"] == "python"
    prop = SolverOptions.model_json_schema()["properties"]["kernel"]
    assert prop["deprecated"] is True and "ignored" in prop["description"]


def test_reweighted_observation_is_a_copy_beyond_the_documents_bound() -> None:
    """Data snooping inflates a candidate's sigma a thousandfold, past the document's 1e6 px
    bound: the copy is not validated, and the original keeps its weight."""
    from solver.schema.job import ImageObservation

    o = ImageObservation(image="a", point="b", line=1.0, column=2.0, sigma_px=5e5)
    r = o.reweighted(5e8)
    assert (r.sigma_px, o.sigma_px) == (5e8, 5e5)
    assert (r.image, r.point, r.line, r.column, r.chip) == (o.image, o.point, o.line, o.column, o.chip)
