"""A job document handed over (:class:`solver.api.Handover`) is freed once the job is parsed,
before the problem is built: at a million image observations the parsed JSON is about 550 MB,
which a caller that keeps it (a server's worker, bench/bench_scale.py) would otherwise hold for
the whole solve and report."""

from __future__ import annotations

import weakref
from typing import Any

import pytest
from utils.scenes import single_image_job

import solver.api
import solver.procedures.single as single


class _Document(dict):
    """A job document a test can watch (a plain dict cannot be weakly referenced)."""


@pytest.fixture
def alive_when_built(monkeypatch: pytest.MonkeyPatch) -> tuple[list[bool], list[Any]]:
    """Whether the watched document (set in the second list) was still alive each time a
    problem was built."""
    alive: list[bool] = []
    watched: list[Any] = []
    real = single.prepare

    def watching(*args: Any, **kwargs: Any) -> Any:
        alive.append(watched[0]() is not None)
        return real(*args, **kwargs)

    monkeypatch.setattr(single, "prepare", watching)
    return alive, watched


def _handed(watched: list[Any]) -> solver.api.Handover:
    """A job document handed over, watched (the caller's own reference dropped)."""
    doc = _Document(single_image_job("K2", seed=3)[0])
    watched.append(weakref.ref(doc))
    return solver.api.Handover(doc)


def test_a_handed_document_is_freed_before_the_problem_is_built(alive_when_built: tuple[list[bool], list[Any]]) -> None:
    alive, watched = alive_when_built
    handed = _handed(watched)
    report = solver.api.run(handed)
    assert alive and not any(alive)
    assert report["adjustment"]["n_observations"] > 0
    with pytest.raises(RuntimeError):  # handed once: the holder is empty
        handed.take()


def test_a_document_the_caller_keeps_stays_alive(alive_when_built: tuple[list[bool], list[Any]]) -> None:
    """The control: the same run with the caller's own reference sees the document alive (so
    the test above would see a Handover that kept it)."""
    alive, watched = alive_when_built
    doc = _Document(single_image_job("K2", seed=3)[0])
    watched.append(weakref.ref(doc))
    solver.api.run(doc)
    assert alive and all(alive)


def test_a_comparison_takes_a_handed_document(alive_when_built: tuple[list[bool], list[Any]]) -> None:
    alive, watched = alive_when_built
    report = solver.api.compare(_handed(watched), ["K1", "K2"])
    assert set(report["reports"]) == {"K1", "K2"} and len(alive) >= 2 and not any(alive)
