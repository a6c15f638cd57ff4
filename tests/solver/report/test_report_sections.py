"""The registry of the report's sections (solver/report/sections.py): a new section is its module
and one registry line. ``_Histogram`` below is such a section, written the way a new module
would be (a histogram of the image points' standardized residuals), put in by ``monkeypatch``:
it appears in the report, after the published sections and before ``quality`` and
``warnings``, with the counts an independent count of the report's own observations gives; its
warning joins the report's; without the line it is not there.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from solver.api import run
from solver.report import sections
from solver.report.sections import ReportInputs

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
EDGES = (0.0, 1.0, 2.0, 3.0, np.inf)  # |standardized residual| bins


class _Histogram:
    """``standardized_histogram``: the image points' |standardized residuals| per bin of
    :data:`EDGES`, from the residuals and leverages of the inputs (not from other sections)."""

    def build(self, inputs: ReportInputs) -> dict[str, Any]:
        if inputs.cov is None:
            return {}
        res = inputs.lin.res_obs.ravel()  # whitened
        r = 1.0 - np.asarray(inputs.cov.leverage)
        keep = r > 1e-9
        z = np.abs(res[keep] / (inputs.stats.sigma0_apriori * np.sqrt(r[keep])))
        counts, _ = np.histogram(z, bins=np.array(EDGES))
        if counts[-1]:
            inputs.warnings.append(f"{int(counts[-1])} standardized residuals above 3")
        return {"standardized_histogram": {"edges": [e if np.isfinite(e) else None for e in EDGES], "counts": counts.tolist()}}


@pytest.fixture
def with_histogram(monkeypatch: pytest.MonkeyPatch) -> None:
    registry = list(sections.SECTIONS)
    registry.insert(len(registry) - 2, _Histogram())  # the one registry line: before quality and warnings
    monkeypatch.setattr(sections, "SECTIONS", tuple(registry))


def _triplet() -> dict[str, Any]:
    return json.loads((EXAMPLES / "prism-triplet.json").read_text())


def test_a_fake_section_is_built_placed_and_counted_independently(with_histogram: None) -> None:
    report = run(_triplet())
    keys = list(report)
    assert keys[-3:] == ["standardized_histogram", "quality", "warnings"]
    assert keys[: len(sections.SECTION_ORDER)] == [k for k in sections.SECTION_ORDER if k in report]
    # the independent count: the report's own standardized residuals of the image points
    z = [abs(v) for o in report["observations"] for v in (o["standardized_line"], o["standardized_column"]) if v is not None]
    expected = [sum(1 for v in z if lo <= v < hi) for lo, hi in zip(EDGES[:-1], EDGES[1:])]
    assert report["standardized_histogram"]["counts"] == expected and sum(expected) > 0
    above = expected[-1]
    assert (f"{above} standardized residuals above 3" in report["warnings"]) == (above > 0)


def test_without_the_registry_line_there_is_no_such_section() -> None:
    assert "standardized_histogram" not in run(_triplet())


def _documented_sections() -> list[set[str]]:
    """The sections docs/architecture.md says each registry entry builds, in the registry's order
    (the entries' names and order: tests/test_architecture.py)."""
    text = (EXAMPLES.parent / "docs" / "architecture.md").read_text()
    block = re.search(r"<!-- report sections: begin -->\n(.*?)<!-- report sections: end -->", text, re.S)
    assert block, "docs/architecture.md has lost its list of report sections"
    return [set(re.findall(r"`(\w+)`", rest)) for rest in re.findall(r"^\s*\d+\. `\w+`: (.*)$", block.group(1), re.M)]


def test_each_entry_builds_the_sections_the_architecture_page_names(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each entry of the registry builds only the sections the page names for it, and every
    section of the report comes from the entry the page says (the triplet has no pass, line or
    DEM: the kinds' and families' entries build some of theirs)."""
    built: list[set[str]] = []

    class Recording:
        def __init__(self, entry: Any) -> None:
            self.entry = entry

        def build(self, inputs: ReportInputs) -> dict[str, Any]:
            out = self.entry.build(inputs)
            built.append(set(out))
            return out

    monkeypatch.setattr(sections, "SECTIONS", tuple(Recording(e) for e in sections.SECTIONS))
    report = run(_triplet())
    documented = _documented_sections()
    assert len(built) == len(documented) == len(sections.SECTIONS)
    for keys, named in zip(built, documented):
        assert keys <= named, (keys, named)
    assert set(report) == set().union(*built) and {"cameras", "ephemeris"} <= set(report)


def test_the_observations_section_is_the_same_in_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Converted chunk by chunk (a million observations' temporary lists at once were 0.2 GB),
    the entries are those of one pass, standardized residuals included, across chunk borders
    (a slice of one column taken at the wrong offset shifts every later chunk)."""
    from utils.scenes import block_job

    from solver.report import core_sections

    job, _truth = block_job(model="P1", n_tie=30, n_gcp=8, n_check=2, seed=5)
    whole = run(json.loads(json.dumps(job)))["observations"]
    monkeypatch.setattr(core_sections, "OBSERVATION_CHUNK", 7)
    chunked = run(json.loads(json.dumps(job)))["observations"]
    assert len(whole) > 3 * 7 and len(chunked) == len(whole)
    for a, b in zip(chunked, whole):
        assert a.keys() == b.keys()
        for key, value in a.items():
            if isinstance(value, float):
                assert value == pytest.approx(b[key], rel=1e-9, abs=1e-12), key
            else:
                assert value == b[key], key
    assert any(e["standardized_line"] is not None for e in chunked)
