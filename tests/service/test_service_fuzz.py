"""Property-based fuzzing of the job document against the real server (issue 13): mutations of
the small triplet job (strings for numbers, huge, tiny, negative and non-finite values, empty
and oversized lists, wrong nesting, missing fields) never get a 5xx, neither from the API nor
from the job the workers run, and the worker pool still solves a normal job afterwards.

Bounded and reproducible: a fixed number of examples, derandomized, no example database.
"""

from __future__ import annotations

import copy
import json
from typing import Any, Iterator

import httpx
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pba_service_harness import Server, execute_body, wait_status

pytestmark = pytest.mark.slow

EXAMPLES = 150
BAD_VALUES = [
    "481.8", "abc", "", None, True, False, 0, -1, 1, 3.5, -1e308, 1e308, 5e-324, -5e-324,
    10**400, float("nan"), float("inf"), -float("inf"), [], [0] * 300, {}, {"a": 1}, [[1, 2]],
    [1e308, 1e308, 1e308], [0, 0, 0], "EPSG:999999", -23.8, 2**63,
]


# fields the example does not have (they are created by the mutation)
ABSENT = [
    ("images", 0, "model", "options"),
    ("images", 0, "model", "options", "orders"),
    ("images", 0, "model", "options", "omega_deg"),
    ("images", 0, "initial"),
    ("cameras", 0, "iop"),
    ("cameras", 0, "iop", "df"),
    ("cameras", 0, "iop_covariance"),
    ("options", "models"),
    ("options", "self_calibration"),
    ("options", "ephemeris"),
    ("crs",),
]


def _paths(node: Any, prefix: tuple = ()) -> Iterator[tuple]:
    """Every path of the document, visiting only the first item of a list (the others have
    the same structure; fewer paths, more mutations of each)."""
    if prefix:
        yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list) and node:
        yield from _paths(node[0], (*prefix, 0))


def _mutated(doc: dict[str, Any], edits: list[tuple[tuple, Any, bool]]) -> dict[str, Any]:
    out = copy.deepcopy(doc)
    for path, value, delete in edits:
        node: Any = out
        try:
            for key in path[:-1]:
                node = node[key]
            if delete and isinstance(node, dict):
                node.pop(path[-1], None)
            else:
                node[path[-1]] = copy.deepcopy(value)
        except (KeyError, IndexError, TypeError):
            continue  # an earlier edit changed the structure under this path
    return out


def _body(job: dict[str, Any]) -> str:
    """The request text: NaN and Infinity kept (the server must answer them 400)."""
    return json.dumps(execute_body(job), allow_nan=True)


@pytest.fixture(scope="module")
def fuzz_client(server: Server) -> Iterator[httpx.Client]:
    with server.client(server.create_key("fuzzer"), timeout=120) as c:
        yield c


def test_fuzzed_jobs_get_no_server_error(
    server: Server, fuzz_client: httpx.Client, small_doc: dict[str, Any]
) -> None:
    paths = list(_paths(small_doc)) + ABSENT
    accepted: list[str] = []
    refused: list[int] = []
    edit = st.tuples(st.sampled_from(paths), st.sampled_from(BAD_VALUES), st.booleans())

    @settings(
        max_examples=EXAMPLES,
        derandomize=True,
        database=None,
        deadline=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(st.lists(edit, min_size=1, max_size=3))
    def fuzz(edits: list[tuple[tuple, Any, bool]]) -> None:
        text = _body(_mutated(small_doc, edits))
        headers = {"content-type": "application/json"}
        r = fuzz_client.post("/jobs/validate", content=text, headers=headers)
        assert r.status_code < 500, (edits, r.text[:1000])
        r = fuzz_client.post(
            "/processes/bundle-adjustment/execution",
            content=text,
            headers={**headers, "Prefer": "respond-async"},
        )
        assert r.status_code < 500, (edits, r.text[:1000])
        if r.status_code == 201:
            accepted.append(r.json()["jobID"])
        else:
            refused.append(r.status_code)

    fuzz()
    # the mutations reached both sides: refused documents and jobs the workers solved
    assert refused and accepted, (len(refused), len(accepted))
    print(f"fuzz: {len(refused)} refused ({sorted(set(refused))}), {len(accepted)} solved")
    for job_id in accepted:  # what the workers ran: finished, and never an internal error
        st_doc = wait_status(fuzz_client, job_id, timeout=300)
        if st_doc["status"] == "failed":
            r = fuzz_client.get(f"/jobs/{job_id}/results")
            assert r.status_code < 500, (job_id, r.text[:1000])
    r = fuzz_client.post("/processes/bundle-adjustment/execution", json=execute_body(small_doc))
    assert r.status_code == 200, r.text[:1000]  # the worker pool is alive and solves
    assert r.json()["adjustment"]["converged"]
