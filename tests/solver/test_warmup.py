"""``pba warmup``: the warm-up jobs reach every platform-model kind and both line models, and
are sound adjustments (a warm-up that fails quietly would hide kernels it never compiled); with
``--jobs 2`` a child process warms the Python evaluation path beside the compiled one, its
failure fails the warm-up and a failure of the parent ends it."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from solver import warmup
from solver.api import run
from solver.cli import build_parser, main
from solver.engine import native
from solver.platforms import get_model, model_names
from solver.warmup import CHILD_PREFIX, WarmupError, compile_kernels, warmup_jobs

REQUIRED = os.environ.get("PBA_REQUIRE_NATIVE") == "1"
requires_native = pytest.mark.skipif(not REQUIRED and native.status().path != "compiled", reason="compiled cost functions not built (make native)")


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
    assert main(["warmup", "--jobs", "1"]) == 0  # one process: the warm-up of before --jobs
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


def _split(lines: list[str]) -> tuple[list[str], list[str]]:
    """This process's lines and the child's (without their prefix)."""
    own = [line for line in lines if not line.startswith(CHILD_PREFIX)]
    return own, [line[len(CHILD_PREFIX) :] for line in lines if line.startswith(CHILD_PREFIX)]


def _no_child(monkeypatch, tmp_path: Path) -> Path:
    """Replace the child's command by one that leaves a mark and fails: started, it would show."""
    mark = tmp_path / "child-started"
    code = f"import pathlib, sys; pathlib.Path({str(mark)!r}).touch(); sys.exit(5)"
    monkeypatch.setattr(warmup, "python_path_command", lambda: [sys.executable, "-c", code])
    return mark


def test_warmup_jobs_option_and_its_default(monkeypatch) -> None:
    parser = build_parser()
    assert parser.parse_args(["warmup"]).jobs is None  # resolved when it runs: default_processes()
    assert parser.parse_args(["warmup", "--jobs", "3"]).jobs == 3
    with pytest.raises(SystemExit):
        parser.parse_args(["warmup", "--jobs", "0"])
    import solver.engine.native as native

    for cores, expected in ((1, 1), (2, 2), (64, 2)):
        monkeypatch.setattr(native, "available_cores", lambda cores=cores: cores)
        assert warmup.default_processes() == expected, cores


def test_one_process_or_the_python_path_starts_no_child(monkeypatch, tmp_path) -> None:
    """``processes=1``, and ``processes=2`` where solves take the Python path anyway, run the
    warm-up of before in this process alone."""
    mark = _no_child(monkeypatch, tmp_path)
    said: list[str] = []
    compile_kernels(said.append, processes=1)
    monkeypatch.setenv("PBA_EVALUATION", "python")
    compile_kernels(said.append, processes=2)
    assert not mark.exists()
    assert not [line for line in said if line.startswith(CHILD_PREFIX)]
    assert [line.split(":")[0] for line in said].count("P2") == 2


@requires_native
def test_pba_warmup_in_two_processes_warms_the_python_path_in_a_child(capsys) -> None:
    """The real child (``python -m solver.warmup``): it says that it takes the Python path and
    adjusts every warm-up job; this process's lines are those of one process."""
    assert main(["warmup", "--jobs", "2"]) == 0
    own, child = _split(capsys.readouterr().out.splitlines())
    labels = [label for label, _ in warmup_jobs()]
    assert own[0] == "residual evaluation: compiled (compiled cost functions loaded)", own[0]
    assert [line.split(":")[0] for line in own[1:-1] if not line.startswith("compil")] == labels
    assert own[-1].startswith("kernels compiled or loaded from the cache in")
    assert child[0] == "residual evaluation: python (PBA_EVALUATION=python)", child
    assert [line.split(":")[0] for line in child[1:-1] if not line.startswith("compil")] == labels
    assert child[-1].startswith("Python path warmed in"), child


@requires_native
def test_a_failing_child_fails_the_warmup_with_its_last_lines(monkeypatch, capsys) -> None:
    code = "import os, sys; print('evaluation', os.environ['PBA_EVALUATION']); print('the last words'); sys.exit(3)"
    monkeypatch.setattr(warmup, "python_path_command", lambda: [sys.executable, "-c", code])
    assert main(["warmup", "--jobs", "2"]) == 1
    captured = capsys.readouterr()
    own, child = _split(captured.out.splitlines())
    assert child == ["evaluation python", "the last words"]  # relayed as they came
    assert not any(line.startswith("kernels compiled or loaded") for line in own)  # no success line
    assert "exit status 3" in captured.err and "the last words" in captured.err, captured.err
    with pytest.raises(WarmupError, match="exit status 3"):
        compile_kernels(processes=2)  # without a say: the tail is in the error all the same


@requires_native
def test_a_failing_parent_ends_its_child(monkeypatch, tmp_path) -> None:
    """The child (here one that says its pid and sleeps) does not outlive a warm-up that fails."""
    from solver.kernels import callbacks

    pid_file = tmp_path / "child.pid"
    code = f"import os, pathlib, time; pathlib.Path({str(pid_file)!r}).write_text(str(os.getpid())); time.sleep(120)"
    monkeypatch.setattr(warmup, "python_path_command", lambda: [sys.executable, "-c", code])

    def fail_once_the_child_runs() -> None:
        deadline = time.monotonic() + 60
        while not pid_file.exists() or not pid_file.read_text():
            assert time.monotonic() < deadline, "the child never started"
            time.sleep(0.05)
        raise RuntimeError("the parent's own warm-up failed")

    monkeypatch.setattr(callbacks, "load_all", fail_once_the_child_runs)
    with pytest.raises(RuntimeError, match="parent's own warm-up failed"):
        compile_kernels(processes=2)
    with pytest.raises(ProcessLookupError):  # ended and reaped
        os.kill(int(pid_file.read_text()), 0)


@requires_native
def test_the_child_program_refuses_another_path_or_installation() -> None:
    """``python -m solver.warmup <solver dir>`` warms only the Python path of that installation."""
    env = {k: v for k, v in os.environ.items() if k != "PBA_EVALUATION"}
    here = str(warmup.SOLVER_DIR)
    for argv, evaluation, expected in (([here], "compiled", "expected the Python evaluation path"), (["/elsewhere/solver"], "python", "not of /elsewhere/solver")):
        cmd = [sys.executable, "-m", "solver.warmup", *argv]
        done = subprocess.run(cmd, cwd=warmup.SOLVER_DIR.parent, env={**env, "PBA_EVALUATION": evaluation}, capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and expected in done.stdout, (argv, done.stdout, done.stderr)


@pytest.mark.slow
@requires_native
def test_cold_two_process_warmup_leaves_a_complete_cache(tmp_path) -> None:
    """On a cold cache (a copy of solver/ without its __pycache__: the cache is keyed on the
    sources and kept in the tree) both processes compile, and a warm-up after them compiles
    nothing, on either evaluation path. The copy is imported from sys.path alone, not from the
    working directory or PYTHONPATH, so the child finds it only as the parent's own package."""
    tree = tmp_path / "tree"
    shutil.copytree(Path(warmup.__file__).resolve().parent, tree / "solver", ignore=shutil.ignore_patterns("__pycache__"))
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PBA_EVALUATION", "PYTHONPATH")}
    code = f"import sys; sys.path.insert(0, {str(tree)!r}); from solver.cli import main; sys.exit(main(['warmup', '--jobs', '2']))"

    def warm() -> tuple[list[str], list[str]]:
        done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
        return _split(done.stdout.splitlines())

    def compiled(lines: list[str]) -> list[str]:
        return [line for line in lines if line.startswith(("compiled ", "compiling "))]

    own, child = warm()
    assert compiled(own) and compiled(child), (own, child)  # cold: each process compiled kernels
    assert str(tree / "solver" / "__pycache__") in own[-1], own[-1]  # into the copy's own cache
    own, child = warm()
    assert not compiled(own) and not compiled(child), (own, child)
    assert child[0] == "residual evaluation: python (PBA_EVALUATION=python)", child
