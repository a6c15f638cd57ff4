"""The plug points later parts rely on (web page, plots, other queue backends): router list,
``get_job_for_user`` and its record, the landing page's link to /ui."""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

import pytest
from fastapi import APIRouter
from fastapi.testclient import TestClient

import service.app
from service.app import ROUTER_MODULES, create_app
from service.deps import CurrentUser, get_job_for_user, get_settings
from service.settings import Settings


def test_router_list_includes_the_web_page_modules() -> None:
    names = [module.__name__.removeprefix("service.routes.") for module in ROUTER_MODULES]
    assert {"ui", "plots"} <= set(names)
    assert names[:6] == ["landing", "processes", "compose", "jobs", "cameras", "ops"]
    assert all(isinstance(module.router, APIRouter) for module in ROUTER_MODULES)


def test_get_job_for_user_from_a_plot_like_route(
    tmp_path: Path, triplet_doc: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    plots = APIRouter(prefix="/jobs", tags=["plots"])

    @plots.get("/{jobId}/plots/probe")
    def probe(jobId: str, user: CurrentUser) -> dict[str, Any]:
        job = get_job_for_user(jobId, user)
        report = job.results
        return {"id": job.id, "status": job.status.value, "sigma0": report and report["sigma0"]}

    ui = APIRouter(tags=["ui"])

    @ui.get("/ui")
    def page() -> dict[str, str]:
        return {"page": "here"}

    # stand-ins for service/routes/{ui,plots}.py, each one entry of the router list like the real ones
    stand_ins = {}
    for name, router in (("ui", ui), ("plots", plots)):
        module = types.ModuleType(f"service.routes.{name}")
        module.router = router  # type: ignore[attr-defined]
        stand_ins[module.__name__] = module
    routers = tuple(stand_ins.get(m.__name__, m) for m in ROUTER_MODULES)
    monkeypatch.setattr(service.app, "ROUTER_MODULES", routers)
    app = create_app(Settings(data_dir=tmp_path, workers=0, require_api_keys=True))
    assert {"ui", "plots"} <= set(app.state.router_modules)
    assert get_settings  # exported for routers that need the settings
    with TestClient(app) as c:
        store = app.state.services.store
        from service.auth import create_key

        alice = {"X-API-Key": create_key(store, "alice")[0]}
        bob = {"X-API-Key": create_key(store, "bob")[0]}
        r = c.post(
            "/processes/bundle-adjustment/execution",
            json={"inputs": {"job": triplet_doc}},
            headers=alice,
        )
        job_id = r.json()["jobID"]
        body = c.get(f"/jobs/{job_id}/plots/probe", headers=alice).json()
        assert body == {"id": job_id, "status": "accepted", "sigma0": None}
        assert c.get(f"/jobs/{job_id}/plots/probe", headers=bob).status_code == 404
        # a worker's result, as the queue writes it, becomes visible as .results
        assert store.claim_next("probe-worker").id == job_id
        assert store.complete(job_id, "probe-worker", '{"sigma0": 1.5}', "done")
        body = c.get(f"/jobs/{job_id}/plots/probe", headers=alice).json()
        assert body == {"id": job_id, "status": "successful", "sigma0": 1.5}
        links = {link["rel"]: link["href"] for link in c.get("/").json()["links"]}
        assert links["alternate"].endswith("/ui")
