"""Removed observations flagged where the report describes their family (data snooping).

Image points removed by snooping stay in ``observations`` with ``rejected: true`` (done by the
snooping procedure). The observation families flag theirs in their own report sections
(``flag`` of :mod:`solver.observations.registry`'s families; docs/report-contract.md), which
describe the final adjustment without them:

* ``line_point``: ``lines.items[].rejected``;
* ``attitude_sample``: ``attitude[].rejected_samples_s``;
* ``ephemeris_sample``: ``ephemeris.images[].rejected_samples_s`` (a pass's ephemeris sample,
  on every image of the pass that carried it) and ``ephemeris.rejected_states`` (the images
  whose weighted line-0 state was removed).

No computation: the entries come from ``quality.rejected`` and the removed members of
``quality.not_identifiable`` (reinstated ones are not removed).
"""

from __future__ import annotations

from typing import Any

from solver.observations import registry


def removed_entries(quality: dict[str, Any]) -> list[dict[str, Any]]:
    """Every observation the final adjustment does not have: removed rejected entries and
    removed members of non-identifiable groups."""
    out = [r for r in quality.get("rejected") or [] if r.get("removed")]
    out += [m for g in quality.get("not_identifiable") or [] for m in g.get("members") or [] if m.get("removed")]
    return out


def flag_sections(report: dict[str, Any]) -> None:
    """Let every family flag its removed observations in its report sections (module doc), in
    the registry's order, in place."""
    removed = removed_entries(report.get("quality") or {})
    for family in registry.FAMILIES:
        family.flag(report, removed)
