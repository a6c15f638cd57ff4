"""Build the compiled Ceres cost functions (solver/engine/native/callback_cost.cpp) in place.

    python scripts/build_native.py [--require] [--force]

Needs g++ (``CXX``), the Python headers, ``ceres/cost_function.h`` (Debian's libceres-dev;
``CERES_INCLUDE_DIR`` to point elsewhere) and the pybind11 release the pyceres wheel was built
with (pinned in pyproject.toml: the two must share pybind11's internals). Nothing is linked
against libceres (the wheel carries Ceres; the module defines the two out-of-line members of
``ceres::CostFunction`` it needs).

The module is rebuilt only when the source, the compiler flags, pyceres or pybind11 changed (a
stamp beside it). When the build is impossible the solver falls back to its Python cost
functions: this script then says why and exits 0, or 1 with ``--require``.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shlex
import shutil
import subprocess
import sys
import sysconfig
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NATIVE = ROOT / "solver" / "engine" / "native"
SOURCE = NATIVE / "callback_cost.cpp"
TARGET = NATIVE / ("callback_cost" + sysconfig.get_config_var("EXT_SUFFIX"))
STAMP = TARGET.with_suffix(TARGET.suffix + ".stamp")
FLAGS = ["-O3", "-shared", "-fPIC", "-std=c++17", "-fvisibility=hidden", "-DNDEBUG"]
HEADER = "ceres/cost_function.h"


def _ceres_include() -> Path | None:
    candidates = [os.environ.get("CERES_INCLUDE_DIR", ""), "/usr/include", "/usr/local/include"]
    for c in candidates:
        if c and (Path(c) / HEADER).is_file():
            return Path(c)
    return None


def _fingerprint(cmd: list[str]) -> str:
    parts = [SOURCE.read_bytes(), " ".join(cmd).encode()]
    for dist in ("pyceres", "pybind11"):
        parts.append(f"{dist}={metadata.version(dist)}".encode())
    return hashlib.sha256(b"\0".join(parts)).hexdigest()


def build(force: bool = False) -> tuple[bool, str]:
    """(built or up to date, message)."""
    cxx = os.environ.get("CXX", "g++")
    if shutil.which(cxx) is None:
        return False, f"no C++ compiler ({cxx!r} not found)"
    try:
        import pybind11
    except ImportError:
        return False, "pybind11 is not installed (pip install -e .)"
    include = _ceres_include()
    if include is None:
        return False, f"{HEADER} not found (Debian: apt-get install libceres-dev; or set CERES_INCLUDE_DIR)"
    py_include = sysconfig.get_paths()["include"]
    if not (Path(py_include) / "Python.h").is_file():
        return False, f"Python headers not found in {py_include}"
    cmd = [cxx, *FLAGS, f"-I{pybind11.get_include()}", f"-I{py_include}", f"-I{include}", str(SOURCE), "-o", str(TARGET)]
    eigen = include / "eigen3"
    if eigen.is_dir():
        cmd.insert(-3, f"-I{eigen}")
    fingerprint = _fingerprint(cmd)
    if not force and TARGET.is_file() and STAMP.is_file() and STAMP.read_text().strip() == fingerprint:
        return True, f"{TARGET.name} is up to date"
    tmp = TARGET.with_name(TARGET.name + ".tmp")
    cmd[-1] = str(tmp)
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        return False, f"compilation failed: {shlex.join(cmd)}\n{proc.stderr.strip()[-4000:]}"
    os.replace(tmp, TARGET)
    STAMP.write_text(fingerprint + "\n")
    return True, f"built {TARGET.relative_to(ROOT)}"


def main() -> int:
    ap = argparse.ArgumentParser(description="build the compiled Ceres cost functions")
    ap.add_argument("--require", action="store_true", help="exit 1 when the module cannot be built")
    ap.add_argument("--force", action="store_true", help="rebuild even when up to date")
    args = ap.parse_args()
    ok, message = build(args.force)
    if ok:
        print(f"native: {message}")
        return 0
    print(f"native: WARNING: {message}; solves will use the slower Python cost functions", file=sys.stderr)
    return 1 if args.require else 0


if __name__ == "__main__":
    sys.exit(main())
