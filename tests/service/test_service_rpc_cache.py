"""A refined RPC is fitted once per job, image and kind (service.gis_results), and an unknown
chip is refused before anything is fitted: before, ``?chip=99`` fitted every chip (24 s on a
big job) before its 404, and every download fitted again."""

from __future__ import annotations

import json
import threading
from datetime import datetime, timezone
from typing import Any

import pytest
from pba_service_harness import load_example

import solver.gis.rpc_export
from service import gis_results
from service.states import JobStatus
from service.store import JobRecord


@pytest.fixture(scope="module")
def solved() -> JobRecord:
    import solver.api

    job = load_example("prism-nadir.json")
    report = solver.api.run(job)
    now = datetime.now(timezone.utc)
    return JobRecord(
        id="rpc-cache-job", owner="u", process_id="bundle-adjustment", name="n", status=JobStatus.successful,
        progress=100, message="", created=now, updated=now,
        _load_results=lambda _: json.dumps(report), _load_document=lambda _: {"job": job},
    )


@pytest.fixture
def fits(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, bool]]:
    calls: list[tuple[str, bool]] = []
    real = solver.gis.rpc_export.image_rpcs

    def counted(model: Any, image: Any, *args: Any, **kwargs: Any) -> Any:
        calls.append((image.id, bool(kwargs.get("per_chip"))))
        return real(model, image, *args, **kwargs)

    monkeypatch.setattr(solver.gis.rpc_export, "image_rpcs", counted)
    gis_results._rpcs.clear()
    return calls


def test_an_unknown_chip_is_refused_before_any_fit(solved: JobRecord, fits: list[tuple[str, bool]]) -> None:
    with pytest.raises(gis_results.NoSuchImage, match="chips: 1, 2, 3, 4"):
        gis_results.rpc_document(solved, "prism-nadir", "txt", "99")
    assert fits == []


def test_each_rpc_is_fitted_once_even_when_asked_concurrently(solved: JobRecord, fits: list[tuple[str, bool]]) -> None:
    texts: list[str] = []
    threads = [threading.Thread(target=lambda: texts.append(gis_results.rpc_document(solved, "prism-nadir", "txt", "2")[0])) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    texts.append(gis_results.rpc_document(solved, "prism-nadir", "rpb", "3")[0])
    texts.append(gis_results.rpc_document(solved, "prism-nadir", "txt", None)[0])
    texts.append(gis_results.rpc_document(solved, "prism-nadir", "txt", None)[0])
    assert fits == [("prism-nadir", True), ("prism-nadir", False)]
    assert len(set(texts[:3])) == 1 and texts[4] == texts[5]
