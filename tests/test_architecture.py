"""The architecture of docs/architecture.md holds in the code (issue 14).

- No import cycle among the modules of ``solver`` and ``service``, counting every import (those
  inside functions and under ``TYPE_CHECKING`` too): grimp's graph, as ``lint-imports`` sees it.
- The layer list of docs/architecture.md is the ``solver layers`` contract of pyproject.toml,
  which ``lint-imports`` (``make test``) enforces: the page a newcomer reads cannot drift from
  the rule the code is held to.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import re
import sys
import tomllib
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]


def import_cycles(graph: grimp.ImportGraph) -> list[set[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    adj = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in sorted(graph.modules)}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[set[str]] = []
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(adj) + 100))

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in adj[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)

    try:
        for m in adj:
            if m not in index:
                visit(m)
    finally:
        sys.setrecursionlimit(limit)
    return out


def test_no_import_cycles() -> None:
    graph = grimp.build_graph("solver", "service", include_external_packages=False)
    assert import_cycles(graph) == []


def test_cycle_finder_has_teeth() -> None:
    graph = grimp.ImportGraph()
    for m in ("p.a", "p.b", "p.c", "p.d"):
        graph.add_module(m)
    graph.add_import(importer="p.a", imported="p.b")
    graph.add_import(importer="p.b", imported="p.c")
    graph.add_import(importer="p.c", imported="p.a")
    graph.add_import(importer="p.c", imported="p.d")
    assert import_cycles(graph) == [{"p.a", "p.b", "p.c"}]


def _contract_layers() -> list[str]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    contracts = config["tool"]["importlinter"]["contracts"]
    (layers,) = [c["layers"] for c in contracts if c["name"] == "solver layers"]
    return layers


def _documented_layers() -> list[str]:
    text = (ROOT / "docs" / "architecture.md").read_text()
    block = re.search(r"<!-- layers: begin -->\n```text\n(.*?)```\n<!-- layers: end -->", text, re.S)
    assert block, "docs/architecture.md has lost its layer diagram"
    rows = [line.split("#")[0].strip() for line in block.group(1).splitlines()]
    return [re.sub(r"\s*\|\s*", " | ", row) for row in rows if row]


def test_documented_layers_are_the_checked_layers() -> None:
    assert _documented_layers() == [re.sub(r"\s*\|\s*", " | ", layer) for layer in _contract_layers()]


def test_every_path_and_module_the_page_names_exists() -> None:
    """The job's path and the 'where new code goes' list name files and modules that exist."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    paths = set(re.findall(r"(?<![\w/])((?:solver|service)/[\w/]*\w(?:\.py|\.cpp)?)", text))  # not tests/solver/...
    missing = [p for p in sorted(paths) if not (ROOT / p).exists()]
    modules = set(re.findall(r"`((?:solver|service)(?:\.\w+)+)", text))
    for name in sorted(modules):  # a module, or a module and an attribute path in it
        parts = name.split(".")
        for k in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:k]))
                break
            except ModuleNotFoundError:
                continue
        for attr in parts[k:]:
            obj = getattr(obj, attr, None)
        if obj is None:
            missing.append(name)
    assert paths and modules and not missing, missing


# ---- observation families: the stages walk the registry, they do not name families -----------

STAGES = ("solver/engine", "solver/quality", "solver/report", "solver/procedures", "solver/adjust.py")
# Names a stage may take from a family module (none: the parameter blocks the families once
# defined are the block kinds of solver/blocks/, which the stages walk through their registry).
ALLOWED: dict[str, set[str]] = {}
# The families' data modules (the rest of solver/observations/ but its interface and registry)
# are held to the same rule. What stages still take from them is listed here, so that the list
# can only shrink: the images' approximate states from header or ephemeris (validation,
# initialisation, pre-analysis, the datum analysis, the report's line-0 states) and the straight
# lines' geometry (assembly, pre-analysis).
DATA_ALLOWED: dict[str, set[str]] = {
    "solver.observations.ephemeris": {"image_state", "line0_state_ecef"},
    "solver.observations.line_data": {"build_lines", "control_line_points_ecef", "lines_ecef"},
}


def family_modules() -> set[str]:
    from solver.observations import registry

    return {type(f).__module__ for f in registry.FAMILIES}


def observation_modules() -> set[str]:
    """The family modules and their data modules: every module of solver/observations/ but the
    interface (``family``) and the registry."""
    folder = ROOT / "solver" / "observations"
    data = {f"solver.observations.{p.stem}" for p in folder.glob("*.py") if p.stem not in ("__init__", "family", "registry")}
    return family_modules() | data


def imported_names(source: str) -> list[tuple[str, set[str]]]:
    """(module, names taken from it) of every absolute import in ``source``, at any depth
    (``import a.b`` takes the module as a whole: the name ``*``)."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.module, {a.name for a in node.names}))
            for a in node.names:  # from solver.observations import lines
                out.append((f"{node.module}.{a.name}", {"*"}))
        elif isinstance(node, ast.Import):
            out += [(a.name, {"*"}) for a in node.names]
    return out


def family_imports(source: str, families: set[str], allowed: dict[str, set[str]] = ALLOWED) -> list[str]:
    """The imports of ``source`` that name a family module beyond what ``allowed`` lets through."""
    bad = []
    for module, names in imported_names(source):
        if module in families:
            extra = names - allowed.get(module, set())
            if extra:
                bad.append(f"{module}: {', '.join(sorted(extra))}")
    return bad


def test_no_stage_imports_an_observation_family_by_name() -> None:
    families = family_modules()
    assert {"solver.observations.lines", "solver.observations.attitude"} <= families
    modules = observation_modules()
    assert {"solver.observations.ephemeris", "solver.observations.line_data"} <= modules - families
    offenders = {}
    for stage in STAGES:
        path = ROOT / stage
        for file in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            bad = family_imports(file.read_text(), modules, {**ALLOWED, **DATA_ALLOWED})
            if bad:
                offenders[str(file.relative_to(ROOT))] = bad
    assert offenders == {}


def test_the_family_import_check_has_teeth() -> None:
    families = {"solver.observations.lines", "solver.observations.passes"}
    assert family_imports("from solver.observations.lines import LineTerm\n", families) == ["solver.observations.lines: LineTerm"]
    assert family_imports("def f():\n    from solver.observations import lines\n", families) == ["solver.observations.lines: *"]
    assert family_imports("import solver.observations.passes as p\n", families) == ["solver.observations.passes: *"]
    assert family_imports("from solver.observations.passes import pass_terms\n", families) == ["solver.observations.passes: pass_terms"]
    allowed = {"solver.observations.passes": {"pass_terms"}}
    assert family_imports("from solver.observations.passes import pass_terms\n", families, allowed) == []
    assert family_imports("from solver.observations import registry\n", families) == []


def _documented_families() -> list[tuple[str, str]]:
    text = (ROOT / "docs" / "architecture.md").read_text()
    block = re.search(r"<!-- families: begin -->\n(.*?)<!-- families: end -->", text, re.S)
    assert block, "docs/architecture.md has lost its list of observation families"
    return re.findall(r"^\d+\. `(\w+)` \(`(solver/observations/\w+\.py)`\)", block.group(1), re.M)


def test_documented_families_are_the_registry() -> None:
    from solver.observations import registry

    want = [(f.name, type(f).__module__.replace(".", "/") + ".py") for f in registry.FAMILIES]
    assert _documented_families() == want


def _documented_block_kinds() -> list[tuple[str, str]]:
    text = (ROOT / "docs" / "architecture.md").read_text()
    block = re.search(r"<!-- block kinds: begin -->\n(.*?)<!-- block kinds: end -->", text, re.S)
    assert block, "docs/architecture.md has lost its list of parameter-block kinds"
    return re.findall(r"^\s*\d+\. `(\w+)` \(`(solver/blocks/\w+\.py)`\)", block.group(1), re.M)


def test_documented_block_kinds_are_the_registry() -> None:
    from solver.blocks import registry

    want = [(k.name, type(k).__module__.replace(".", "/") + ".py") for k in registry.BLOCK_KINDS]
    assert _documented_block_kinds() == want


SECTION_LINE = r"^\s*\d+\. `(\w+)`: (.*)$"  # a report section's entry: its name, the sections it builds
READER_LINE = r"^\s*\d+\. `([\w-]+)` \(`(solver/sensors/\w+\.py)`\): (.*)$"  # a format: name, module, roots


def _documented_list(marker: str, pattern: str) -> list[tuple[str, ...]]:
    """The entries of the list between ``<!-- marker: begin -->`` and ``<!-- marker: end -->``."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    block = re.search(rf"<!-- {marker}: begin -->\n(.*?)<!-- {marker}: end -->", text, re.S)
    assert block, f"docs/architecture.md has lost its list of {marker}"
    return re.findall(pattern, block.group(1), re.M)


def snake(name: str) -> str:
    """``_BlockKinds`` -> ``block_kinds``: the name the page gives a report section's entry."""
    return re.sub(r"(?<!^)([A-Z])", r"_\1", name.lstrip("_")).lower()


def test_documented_report_sections_are_the_registry() -> None:
    """The report's entries in the order they are built (the keys each builds:
    tests/solver/report/test_report_sections.py checks them on a report)."""
    from solver.report import sections

    documented = [name for name, _ in _documented_list("report sections", SECTION_LINE)]
    assert documented == [snake(type(entry).__name__) for entry in sections.SECTIONS]


def test_documented_readers_are_the_registry() -> None:
    """The sensor formats in the order they are tried, the module that reads them (its product's;
    a format without a product type: its detection's) and the XML roots the job builder learns."""
    from solver.sensors import readers

    documented = [(name, path, tuple(re.findall(r"`(\w+)`", rest)))
                  for name, path, rest in _documented_list("readers", READER_LINE)]
    want = [(r.name, (r.products[0] if r.products else r.detect).__module__.replace(".", "/") + ".py", r.roots)
            for r in readers.READERS]
    assert documented == want


def test_the_documented_list_checks_have_teeth() -> None:
    assert snake("_BlockKinds") == "block_kinds" and snake("_Header") == "header"
    text = "  1. `maxar` (`solver/sensors/maxar.py`): root `isd`.\n  2. `x-y` (`solver/sensors/x.py`): roots `a`, `b`.\n"
    assert re.findall(READER_LINE, text, re.M) == [
        ("maxar", "solver/sensors/maxar.py", "root `isd`."), ("x-y", "solver/sensors/x.py", "roots `a`, `b`.")]
    assert re.findall(SECTION_LINE, "  10. `quality`: `quality` (leave-one-out).\n", re.M) == [("quality", "`quality` (leave-one-out).")]


# ---- one place for a repeated concept: CRS transformers ---------------------------------------

# Where a pyproj transformer may be built with its own axis order: the one place
# (solver.geometry.geodesy.transformer), the simulator (the independent truth: PROJ on its own),
# and the vertical datums' TransformerGroup (it picks among PROJ's operations by their grids).
TRANSFORMER_BUILDERS = ("solver/geometry/geodesy.py", "solver/simulate/", "solver/geometry/vertical.py")


def transformer_builds(source: str) -> list[int]:
    """Lines of ``source`` that build a pyproj transformer (``Transformer.from_crs``,
    ``Transformer.from_pipeline``, ``Transformer.from_proj``, ``TransformerGroup(...)``)."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Attribute) and f.attr.startswith("from_") and getattr(f.value, "id", None) == "Transformer":
                out.append(node.lineno)
            elif getattr(f, "id", None) == "TransformerGroup":
                out.append(node.lineno)
    return out


def test_transformers_are_built_in_one_place() -> None:
    builds = {}
    for file in sorted((ROOT / "solver").rglob("*.py")) + sorted((ROOT / "service").rglob("*.py")):
        rel = str(file.relative_to(ROOT))
        if not rel.startswith(TRANSFORMER_BUILDERS) and (lines := transformer_builds(file.read_text())):
            builds[rel] = lines
    assert builds == {}


def test_the_transformer_scan_has_teeth() -> None:
    source = ("t = Transformer.from_crs(a, b, always_xy=True)\nu = transformer(a, b)\n"
              "g = TransformerGroup(a, b)\nv = Transformer.from_pipeline(p)\nw = CRS.from_epsg(4326)\n")
    assert transformer_builds(source) == [1, 3, 4]


# ---- platform models: the checklist of docs/architecture.md holds ------------------------------

def _platform_checklist() -> str:
    text = (ROOT / "docs" / "architecture.md").read_text()
    block = re.search(r"- \*\*A platform model\*\*(.*?)\n- \*\*An observation family\*\*", text, re.S)
    assert block, "docs/architecture.md has lost its platform-model checklist"
    return block.group(1)


def kind_interface(cls: type) -> set[str]:
    """The public fields, properties and methods of a kind class (and its bases), but its name."""
    names = {f.name for f in dataclasses.fields(cls)} - {"name"}
    for klass in cls.__mro__:
        if klass is object:
            continue
        names |= {n for n, v in vars(klass).items() if not n.startswith("_") and (callable(v) or isinstance(v, property))}
    return names


def test_the_kind_answers_what_the_checklist_says() -> None:
    """Step 2 names everything the kind answers: exactly the public interface of PlatformKind."""
    from solver.platforms.kinds import PlatformKind

    block = re.search(r"<!-- kind: begin -->(.*?)<!-- kind: end -->", _platform_checklist(), re.S)
    assert block, "the checklist has lost its list of what a kind answers"
    assert set(re.findall(r"`(\w+)`", block.group(1))) == kind_interface(PlatformKind)


# ---- the platform kind's capabilities are asked where the platforms live -----------------------

CAPABILITY_READERS = ("solver/platforms", "solver/kernels", "solver/blocks")
MOST_CAPABILITY_READS_ELSEWHERE = 3  # ratcheted to what is left (the issue allowed 5): the model comparison, the pre-analysis's levelling, the state's kernel code


def capability_reads(source: str, capabilities: set[str]) -> list[int]:
    """Lines of ``source`` that read a capability of a platform kind (``<x>.kind.<capability>``)."""
    return [
        node.lineno
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Attribute) and node.attr in capabilities
        and isinstance(node.value, ast.Attribute) and node.value.attr == "kind"
    ]


def test_the_platform_kinds_capabilities_are_read_by_the_platforms_kernels_and_blocks() -> None:
    """Stages ask the parameter blocks (solver/blocks/), which ask the platform kind: outside the
    platforms, the kernels and the blocks, at most a few reads of a kind's capabilities remain."""
    from solver.platforms.kinds import PlatformKind

    capabilities = kind_interface(PlatformKind)
    reads = {}
    for file in sorted((ROOT / "solver").rglob("*.py")):
        rel = str(file.relative_to(ROOT))
        if rel.startswith(CAPABILITY_READERS):
            continue
        lines = capability_reads(file.read_text(), capabilities)
        if lines:
            reads[rel] = lines
    assert sum(len(v) for v in reads.values()) <= MOST_CAPABILITY_READS_ELSEWHERE, reads


def test_the_capability_count_has_teeth() -> None:
    caps = {"has_camera", "kernel"}
    assert capability_reads("if img.model.kind.has_camera:\n    pass\nk = m.kind.kernel\n", caps) == [1, 3]
    assert capability_reads("kind = 'x'\nif g.kind == 'y': pass\n", caps) == []


def registering_modules(package: Path, root: Path = ROOT) -> set[str]:
    """Modules of ``package`` (a directory under ``root``) that call ``register(...)`` at import."""
    out = set()
    for file in package.glob("*.py"):
        todo: list[ast.AST] = [ast.parse(file.read_text())]
        while todo:  # module-level statements, loops included, functions' bodies not
            node = todo.pop()
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "register":
                out.add(".".join(file.relative_to(root).with_suffix("").parts))
            todo += [c for c in ast.iter_child_nodes(node) if not isinstance(c, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))]
    return out


def test_every_model_module_is_one_import_line_and_the_registry_imports_none() -> None:
    """Step 1: a model module registers itself and is imported by one line of the package's
    ``__init__``; the registry imports no model module."""
    package = ROOT / "solver" / "platforms"
    models = registering_modules(package)
    assert {"solver.platforms.polynomial", "solver.platforms.rpc_bias"} <= models
    init = {m for m, _ in imported_names((package / "__init__.py").read_text())}
    assert models <= init, models - init
    registry_imports = {m for m, _ in imported_names((package / "registry.py").read_text())}
    assert not registry_imports & models


def test_the_registering_scan_has_teeth(tmp_path) -> None:
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "model_a.py").write_text("from x import register\nregister(Model('A'))\n")
    (pkg / "model_b.py").write_text("M = register(Model('B'))\nfor n in 'CD':\n    register(Model(n))\n")
    (pkg / "helper.py").write_text("def f():\n    register(1)\nregister_kind(K)\n")
    assert registering_modules(pkg, tmp_path) == {"pkg.model_a", "pkg.model_b"}


def test_every_kind_has_its_kernel_branch() -> None:
    """Step 3: each registered kind names a ``KIND_*`` code of solver/kernels/layout.py, and that
    code is branched on where the checklist says: platform evaluation (solver/kernels/platform.py)
    for a kind with a camera, the projection's dispatch (solver/kernels/projection.py) without."""
    from solver.kernels import layout
    from solver.platforms.kinds import all_kinds

    codes = {getattr(layout, n): n for n in dir(layout) if n.startswith("KIND_")}
    sources = {w: (ROOT / "solver" / "kernels" / f"{w}.py").read_text() for w in ("platform", "projection")}
    missing = []
    for kind in all_kinds():
        assert kind.kernel in codes, kind.name
        where = "platform" if kind.has_camera else "projection"
        if not re.search(rf"kind [!=]= {codes[kind.kernel]}\b", sources[where]):
            missing.append(f"{kind.name}: {codes[kind.kernel]} in solver/kernels/{where}.py")
    assert missing == []
