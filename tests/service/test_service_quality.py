"""Data snooping through the HTTP API (docs/quality.md): a job with blunders and
``options.blunder_detection`` run by a real server; the report's ``quality`` section equals the
solver's own, the removed image points are flagged in ``observations.csv``, ``rejected.csv``
lists the rejected tests and groups, and the residual plot draws with them."""

from __future__ import annotations

import copy
import csv
import io
from typing import Any

from pba_service_harness import Server, solved_report
from utils.scenes import block_job


def _job_with_blunders() -> dict[str, Any]:
    job, _truth = block_job(model="P1", n_tie=30, n_gcp=14, n_check=6, seed=3, gcp_sigma_m=0.5)
    ties = [i for i, o in enumerate(job["observations"]) if "-T" in o["point"]]
    job["observations"][ties[0]]["line"] += 20.0  # along track on a 3-ray tie: not identifiable
    job["observations"][ties[5]]["column"] += 12.0
    job["options"] = {"blunder_detection": {}}
    return job


def test_quality_fields_through_the_http_api(server: Server, keys: dict[str, str]) -> None:
    import solver.api

    job = _job_with_blunders()
    direct = solver.api.run(copy.deepcopy(job))
    with server.client(keys["alice"]) as c:
        job_id, report = solved_report(c, job)
        q = report["quality"]
        assert q["blunder_detection"]["n_removed"] == direct["quality"]["blunder_detection"]["n_removed"] == 4
        assert [(r["image"], r["point"]) for r in q["rejected"]] == [(r["image"], r["point"]) for r in direct["quality"]["rejected"]]
        assert len(q["not_identifiable"]) == 1 and len(q["not_identifiable"][0]["members"]) == 3
        assert q["reliability"]["groups"]
        obs = list(csv.DictReader(io.StringIO(c.get(f"/jobs/{job_id}/results/observations.csv").text)))
        flagged = [o for o in obs if o["rejected"] == "True"]
        assert len(flagged) == 4 and len(obs) == len(direct["observations"])
        r = c.get(f"/jobs/{job_id}/results/rejected.csv")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
        rows = list(csv.DictReader(io.StringIO(r.text)))
        assert len(rows) == len(q["rejected"]) + 3
        assert {row["kind"] for row in rows} == {"image_point"}
        assert all(float(row["w"]) > float(row["critical"]) for row in rows)
        png = c.get(f"/jobs/{job_id}/plots/image-residuals.png")
        assert png.status_code == 200 and png.content[:4] == b"\x89PNG"
