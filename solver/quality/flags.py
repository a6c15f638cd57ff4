"""Removed observations flagged where the report describes their family (data snooping).

Image points removed by snooping stay in ``observations`` with ``rejected: true`` (done in
``solver.adjust``). The other removable kinds are flagged here, in the report sections that
describe the final adjustment without them (docs/report-contract.md):

* ``line_point``: ``lines.items[].rejected``: ``[{"image", "line", "column"}]`` for a measured
  line image point (image coordinates in pixels, as measured), ``{"image", "line": null,
  "column": null}`` for a line image removed whole (a fitted image line, or the last point of
  a line image, ``collateral``);
* ``attitude_sample``: ``attitude[].rejected_samples_s``: the epochs (s, the job's time scale)
  of the samples removed from that attitude block;
* ``ephemeris_sample``: ``ephemeris.images[].rejected_samples_s`` (a pass's ephemeris sample,
  on every image of the pass that carried it) and ``ephemeris.rejected_states`` (the images
  whose weighted line-0 state was removed: the state stays as the image's unweighted
  approximate state and its ephemeris goes, so the image has no entry in
  ``ephemeris.images`` any more).

No computation: the entries come from ``quality.rejected`` and the removed members of
``quality.not_identifiable`` (reinstated ones are not removed).
"""

from __future__ import annotations

from typing import Any

from solver.schema.job import Job


def line_point_coordinates(job: Job, line: str, image: str, k: int | None) -> dict[str, float | None]:
    """The measured image coordinates (px) of point ``k`` of ``line`` in ``image`` in ``job``
    (the job at the time of the removal, whose indices the removal used); ``None`` for a line
    image removed whole."""
    if k is not None:
        for gl in job.lines:
            if gl.id != line:
                continue
            for lo in gl.observations:
                if lo.image == image and 0 <= k < len(lo.points):
                    q = lo.points[k]
                    return {"line": float(q.line), "column": float(q.column)}
    return {"line": None, "column": None}


def removed_entries(quality: dict[str, Any]) -> list[dict[str, Any]]:
    """Every observation the final adjustment does not have: removed rejected entries and
    removed members of non-identifiable groups."""
    out = [r for r in quality.get("rejected") or [] if r.get("removed")]
    out += [m for g in quality.get("not_identifiable") or [] for m in g.get("members") or [] if m.get("removed")]
    return out


def flag_sections(report: dict[str, Any]) -> None:
    """Add the ``rejected`` / ``rejected_samples_s`` / ``rejected_states`` flags (module doc)
    to the ``lines``, ``attitude`` and ``ephemeris`` sections of ``report`` in place."""
    removed = removed_entries(report.get("quality") or {})
    lines = report.get("lines") or {}
    items = {it["id"]: it for it in lines.get("items") or []}
    for it in items.values():
        it["rejected"] = []
    block_of = {}
    for block in report.get("attitude") or []:
        block["rejected_samples_s"] = []
        block_of.update({image: block for image in block.get("images") or []})
    ephemeris = report.get("ephemeris")
    eph_images = {e["image"]: e for e in (ephemeris or {}).get("images") or []}
    for e in eph_images.values():
        e["rejected_samples_s"] = []
    rejected_states: list[str] = []
    pass_images = {p.get("id"): p.get("images") or [] for p in report.get("passes") or []}
    for r in removed:
        kind = r["kind"]
        if kind == "line_point" and r.get("line") in items:
            where = r.get("measured") or {"line": None, "column": None}
            items[r["line"]]["rejected"].append({"image": r.get("image"), **where})
        elif kind == "attitude_sample" and r.get("image") in block_of:
            block_of[r["image"]]["rejected_samples_s"].append(r.get("time_s"))
        elif kind == "ephemeris_sample":
            if r.get("time_s") is None:  # an image's weighted line-0 state
                rejected_states.append(r.get("image"))
                continue
            for image in pass_images.get(r.get("pass"), [r.get("image")]):
                if image in eph_images:
                    eph_images[image]["rejected_samples_s"].append(r["time_s"])
    if isinstance(ephemeris, dict):
        ephemeris["rejected_states"] = rejected_states
