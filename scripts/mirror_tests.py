"""Move the flat test files into folders that mirror the package tree (``tests/solver/<package>/``).

Run from the repository root, on a clean work tree, after every branch that adds tests is merged:

    python scripts/mirror_tests.py --dry-run     # print the moves and the rewritten references
    python scripts/mirror_tests.py               # git mv, rewrite, then check collection yourself:
    python -m pytest --collect-only -q | tail -1  # the same number of tests as before the move

What the move needs besides ``git mv`` (each is done here):

* ``Path(__file__)`` depths: a file moved two folders down finds the repository root at
  ``parents[k + 2]``; ``.parent`` (the tests folder: its data/ and fixtures/) becomes
  ``.parents[depth]``.
* Helpers imported by their module name (``from test_orbit_pass import _pass_job``,
  ``from fake_platform_kind import install``): pytest's default ``prepend`` import mode puts
  only the importing file's folder and the folders of conftest.py files on ``sys.path``, so a
  helper imported from another folder needs its folder there: tests/conftest.py gets one
  ``sys.path`` line per such folder. Helpers shared across packages (tolerances.py,
  bad_job_cases.py) stay in tests/, which conftest.py already puts there.
* Basenames stay unique (no ``__init__.py`` is added, so two ``test_x.py`` in two folders would
  collide); the script refuses a mapping that breaks this.
* References to the moved files by path (docs, docstrings, comments, the Makefile) are rewritten.

Files not named in :data:`MAPPING` stay where they are (tests/service/, tests/browser/ and the
cross-cutting tests at the top: architecture, docs, examples, report fixtures, bad input); a
test file that is in neither :data:`MAPPING` nor :data:`STAY` stops the script, so a file added
after this mapping was written is placed by a person, not by default.
"""

from __future__ import annotations

import argparse
import ast
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"

# tests/<name> -> folder under tests/ (mirrors solver/<package>/)
MAPPING: dict[str, str] = {
    # solver top level: commands, CLI, warm-up, the adjustment's outcome
    "test_cli.py": "solver",
    "test_warmup.py": "solver",
    # engine: validation, assembly, backend, linearisation
    "test_linalg.py": "solver/engine",
    "test_residual_jacobians.py": "solver/engine",
    "test_solve_outcomes.py": "solver/engine",
    "test_compiled_evaluation.py": "solver/engine",
    "test_handed_validation.py": "solver/engine",
    # kernels
    "test_kernels.py": "solver/kernels",
    "test_kernel_cache.py": "solver/kernels",
    "test_pixel_convention.py": "solver/kernels",
    # observation families
    "test_observation_registry.py": "solver/observations",
    "test_attitude_obs.py": "solver/observations",
    "test_ephemeris.py": "solver/observations",
    "test_lines.py": "solver/observations",
    "test_lines_cbers.py": "solver/observations",
    "test_prior_jacobians.py": "solver/observations",
    "test_selfcal.py": "solver/observations",
    "test_chips.py": "solver/observations",
    # platform models and kinds
    "test_models.py": "solver/platforms",
    "test_platform_kinds.py": "solver/platforms",
    "fake_platform_kind.py": "solver/platforms",
    "test_orbit_pass.py": "solver/platforms",
    "test_orbit_attitude.py": "solver/platforms",
    "test_rpc_models.py": "solver/platforms",
    # quality control
    "test_quality_defaults.py": "solver/quality",
    "test_quality_external.py": "solver/quality",
    "test_quality_parsimony.py": "solver/quality",
    "test_quality_preanalysis.py": "solver/quality",
    "test_quality_precision.py": "solver/quality",
    "test_quality_removal.py": "solver/quality",
    "test_quality_snooping.py": "solver/quality",
    "test_montecarlo.py": "solver/quality",
    "test_tie_pairs.py": "solver/quality",
    # procedures that adjust more than once
    "test_weak_control.py": "solver/procedures",
    # report
    "test_report_statistics.py": "solver/report",
    # geometry
    "test_geodesy.py": "solver/geometry",
    "test_chip_indices.py": "solver/geometry",
    # schema
    "test_settings.py": "solver/schema",
    # GIS
    "test_gis_ortho.py": "solver/gis",
    "test_gis_resample.py": "solver/gis",
    "test_gis_rpc.py": "solver/gis",
    "test_gis_rpc_images.py": "solver/gis",
    "test_gis_transforms.py": "solver/gis",
    "gis_scenes.py": "solver/gis",  # since moved to tests/utils/
    # importers
    "test_importers.py": "solver/importers",
    "test_importers_rpc.py": "solver/importers",
    "test_job_command.py": "solver/importers",
    "test_import_rpc_vendor_files.py": "solver/importers",
    "test_job_named_measurements.py": "solver/importers",
    # vendors' sensor metadata
    "test_sensors_maxar.py": "solver/sensors",
    "test_sensors_spot5.py": "solver/sensors",
    "test_sensors_spot1to4.py": "solver/sensors",
    "test_sensors_dimap_v2.py": "solver/sensors",
    "test_sensors_cbers.py": "solver/sensors",
    "test_sensor_simulated.py": "solver/sensors",
    "simulated_dimap.py": "solver/sensors",
    # the simulator
    "test_simulate_experiments.py": "solver/simulate",
    "test_simulate_geometry.py": "solver/simulate",
    "test_simulate_independence.py": "solver/simulate",
    "test_simulate_iop.py": "solver/simulate",
    "test_simulate_models.py": "solver/simulate",
    "test_simulate_orbit.py": "solver/simulate",
    "test_simulate_rpc.py": "solver/simulate",
    "test_simulate_scene.py": "solver/simulate",
    "test_simulate_selfcal.py": "solver/simulate",
    "test_simulate_small_triplet.py": "solver/simulate",
    # matching
    "test_matching.py": "solver/matching",
    "test_matching_gcp.py": "solver/matching",
    "test_matching_real.py": "solver/matching",
}

# tests/service/<name> -> folder under tests/service/ (mirrors service/<package>/); the rest of
# tests/service/ (the harnesses, conftest.py, tests of service/*.py modules and of the whole
# server) stays where it is: ``python scripts/mirror_tests.py --service``
SERVICE_MAPPING: dict[str, str] = {
    # service/routes/ and the use cases behind them, in process or on a real server
    "test_service_api.py": "service/routes",
    "test_service_admin.py": "service/routes",
    "test_service_bad_input.py": "service/routes",
    "test_service_camera_owners.py": "service/routes",
    "test_service_compose.py": "service/routes",
    "test_service_gis.py": "service/routes",
    "test_service_ownership.py": "service/routes",
    "test_service_promises.py": "service/routes",
    "test_service_uploads.py": "service/routes",
    # service/store/: the job store, its migrations, leases, fair sharing, quotas, retention
    "test_service_store.py": "service/store",
    "test_service_migrations.py": "service/store",
    "test_service_leases.py": "service/store",
    "test_service_fair.py": "service/store",
    "test_service_quota.py": "service/store",
    "test_service_retention.py": "service/store",
    # service/queue/: local workers and Celery, lanes, fair order, restarts
    "test_service_celery.py": "service/queue",
    "test_service_fair_queues.py": "service/queue",
    "test_service_lanes.py": "service/queue",
    "test_service_restart.py": "service/queue",
}

# stay at the top of tests/: cross-cutting tests and the helpers several packages share
STAY = {
    "conftest.py",
    "tolerances.py",
    "bad_job_cases.py",
    "test_architecture.py",
    "test_docs.py",
    "test_examples.py",
    "test_report_fixtures.py",
    "test_bad_input.py",
}

SYS_PATH_BEGIN = "# ---- mirror_tests: helper folders on sys.path (begin) ----"
SYS_PATH_END = "# ---- mirror_tests: helper folders on sys.path (end) ----"
TEXT_SUFFIXES = {".py", ".md", ".toml", ".yml", ".yaml", ".txt", ".cfg", ".ini", ".sh"}
TEXT_NAMES = {"Makefile", "Dockerfile"}


def service_moves() -> int:
    """Move the service tests into tests/service/<package>/ (``--service``): the same steps as the
    solver move, one folder down."""
    here = TESTS / "service"
    present = {n: d for n, d in SERVICE_MAPPING.items() if (here / n).exists()}
    names = [p.name for p in TESTS.rglob("*.py") if p.name not in ("conftest.py", "__init__.py")]
    if any(names.count(n) > 1 for n in names):
        sys.exit("mirror_tests: duplicate basenames under tests/")
    for name, folder in present.items():
        print(f"git mv tests/service/{name} tests/{folder}/{name}")
        (TESTS / folder).mkdir(parents=True, exist_ok=True)
        subprocess.run(["git", "mv", f"tests/service/{name}", f"tests/{folder}/{name}"], cwd=ROOT, check=True)
        moved = TESTS / folder / name
        moved.write_text(rewrite_file_depth(moved.read_text(), 1))
    pattern = re.compile(r"(?<![\w/.])tests/service/(" + "|".join(re.escape(n) for n in present) + r")\b")
    for f in text_files():
        try:
            text = f.read_text()
        except UnicodeDecodeError:
            continue
        new = pattern.sub(lambda m: f"tests/{present[m.group(1)]}/{m.group(1)}", text)
        if new != text:
            print("references rewritten in", f.relative_to(ROOT))
            f.write_text(new)
    conftest = TESTS / "conftest.py"
    text = conftest.read_text()
    folders = helper_folders({})
    text = re.sub(re.escape(SYS_PATH_BEGIN) + r".*?" + re.escape(SYS_PATH_END) + r"\n", "", text, flags=re.S)
    conftest.write_text(text.rstrip("\n") + "\n\n\n" + conftest_block(folders))
    print("sys.path folders in tests/conftest.py:", ", ".join(folders))
    return 0


def check_mapping() -> None:
    """Every top-level Python file of tests/ is mapped or listed to stay; basenames stay unique."""
    here = {p.name for p in TESTS.glob("*.py")}
    unplaced = sorted(here - set(MAPPING) - STAY)
    if unplaced:
        sys.exit(f"mirror_tests: no place for {', '.join(unplaced)}: add them to MAPPING or STAY")
    names = [p.name for p in TESTS.rglob("*.py") if p.name != "conftest.py" and p.name != "__init__.py"]
    dups = sorted({n for n in names if names.count(n) > 1})
    if dups:
        sys.exit(f"mirror_tests: duplicate basenames under tests/: {', '.join(dups)}")


def rewrite_file_depth(text: str, depth: int) -> str:
    """``Path(__file__)`` expressions of a file moved ``depth`` folders further down tests/."""
    def up(m: re.Match) -> str:
        return f"{m.group(1)}.parents[{int(m.group(2)) + depth}]"

    text = re.sub(r"(Path\(__file__\)(?:\.resolve\(\))?)\.parents\[(\d+)\]", up, text)
    text = re.sub(r"(Path\(__file__\)(?:\.resolve\(\))?)\.parent\.parent\b", lambda m: f"{m.group(1)}.parents[{1 + depth}]", text)
    text = re.sub(r"(Path\(__file__\)(?:\.resolve\(\))?)\.parent\b(?!s)", lambda m: f"{m.group(1)}.parents[{depth}]", text)
    return text


def imported_helpers(path: Path) -> set[str]:
    """Top-level module names a test file imports that are files under tests/."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
        elif isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
    return names


def helper_folders(new_place: dict[str, Path]) -> list[str]:
    """Folders (relative to tests/) of modules imported by name from a file in another folder."""
    where = {p.stem: p.parent for p in TESTS.rglob("*.py")}
    where.update({Path(n).stem: d for n, d in new_place.items()})
    out = set()
    for p in TESTS.rglob("*.py"):
        folder = new_place.get(p.name, p.parent) if p.parent == TESTS else p.parent
        for name in imported_helpers(p):
            if name in where and where[name] != folder and where[name] != TESTS:
                out.add(str(where[name].relative_to(TESTS)))
    return sorted(out)


def conftest_block(folders: list[str]) -> str:
    lines = [
        SYS_PATH_BEGIN,
        "def _helper_folders_on_sys_path() -> None:",
        '    """Test helpers imported by their module name from any folder: pytest (prepend mode) puts',
        '    only a test file\'s own folder on sys.path; their folders, from scripts/mirror_tests.py."""',
        "    import sys",
        "    from pathlib import Path",
        "",
        f"    for folder in {tuple(folders)!r}:",
        "        path = str(Path(__file__).resolve().parent / folder)",
        "        if path not in sys.path:",
        "            sys.path.insert(0, path)",
        "",
        "",
        "_helper_folders_on_sys_path()",
        SYS_PATH_END,
    ]
    return "\n".join(lines) + "\n"


def text_files() -> list[Path]:
    listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    return [ROOT / f for f in listed if (Path(f).suffix in TEXT_SUFFIXES or Path(f).name in TEXT_NAMES) and (ROOT / f).is_file()]


def rewrite_references(moves: dict[str, str], dry: bool) -> list[str]:
    """``tests/<name>`` (not already deeper) -> ``tests/<folder>/<name>``, and the dotted module
    ``tests.<stem>`` -> ``tests.<folder dotted>.<stem>``, in every tracked text file."""
    pattern = re.compile(r"(?<![\w/.])tests/(" + "|".join(re.escape(n) for n in moves) + r")\b")
    stems = {Path(n).stem: d for n, d in moves.items()}
    dotted = re.compile(r"(?<![\w.])tests\.(" + "|".join(re.escape(s) for s in stems) + r")\b")
    changed = []
    for f in text_files():
        try:
            text = f.read_text()
        except UnicodeDecodeError:
            continue
        new = pattern.sub(lambda m: f"tests/{moves[m.group(1)]}/{m.group(1)}", text)
        new = dotted.sub(lambda m: f"tests.{stems[m.group(1)].replace('/', '.')}.{m.group(1)}", new)
        if new != text:
            changed.append(str(f.relative_to(ROOT)))
            if not dry:
                f.write_text(new)
    return changed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dry-run", action="store_true", help="print what would move and change; touch nothing")
    ap.add_argument("--service", action="store_true", help="move the service tests into tests/service/<package>/ instead")
    args = ap.parse_args(argv)
    if args.service:
        return service_moves()
    check_mapping()
    present = {n: d for n, d in MAPPING.items() if (TESTS / n).exists()}
    new_place = {n: TESTS / d for n, d in present.items()}
    folders = helper_folders(new_place)
    for name, folder in present.items():
        print(f"git mv tests/{name} tests/{folder}/{name}")
    print("sys.path folders in tests/conftest.py:", ", ".join(folders) or "none")
    refs = rewrite_references({n: d for n, d in present.items()}, dry=True)
    print("references rewritten in:", ", ".join(refs) or "none")
    if args.dry_run:
        return 0
    for name, folder in present.items():
        (TESTS / folder).mkdir(parents=True, exist_ok=True)
        subprocess.run(["git", "mv", f"tests/{name}", f"tests/{folder}/{name}"], cwd=ROOT, check=True)
        moved = TESTS / folder / name
        moved.write_text(rewrite_file_depth(moved.read_text(), len(Path(folder).parts)))
    rewrite_references({n: d for n, d in present.items()}, dry=False)
    conftest = TESTS / "conftest.py"
    text = conftest.read_text()
    text = re.sub(re.escape(SYS_PATH_BEGIN) + r".*?" + re.escape(SYS_PATH_END) + r"\n", "", text, flags=re.S)
    if folders:
        text = text.rstrip("\n") + "\n\n\n" + conftest_block(folders)
    conftest.write_text(text)
    # the dotted imports rewritten above may need re-sorting (ruff's isort rules, as make test runs them)
    subprocess.run([sys.executable, "-m", "ruff", "check", "--fix", "--select", "I", "tests"], cwd=ROOT, check=False)
    print("done: run `python -m pytest --collect-only -q | tail -1` and compare with the count before the move")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
