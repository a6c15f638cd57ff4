"""The Python snippets of docs/how-to/api-python.md (httpx, then OWSLib) run as printed against a
real server: only the server's address, the key and the example's path are replaced. What they
leave behind (the report, the check-point table, the job ids) is then checked, so a snippet that
stops working, or quietly does something else, fails here."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from pba_service_harness import Server

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "how-to" / "api-python.md"
FENCE = re.compile(r"^```python\n(.*?)^```\s*$", re.M | re.S)


def test_the_python_snippets_run_against_a_server(server: Server, keys: dict[str, str]) -> None:
    text = PAGE.read_text()
    assert "http://127.0.0.1:8000" in text and '"pba_..."' in text  # what the substitutions below replace
    text = text.replace("http://127.0.0.1:8000", server.url).replace('"pba_..."', repr(keys["alice"]))
    text = text.replace('open("examples/prism-triplet.json")', f'open({str(ROOT / "examples" / "prism-triplet.json")!r})')
    blocks = FENCE.findall(text)
    assert len(blocks) == 2, "the page's httpx and OWSLib snippets"
    namespace: dict[str, Any] = {}
    for code in blocks:
        exec(compile(code, str(PAGE), "exec"), namespace)  # noqa: S102 - the documentation's own code
    report = namespace["report"]
    assert report["kind"] == "adjustment" and report["adjustment"]["converged"] is True
    assert namespace["csv_text"].splitlines()[0].startswith("id,")  # the check-point table's header
    assert namespace["status"]["jobID"] != namespace["job_id"]  # OWSLib's asynchronous run is a new job
