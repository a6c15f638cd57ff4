"""The API process stays small: whatever a client asks (validation, submission, composition of
uploaded files, cameras, RPC downloads, transforms, GeoJSON), it never loads numba or scipy
(about 190 MB together); the numerical work runs in the workers and in the GIS process
(service/gis_process.py). A crash of the GIS process is a 503 problem, and the next request is
answered by a new one."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterator

import pytest
from pba_service_harness import Server, execute_body, gis_processes, load_example
from test_service_compose import example_files, example_spec

HEAVY = ("llvmlite", "numba", "scipy")  # shared libraries the API process must never map


def _mapped_packages(pid: int) -> set[str]:
    """The site-packages of every shared library mapped by ``pid`` (Linux /proc)."""
    out = set()
    for row in Path(f"/proc/{pid}/maps").read_text().splitlines():
        path = row.split()[-1]
        if ".so" in path and "site-packages/" in path:
            out.add(path.split("site-packages/", 1)[1].split("/", 1)[0])
    return out


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A server of its own (local mode, one worker): what its API process maps comes from this
    module's requests alone, whatever other modules asked of the shared one."""
    with Server(tmp_path_factory.mktemp("api-process"), workers=1) as srv:
        yield srv


@pytest.fixture(scope="module")
def keys() -> dict[str, str | None]:
    return {"alice": None}  # local mode: no key


@pytest.fixture(scope="module")
def solved(server: Server, keys: dict[str, str]) -> str:
    with server.client(keys["alice"]) as c:
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(load_example("prism-nadir.json")))
        assert r.status_code == 200, r.text[:500]
        return r.headers["location"].rsplit("/", 1)[1]


def test_the_api_process_never_loads_the_numerical_libraries(server: Server, keys: dict[str, str], solved: str) -> None:
    assert server.proc is not None
    files = example_files()
    with server.client(keys["alice"]) as c:
        assert c.post("/jobs/validate", json=execute_body(load_example("prism-triplet.json"))).status_code == 200
        r = c.post(
            "/jobs/compose",
            data={"spec": json.dumps(example_spec())},
            files=[("files", (name, data, "application/octet-stream")) for name, data in files.items()],
        )
        assert r.status_code == 200, r.text[:500]
        assert c.get("/cameras").status_code == 200
        # the checks of a pre-analysis and of a model comparison run in the API process too
        job = load_example("prism-nadir.json")
        r = c.post("/processes/model-comparison/execution", json=execute_body(job, models=["P2", "NO-SUCH-MODEL"]))
        assert r.status_code == 422 and "/inputs/models" in r.text, r.text[:500]
        r = c.post("/processes/preanalysis/execution", json=execute_body(job))  # checked here, run by the worker
        assert r.status_code == 200 and r.json()["kind"] == "preanalysis", r.text[:500]
        assert c.get("/cameras/shared/prism-nadir/versions").status_code == 200
        rpc = c.get(f"/jobs/{solved}/results/rpc/prism-nadir", params={"chip": "2"})
        assert rpc.status_code == 200 and "LINE_OFF" in rpc.text
        g2i = c.post(f"/jobs/{solved}/results/ground-to-image", json={"image": "prism-nadir", "points": [{"lon": 138.7, "lat": 35.3, "height": 500.0}]})
        assert g2i.status_code == 200, g2i.text[:500]
        assert c.get(f"/jobs/{solved}/results/geojson").status_code == 200
        # a problem raised in the GIS process comes back as the same problem document
        bad = c.get(f"/jobs/{solved}/results/rpc/prism-nadir", params={"chip": "99"})
        assert bad.status_code == 404 and bad.json()["type"].endswith("no-such-image"), bad.text[:500]
        assert "chips: 1, 2, 3, 4" in bad.json()["detail"]
    loaded = _mapped_packages(server.proc.pid)
    assert loaded & {"numpy", "pyproj", "pydantic_core"} == {"numpy", "pyproj", "pydantic_core"}, loaded  # the check sees libraries
    assert not loaded & set(HEAVY), f"the API process mapped {sorted(loaded & set(HEAVY))}"


def test_a_crashed_gis_process_is_a_503_and_the_next_request_starts_another(server: Server, keys: dict[str, str], solved: str) -> None:
    assert server.proc is not None
    url = f"/jobs/{solved}/results/ground-to-image"
    body: dict[str, Any] = {"image": "prism-nadir", "points": [{"lon": 138.7, "lat": 35.3, "height": 500.0}]}
    with server.client(keys["alice"]) as c:
        assert c.post(url, json=body).status_code == 200
        named = gis_processes(server.proc.pid)
        assert len(named) == 2, named  # the small-transform lane's process and a general one
        for target in named:
            os.kill(target, signal.SIGKILL)
        deadline = time.monotonic() + 10
        while any(Path(f"/proc/{t}").exists() for t in named) and time.monotonic() < deadline:
            time.sleep(0.05)
        r = c.post(url, json=body)
        assert r.status_code == 503 and r.json()["type"].endswith("gis-unavailable"), r.text[:500]
        again = c.post(url, json=body)
        assert again.status_code == 200, again.text[:500]
        assert again.json()["rows"] == c.post(url, json=body).json()["rows"]
    assert server.proc.poll() is None, "the server survived"


def test_validation_and_the_job_schema_load_no_kernel() -> None:
    """In a fresh interpreter: the job schema, validation of a job with lines and passes' models,
    and the app's construction import neither numba nor scipy."""
    code = (
        "import json, sys\n"
        "from solver.api import validate\n"
        "from solver.schema.job import load_job\n"
        "from service.app import create_app\n"
        "create_app()\n"
        "doc = json.load(open('examples/prism-triplet.json'))\n"
        "assert validate(load_job(doc))['valid']\n"
        "print(json.dumps(sorted(m for m in ('numba', 'llvmlite', 'scipy') if m in sys.modules)))\n"
    )
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
