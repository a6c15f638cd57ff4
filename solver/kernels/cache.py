"""Disk cache of the compiled numba kernels, keyed on the kernel sources (import before ``@njit``).

numba's own cache (``cache=True``) checks only the source file of the function it loads: a
kernel in :mod:`solver.kernels` that inlines :func:`solver.kernels.propagation.gravity_and_gradient`
is loaded from the cache unchanged after ``propagation.py`` is edited, so a developer's test
run, or an installation upgraded in place, can run the old physics without a word.

Importing this module registers :class:`KernelSourceLocator` first in numba's list of cache
locators. For every function defined in a ``solver`` source file it puts the cache in a
directory named after one digest of all the kernel sources (:func:`kernel_sources`):

    <base>/pba-kernels-<digest>/<numba's per-directory subpath>/

so a change to any of them starts an empty directory and the kernels are compiled afresh.
``<base>`` is ``NUMBA_CACHE_DIR`` when set, else ``solver/__pycache__`` when writable, else
numba's user-wide cache directory. Directories of older digests are left in place: a worker
of the previous version may still be using one while an upgrade is under way.

Processes sharing the cache at once (server workers, ``pba warmup``, the tests) are safe:
numba writes each cache file to a temporary name and renames it into place, and two processes
that compile the same kernel write the same content.

Every module that defines ``@njit`` functions imports this module before its first decorator
(tests/solver/kernels/test_kernel_cache.py checks it). ``NUMBA_CACHE_LOCATOR_CLASSES``, when set, replaces
numba's locator list and with it this mechanism.
"""

from __future__ import annotations

import ast
import hashlib
import os
import re
from functools import lru_cache
from pathlib import Path

from numba.core import caching
from numba.misc.appdirs import AppDirs

SOLVER_DIR = Path(__file__).resolve().parent.parent  # solver/
_CACHE_IMPL = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl")  # numba >= 0.61 / older
_JIT_DECORATORS = {"njit", "jit", "vectorize", "guvectorize", "cfunc"}
_DECORATOR_LINE = re.compile(r"^\s*@\s*(?:numba\.)?(?:njit|jit|vectorize|guvectorize|cfunc)\b", re.M)


def defines_kernels(tree: ast.AST) -> bool:
    """Whether a parsed module has a function decorated with a numba compiler (``@njit(...)``)."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for dec in node.decorator_list:
                target = dec.func if isinstance(dec, ast.Call) else dec
                name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", None)
                if name in _JIT_DECORATORS:
                    return True
    return False


def _constant_sources(tree: ast.AST) -> set[Path]:
    """Source files of the ``solver`` modules a parsed module takes constants from
    (``from solver.x import UPPER_CASE``): the only globals, besides other kernels, that a
    jitted function can read and freeze into its compiled code."""
    out: set[Path] = set()
    for node in ast.walk(tree):
        if not (isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("solver.")):
            continue
        if not any(a.name.isupper() for a in node.names):
            continue
        rel = Path(*node.module.split(".")[1:])
        for candidate in (SOLVER_DIR / rel.with_suffix(".py"), SOLVER_DIR / rel / "__init__.py"):
            if candidate.is_file():
                out.add(candidate)
    return out


def kernel_sources() -> list[Path]:
    """The files the compiled kernels depend on, sorted: every ``solver`` module that defines
    jitted functions (a kernel inlines the kernels it calls, from whichever module) and the
    ``solver`` modules those take constants from. Other modules (problem.py, adjust.py...) do
    not reach compiled code, so editing them keeps the cache."""
    deps: set[Path] = set()
    for p in SOLVER_DIR.rglob("*.py"):
        text = p.read_text(encoding="utf-8")
        if not _DECORATOR_LINE.search(text):
            continue  # no decorator line of a numba compiler: no need to parse it
        tree = ast.parse(text)
        if defines_kernels(tree):
            deps |= {p} | _constant_sources(tree)
    return sorted(deps)


@lru_cache(maxsize=1)
def sources_digest() -> str:
    """16 hex digits of SHA-256 over the kernel sources' relative paths and contents."""
    h = hashlib.sha256()
    for p in kernel_sources():
        h.update(p.relative_to(SOLVER_DIR).as_posix().encode())
        h.update(b"\0")
        h.update(p.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:16]


def cache_bases(py_file: str) -> list[str]:
    """Candidate base directories, in order of preference."""
    bases = []
    if caching.config.CACHE_DIR:
        bases.append(caching.config.CACHE_DIR)
    bases.append(os.path.join(os.path.dirname(py_file), "__pycache__"))
    bases.append(AppDirs(appname="numba", appauthor=False).user_cache_dir)
    return bases


class KernelSourceLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
    """numba cache locator for ``solver`` sources: one directory per digest of the kernel sources."""

    def __init__(self, py_func, py_file: str, base: str) -> None:
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = os.path.join(
            base, f"pba-kernels-{sources_digest()}", self.get_suitable_cache_subpath(py_file)
        )

    def get_cache_path(self) -> str:
        return self._cache_path

    def get_source_stamp(self):
        # the digest in the stamp too: an index written under another digest is never trusted
        return (super().get_source_stamp(), sources_digest())

    @classmethod
    def from_function(cls, py_func, py_file: str):
        try:
            inside = Path(py_file).resolve().is_relative_to(SOLVER_DIR)
        except OSError:
            inside = False
        if not inside or not os.path.exists(py_file):
            return None
        for base in cache_bases(py_file):
            self = cls(py_func, py_file, base)
            try:
                self.ensure_cache_path()
            except OSError:
                continue
            return self
        return None


def install() -> None:
    """Put :class:`KernelSourceLocator` first in numba's locator list (idempotent)."""
    classes = _CACHE_IMPL._locator_classes
    if not any(c.__name__ == KernelSourceLocator.__name__ and c.__module__ == __name__ for c in classes):
        classes.insert(0, KernelSourceLocator)


def cache_dir() -> Path:
    """The directory the kernels of :mod:`solver.kernels` are cached in (for ``pba warmup``)."""
    py_file = str(SOLVER_DIR / "kernels" / "__init__.py")
    for base in cache_bases(py_file):
        path = Path(base) / f"pba-kernels-{sources_digest()}" / KernelSourceLocator.get_suitable_cache_subpath(py_file)
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError:
            continue
        if os.access(path, os.W_OK):
            return path
    raise OSError("no writable numba cache directory")


install()
