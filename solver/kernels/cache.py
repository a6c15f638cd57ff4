"""Disk cache of the compiled numba kernels, keyed on the kernel sources (import before ``@njit``).

numba's own cache (``cache=True``) checks only the source file of the function it loads: a
kernel in :mod:`solver.kernels` that inlines :func:`solver.kernels.propagation.gravity_and_gradient`
is loaded from the cache unchanged after ``propagation.py`` is edited, so a developer's test
run, or an installation upgraded in place, can run the old physics without a word.

Importing this module registers :class:`KernelSourceLocator` first in numba's list of cache
locators. For every function defined in a ``solver`` source file it puts the cache in a
directory named after one digest of all the kernel sources (:func:`kernel_sources`):

    <base>/pba-kernels-<digest>/<the source file's folder under solver/>/

so a change to any of them starts an empty directory and the kernels are compiled afresh.
Directories of older digests are left in place: a worker of the previous version may still be
using one while an upgrade is under way.

Compiled once per installation. The installation's own cache is ``solver/__pycache__``
(:data:`INSTALLATION_BASE`): ``make native``, the Docker build and ``pba warmup`` compile every
kernel into it, and every process of the installation finds it, whatever its
``NUMBA_CACHE_DIR`` or user: a process works in the first writable base of
``NUMBA_CACHE_DIR``, ``solver/__pycache__`` and numba's user-wide cache directory, and when
that is not the installation's (another user, a read-only image, a cache directory of its own)
it first copies into it the installation's files it lacks (:func:`_seed`). Nothing in the path or the entries depends on where the installation lives
(numba's own stamp is a hash of the source's content), so a copied installation or image keeps
its cache.

Portable machine code (:func:`select_cpu`): numba keys its entries on the CPU it compiles for,
by default the host's model. On an x86-64 host that has the x86-64-v3 feature level (AVX2, FMA:
every x86 server CPU since 2013-2015) the kernels are compiled for ``x86-64-v3`` instead, so a
cache compiled on one machine (an image's build host) serves every such machine it is copied
to; measured on the 100,000-observation P2 block, the kernels run as fast (1.17 against 1.26
us per observation with Jacobians, one core). ``PBA_KERNEL_CPU=host`` keeps numba's default,
``NUMBA_CPU_NAME`` when set is left alone.

Processes sharing the cache at once (server workers, ``pba warmup``, the tests) are safe:
numba writes each cache file to a temporary name and renames it into place, and two processes
that compile the same kernel write the same content.

While kernels compile (a minute or more of CPU for a whole set: numba types and optimises
every kernel of the call tree again for each entry point), :func:`compile_notices` says so.

Every module that defines ``@njit`` functions imports this module before its first decorator
(tests/solver/kernels/test_kernel_cache.py checks it). ``NUMBA_CACHE_LOCATOR_CLASSES``, when set, replaces
numba's locator list and with it this mechanism.
"""

from __future__ import annotations

import ast
import hashlib
import os
import re
import tempfile
import time
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Callable, Iterator

from numba.core import caching
from numba.core import event as numba_event
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


INSTALLATION_BASE = SOLVER_DIR / "__pycache__"  # the installation's own cache (make native, pba warmup)

# the x86-64-v3 feature level (LLVM's names): AVX, AVX2, BMI1/2, F16C, FMA, LZCNT, MOVBE, XSAVE
# and the x86-64-v2 features below them
X86_64_V3 = frozenset(
    {"avx", "avx2", "bmi", "bmi2", "f16c", "fma", "lzcnt", "movbe", "xsave", "cx16", "sahf", "popcnt", "sse3", "sse4.1",
     "sse4.2", "ssse3"}
)
PORTABLE_X86 = "x86-64-v3"


def select_cpu() -> str:
    """The CPU model the kernels are compiled for, set in numba's configuration before its first
    compilation (``NUMBA_CPU_NAME``, inherited by the processes this one starts).

    ``PBA_KERNEL_CPU``: ``portable`` (the default) compiles for x86-64-v3 on an x86-64 host that
    has that feature level, so that a cache compiled on one machine serves another; ``host``
    keeps numba's default (the host's own model, e.g. ``znver4``); any other value is an LLVM
    CPU name. An explicit ``NUMBA_CPU_NAME`` is left alone.
    """
    import platform

    import llvmlite.binding as ll
    from numba.core import config

    if os.environ.get("NUMBA_CPU_NAME"):
        return os.environ["NUMBA_CPU_NAME"]
    choice = os.environ.get("PBA_KERNEL_CPU", "portable").strip() or "portable"
    if choice == "host":
        return ll.get_host_cpu_name()
    if choice == "portable":
        if platform.machine().lower() not in ("x86_64", "amd64"):
            return ll.get_host_cpu_name()
        features = ll.get_host_cpu_features()
        if not all(features.get(f, False) for f in X86_64_V3):
            return ll.get_host_cpu_name()
        choice = PORTABLE_X86
    os.environ["NUMBA_CPU_NAME"] = choice
    os.environ["NUMBA_CPU_FEATURES"] = ""  # the model's own features, not the host's
    config.reload_config()
    return choice


def cache_bases() -> list[Path]:
    """Writable candidates for a process's cache, in order of preference."""
    bases = []
    if caching.config.CACHE_DIR:
        bases.append(Path(caching.config.CACHE_DIR))
    bases.append(INSTALLATION_BASE)
    bases.append(Path(AppDirs(appname="numba", appauthor=False).user_cache_dir))
    return bases


def subpath(py_file: str) -> str:
    """The cache folder of a source file's functions below ``pba-kernels-<digest>``: its folder
    under solver/ (``kernels``, ``engine``...), the same wherever the installation lives."""
    rel = Path(py_file).resolve().parent.relative_to(SOLVER_DIR)
    return "_".join(rel.parts) or "solver"


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


_SEEDED: set[tuple[Path, Path]] = set()


def _seed(source: Path, target: Path) -> None:
    """Copy into ``target`` the cache files of ``source`` (the installation's) it lacks, each
    under a temporary name renamed into place (processes seeding at once write the same bytes)."""
    if (source, target) in _SEEDED or not source.is_dir() or source == target:
        return
    _SEEDED.add((source, target))
    for f in source.iterdir():
        dest = target / f.name
        if f.suffix not in (".nbi", ".nbc") or dest.exists():
            continue
        try:
            with tempfile.NamedTemporaryFile(dir=target, prefix=f".{f.name}.", delete=False) as tmp:
                tmp.write(f.read_bytes())
            os.replace(tmp.name, dest)
        except OSError:
            continue


class KernelSourceLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
    """numba cache locator for ``solver`` sources: one directory per digest of the kernel sources."""

    def __init__(self, py_func, py_file: str, base: Path) -> None:
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = str(base / f"pba-kernels-{sources_digest()}" / subpath(py_file))

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
        base = process_base()
        if base is None:
            return None
        return cls(py_func, py_file, base)


@lru_cache(maxsize=1)
def process_base() -> Path | None:
    """This process's cache base: the first writable of :func:`cache_bases` (``NUMBA_CACHE_DIR``
    when set, else the installation's, else numba's user-wide directory), first seeded with the
    installation's files it lacks when it is not the installation's (:func:`_seed`)."""
    for base in cache_bases():
        if _writable(base / f"pba-kernels-{sources_digest()}"):
            if base != INSTALLATION_BASE:
                _seed_all(base)
            return base
    return None


def _seed_all(base: Path) -> None:
    installed = INSTALLATION_BASE / f"pba-kernels-{sources_digest()}"
    if not installed.is_dir():
        return
    for folder in installed.iterdir():
        if folder.is_dir():
            target = base / f"pba-kernels-{sources_digest()}" / folder.name
            if _writable(target):
                _seed(folder, target)


def install() -> None:
    """Put :class:`KernelSourceLocator` first in numba's locator list (idempotent) and choose
    the CPU the kernels are compiled for (:func:`select_cpu`)."""
    select_cpu()
    classes = _CACHE_IMPL._locator_classes
    if not any(c.__name__ == KernelSourceLocator.__name__ and c.__module__ == __name__ for c in classes):
        classes.insert(0, KernelSourceLocator)


def cache_dir() -> Path:
    """The directory the kernels of :mod:`solver.kernels` are cached in (for ``pba warmup``)."""
    base = process_base()
    if base is None:
        raise OSError("no writable numba cache directory")
    return base / f"pba-kernels-{sources_digest()}" / subpath(str(SOLVER_DIR / "kernels" / "__init__.py"))


# what a whole set costs, measured: the warm-up's kernels 140 s of CPU on a 2-core machine, the
# P2 or K2 kernels of one job 50-60 s (all of it the compiler: numba types and optimises each
# kernel of the call tree again for every kernel above it)
COMPILE_ESTIMATE = "1-3 minutes of CPU for the whole set"


class _CompileWatch(numba_event.Listener):
    """numba's compile events (a kernel not found in the cache): the solver's outermost ones."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self.say = say
        self.depth = 0
        self.started: float | None = None
        self.t_kernel = 0.0
        self.count = 0

    @staticmethod
    def _name(event) -> str | None:
        func = getattr((event.data or {}).get("dispatcher"), "py_func", None)
        module = getattr(func, "__module__", "") or ""
        return f"{module.rsplit('.', 1)[-1]}.{func.__qualname__}" if module.startswith("solver.") else None

    def on_start(self, event) -> None:
        self.depth += 1
        if self.depth != 1 or self._name(event) is None:
            return
        now = time.perf_counter()
        if self.started is None:
            self.started = now
            self.say(
                f"compiling the solver's kernels for this machine ({os.environ.get('NUMBA_CPU_NAME') or 'host CPU'}), "
                f"once per installation and version: {COMPILE_ESTIMATE}; `pba warmup` does it ahead of the first job"
            )
        self.t_kernel = now

    def on_end(self, event) -> None:
        self.depth -= 1
        name = self._name(event)
        if self.depth != 0 or name is None or self.started is None:
            return
        self.count += 1
        now = time.perf_counter()
        self.say(f"compiled {name} in {now - self.t_kernel:.0f} s ({self.count} so far, {now - self.started:.0f} s)")


@contextmanager
def compile_notices(say: Callable[[str], None]) -> Iterator[None]:
    """Within the block, call ``say(message)`` when a solver kernel has to be compiled (it was not
    in the cache): first what is happening and how long it takes, then after each outermost
    kernel compiled its name and seconds. Nothing is said when every kernel comes from the cache."""
    with numba_event.install_listener("numba:compile", _CompileWatch(say)):
        yield


install()
