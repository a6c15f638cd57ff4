"""``pba warmup``: the warm-up jobs reach every platform-model kind and both line models, and
are sound adjustments (a warm-up that fails quietly would hide kernels it never compiled)."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from solver.api import run
from solver.cli import main
from solver.engine import native
from solver.platforms import get_model, model_names
from solver.warmup import warmup_jobs


@pytest.fixture(scope="module")
def jobs() -> list[tuple[str, dict]]:
    return list(warmup_jobs())


def test_warmup_jobs_cover_every_model_kind_and_both_line_models(jobs) -> None:
    kinds = {get_model(im["model"]["name"]).kind for _, job in jobs for im in job["images"]}
    assert kinds == {get_model(name).kind for name in model_names()}
    line_models = {job["options"]["line_model"] for _, job in jobs if job.get("lines")}
    assert line_models == {"rigorous", "equivalent_planes"}
    options = [job.get("options", {}) for _, job in jobs]
    assert any("self_calibration" in o for o in options) and any("ephemeris" in o for o in options)


def test_warmup_jobs_are_sound_adjustments(jobs) -> None:
    """Each gives a usable solution whose sigma0 is that of the simulated noise (0.5 px
    observations, 0.5 px sigmas): the 10-line scene once ended at its initial values with a
    NaN sigma0 (failed closest-point searches, tests/solver/observations/test_lines.py)."""
    for label, job in jobs:
        adj = run(job)["adjustment"]
        sigma0 = adj["sigma0_aposteriori"]
        assert math.isfinite(sigma0) and 0.5 < sigma0 < 2.0, (label, sigma0, adj["message"])
        assert adj["iterations"] > 0, label


def test_pba_warmup_reports_each_job(capsys, monkeypatch) -> None:
    from solver.kernels import callbacks

    loaded = []
    monkeypatch.setattr(callbacks, "load_all", lambda: loaded.append(True))
    assert main(["warmup"]) == 0
    # the C callbacks load on first use: the warm-up asks for all of them (no job of it has a fixed point)
    assert loaded == ([True] if native.status().path == "compiled" else [])
    out = capsys.readouterr().out.splitlines()
    labels = [label for label, _ in warmup_jobs()]
    # first which evaluation path solves take (a warning when it is not the compiled one)
    assert out[0].split(": ")[0] in ("residual evaluation", "WARNING: residual evaluation"), out[0]
    assert ("compiled" in out[0]) == (native.status().path == "compiled"), out[0]
    assert [line.split(":")[0] for line in out[1:-1]] == labels
    assert out[-1].startswith("kernels compiled or loaded from the cache in")


def test_callbacks_load_on_first_use_and_all_at_once() -> None:
    """In a new interpreter: importing the callbacks' module loads none of them (a job without
    lines would pay 10-40 ms each), asking for one loads it, ``load_all`` loads the rest."""
    code = (
        "from solver.kernels import callbacks as c\n"
        "print(sorted(n for n in c.CALLBACKS if n in vars(c)))\n"
        "c.point_block_callback.address\n"
        "print(sorted(n for n in c.CALLBACKS if n in vars(c)))\n"
        "c.load_all()\n"
        "print(sorted(n for n in c.CALLBACKS if n in vars(c)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.splitlines()
    from solver.kernels.callbacks import CALLBACKS

    assert out == ["[]", "['point_block_callback']", str(sorted(CALLBACKS))]
