"""The compiled-kernel disk cache is keyed on every kernel source (solver/kernels/cache.py).

numba alone invalidates a cached function only when its own file changes: after an edit of
solver/kernels/propagation.py the J2 term reached through solver/kernels/platform.py came from the cache
unchanged (0.0079 m/s^2 off). These tests edit a dependency in a scratch copy of the package
and require the new value.
"""

from __future__ import annotations

import ast
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from solver.kernels import cache as kernel_cache

SOLVER = Path(kernel_cache.__file__).resolve().parents[1]

SAME_CODE_ABS = 1e-12  # m/s^2: a kernel loaded from the cache computes what it computed when compiled
J2_TERM_ABS = 1e-9  # m/s^2: doubling J2 adds one more J2 term; rounding on ~10 m/s^2

# _kepler_terms (solver/kernels/platform.py) inlines gravity_and_gradient (solver/kernels/propagation.py)
_PROBE = """
import json, numpy as np
from solver.kernels import _kepler_terms
coef = np.zeros(24); coef[0], coef[4], coef[8] = 4.0e6, 3.0e6, 4.5e6
coef[1], coef[5], coef[9] = 1000.0, -2000.0, 6000.0
kc = np.zeros(17); kc[12], kc[13], kc[14], kc[15] = 3.986004418e14, 7.292115e-5, 1.08263e-3, 6378137.0
a, _ = _kepler_terms(coef, kc)
print(json.dumps([float(x) for x in a]))
"""


def _j2_acceleration(r: np.ndarray, gm: float, j2: float, ae: float) -> np.ndarray:
    """J2 part of the gravity acceleration (m/s^2), written out independently of the solver."""
    x, y, z = r
    rn = np.linalg.norm(r)
    k = 1.5 * j2 * gm * ae**2 / rn**5
    f = 5.0 * z**2 / rn**2
    return np.array([-k * x * (1.0 - f), -k * y * (1.0 - f), -k * z * (3.0 - f)])


def _probe(root: Path, cache: Path) -> np.ndarray:
    env = dict(os.environ, PYTHONPATH=str(root), NUMBA_CACHE_DIR=str(cache))
    env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, cwd=root, capture_output=True, text=True, check=True)
    return np.array(json.loads(out.stdout.strip().splitlines()[-1]))


def test_edit_of_a_dependency_module_is_not_served_from_the_cache(tmp_path: Path) -> None:
    root = tmp_path / "pkg"
    shutil.copytree(SOLVER, root / "solver", ignore=shutil.ignore_patterns("__pycache__"))
    cache = tmp_path / "cache"
    r = np.array([4.0e6, 3.0e6, 4.5e6])
    gm, j2, ae = 3.986004418e14, 1.08263e-3, 6378137.0
    j2_part = _j2_acceleration(r, gm, j2, ae)
    assert np.linalg.norm(j2_part) > 1e-3  # the edit below changes the answer by this much

    first = _probe(root, cache)
    assert list(cache.rglob("platform._kepler_terms*.nbi")), "the probe must have written the cache"
    again = _probe(root, cache)  # loaded from the cache: same value
    np.testing.assert_allclose(again, first, rtol=0, atol=SAME_CODE_ABS)

    prop = root / "solver" / "kernels" / "propagation.py"
    text = prop.read_text()
    assert text.count("k = 1.5 * j2 * gm * ae * ae") == 1
    prop.write_text(text.replace("k = 1.5 * j2 * gm * ae * ae", "k = 3.0 * j2 * gm * ae * ae"))
    edited = _probe(root, cache)
    np.testing.assert_allclose(edited - first, j2_part, rtol=0, atol=J2_TERM_ABS)
    assert len(list(cache.glob("pba-kernels-*"))) == 2  # one directory per version of the sources


def test_processes_compiling_into_one_empty_cache_at_once_agree(tmp_path: Path) -> None:
    """Server workers starting together share one cache directory: numba writes each file
    under a temporary name and renames it, so concurrent writers neither fail nor corrupt it."""
    root = tmp_path / "pkg"
    shutil.copytree(SOLVER, root / "solver", ignore=shutil.ignore_patterns("__pycache__"))
    cache = tmp_path / "cache"
    env = dict(os.environ, PYTHONPATH=str(root), NUMBA_CACHE_DIR=str(cache))
    env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
    procs = [
        subprocess.Popen([sys.executable, "-c", _PROBE], env=env, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(3)
    ]
    outs = [p.communicate(timeout=600) for p in procs]
    assert all(p.returncode == 0 for p in procs), [err[-500:] for _out, err in outs]
    values = [np.array(json.loads(out.strip().splitlines()[-1])) for out, _err in outs]
    for v in values[1:]:  # the same machine code
        np.testing.assert_allclose(v, values[0], rtol=0, atol=SAME_CODE_ABS)
    np.testing.assert_allclose(_probe(root, cache), values[0], rtol=0, atol=SAME_CODE_ABS)  # and it loads


def test_every_kernel_module_registers_the_locator_before_its_first_kernel() -> None:
    modules = [p for p in SOLVER.rglob("*.py") if kernel_cache.defines_kernels(ast.parse(p.read_text()))]
    assert {p.relative_to(SOLVER).as_posix() for p in modules} >= {
        "kernels/rotation.py", "kernels/platform.py", "kernels/projection.py", "kernels/blocks.py",
        "kernels/propagation.py", "kernels/lines.py", "engine/linalg.py",
    }
    for path in modules:
        lines = path.read_text().splitlines()
        hook = [i for i, s in enumerate(lines) if s.startswith("import solver.kernels.cache")]
        first_kernel = min(i for i, s in enumerate(lines) if s.startswith("@njit") or s.startswith("@jit"))
        assert hook and hook[0] < first_kernel, path.name


def test_digest_covers_the_kernel_modules_and_the_constants_they_read() -> None:
    names = {p.relative_to(SOLVER).as_posix() for p in kernel_cache.kernel_sources()}
    # kernels/propagation.py holds kernels that kernels/platform.py inlines, and the PASS_* layout
    # constants; kernels/layout.py the KIND_* codes and table offsets frozen into the compiled code
    assert {"kernels/platform.py", "kernels/propagation.py", "kernels/layout.py", "engine/linalg.py", "kernels/lines.py"} <= names
    # modules that cannot reach compiled code keep the cache when edited
    assert not names & {"engine/assemble.py", "adjust.py", "report/statistics.py", "report/checkpoints.py", "kernels/cache.py"}
    assert not any(n.startswith("simulate/") for n in names)


def test_kernels_are_cached_under_the_digest_directory() -> None:
    from solver import kernels

    path = kernel_cache.cache_dir()
    assert f"pba-kernels-{kernel_cache.sources_digest()}" in path.parts
    locator = kernels.platform_state._cache._impl.locator
    assert isinstance(locator, kernel_cache.KernelSourceLocator)
    assert Path(locator.get_cache_path()) == path


# a probe that says whether any solver kernel had to be compiled (solver/kernels/cache.py's notices)
_NOTICE_PROBE = """
import json, numpy as np
from solver.kernels.cache import compile_notices, process_base
said = []
with compile_notices(said.append):
    from solver.kernels import _kepler_terms
    coef = np.zeros(24); coef[0], coef[4], coef[8] = 4.0e6, 3.0e6, 4.5e6
    coef[1], coef[5], coef[9] = 1000.0, -2000.0, 6000.0
    kc = np.zeros(17); kc[12], kc[13], kc[14], kc[15] = 3.986004418e14, 7.292115e-5, 1.08263e-3, 6378137.0
    a, _ = _kepler_terms(coef, kc)
print(json.dumps({"a": [float(x) for x in a], "said": said, "base": str(process_base())}))
"""


def _notice_probe(root: Path, cache: Path | None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(root))
    env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
    env.pop("NUMBA_CACHE_DIR", None)
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    out = subprocess.run([sys.executable, "-c", _NOTICE_PROBE], env=env, cwd=root, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_an_installation_compiles_once_and_every_process_finds_it_even_moved(tmp_path: Path) -> None:
    """The kernels compile into the installation's own cache (solver/__pycache__), with a notice;
    a later process loads them silently; a copy of the installation elsewhere (an image, another
    prefix) run with a cache directory of its own loads them too (copied in), without compiling."""
    first = tmp_path / "a"
    shutil.copytree(SOLVER, first / "solver", ignore=shutil.ignore_patterns("__pycache__"))
    compiled = _notice_probe(first, None)
    assert Path(compiled["base"]) == first / "solver" / "__pycache__"
    assert compiled["said"] and compiled["said"][0].startswith("compiling the solver's kernels"), compiled["said"]
    assert any(m.startswith("compiled platform._kepler_terms") for m in compiled["said"]), compiled["said"]
    again = _notice_probe(first, None)
    assert again["said"] == []  # from the installation's cache: nothing to say
    np.testing.assert_allclose(again["a"], compiled["a"], rtol=0, atol=SAME_CODE_ABS)

    moved = tmp_path / "b"
    shutil.copytree(first / "solver", moved / "solver")  # with its __pycache__
    own = tmp_path / "own-cache"
    elsewhere = _notice_probe(moved, own)
    assert Path(elsewhere["base"]) == own
    assert elsewhere["said"] == [], elsewhere["said"]  # the moved installation's kernels, not compiled again
    assert list(own.rglob("platform._kepler_terms*.nbi")), "copied into the process's own cache"
    np.testing.assert_allclose(elsewhere["a"], compiled["a"], rtol=0, atol=SAME_CODE_ABS)


def test_kernels_are_compiled_for_a_portable_cpu_unless_told_otherwise() -> None:
    import llvmlite.binding as ll

    code = "import os, solver.kernels.cache as c; from numba.core import config; print(c.select_cpu(), config.CPU_NAME, repr(config.CPU_FEATURES))"

    def chosen(**extra: str) -> list[str]:
        env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES", "PBA_KERNEL_CPU")}
        env.update(extra)
        return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout.split()

    features = ll.get_host_cpu_features()
    portable = all(features.get(f, False) for f in kernel_cache.X86_64_V3)
    name, config_name, config_features = chosen()
    if portable:  # the same name on every such machine: a cache compiled on one serves the others
        assert (name, config_name, config_features) == ("x86-64-v3", "x86-64-v3", "''")
    else:
        assert name == ll.get_host_cpu_name() and config_name == "None"
    name, config_name, _ = chosen(PBA_KERNEL_CPU="host")
    assert name == ll.get_host_cpu_name() and config_name == "None"  # numba's default
    name, config_name, _ = chosen(NUMBA_CPU_NAME="x86-64")
    assert name == config_name == "x86-64"  # numba's own setting is left alone


def test_a_run_and_the_command_line_say_when_kernels_compile() -> None:
    """numba's compile events of a solver kernel (simulated here: a real cold compile is the test
    above) reach a run's progress at the fraction reached, marked, and the command line's
    progress bar prints them on a line of their own even without a terminal."""
    import io
    import types as pytypes

    from numba.core import event as numba_event

    from solver.api import KERNELS_COMPILING, _kernel_notices
    from solver.commands import ProgressBar

    def kernel():  # stands for a kernel of the solver
        return None

    kernel.__module__ = "solver.kernels.example"
    kernel.__qualname__ = "kernel"
    data = {"dispatcher": pytypes.SimpleNamespace(py_func=kernel)}
    heard = []
    with _kernel_notices(lambda fraction, message, info=None: heard.append((fraction, message, info))) as progress:
        progress(0.3, "computing initial values", {})
        numba_event.start_event("numba:compile", data=data)
        numba_event.end_event("numba:compile", data=data)
    numba_event.start_event("numba:compile", data=data)  # outside the block: nobody listens
    numba_event.end_event("numba:compile", data=data)
    assert [h[0] for h in heard] == [0.3, 0.3, 0.3]
    assert heard[1][1].startswith("compiling the solver's kernels") and heard[1][2] == {KERNELS_COMPILING: True}
    assert heard[2][1].startswith("compiled example.kernel in") and heard[2][2] == {KERNELS_COMPILING: True}

    stream = io.StringIO()
    ProgressBar(stream=stream, enabled=False)(0.3, heard[1][1], heard[1][2])
    ProgressBar(stream=stream, enabled=False)(0.4, "solving", {})
    assert stream.getvalue() == heard[1][1] + "\n"
