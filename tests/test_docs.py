"""The documentation site (docs/, mkdocs.yml): it builds in strict mode, its generated reference
covers the code, its tutorials run as written, and the README and docs name no issue numbers.

- The strict build fails on a broken link, a missing page or a bad anchor (MkDocs' validation).
- The reference pages are generated from the code (scripts/gen_reference.py); the coverage
  checks walk the code independently (the pydantic model classes, argparse's actions, the
  OpenAPI paths, the settings' fields, the registry) and look each entry up in the page.
- Tutorials: every ``sh`` and ``python`` block of a tutorial page runs, in order, in one
  temporary folder holding a copy of ``examples/``; a block is left out only when the line
  before its fence says ``<!-- not run: REASON -->``.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

import gen_reference  # noqa: E402

BIN = Path(sys.executable).parent
ISSUE_NUMBER = re.compile(r"\bissues? #?\d+|\(#\d+\)", re.I)
NOT_RUN = re.compile(r"<!--\s*not run:\s*(.+?)\s*-->")
OUTPUT_MARK = re.compile(r"<!--\s*output\s*-->")
NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", re.I)
# A number a tutorial states may differ from the run's by one unit of its last printed digit
# or by this fraction (rounding across platforms and BLAS builds); more, and the text is stale.
OUTPUT_REL_TOL = 0.02
FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```\s*$", re.M | re.S)


# ------------------------------------------------------------------ the strict build ------
@pytest.mark.slow
def test_the_site_builds_strictly(tmp_path: Path) -> None:
    """``mkdocs build --strict`` (what ``make docs`` runs): every page, link and anchor resolves."""
    out = tmp_path / "site"
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=600, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for page in ("index.html", "tutorials/prism-triplet.html", "reference/job.html", "reference/cli.html", "reference/report-keys.html",
                 "reference/http-api.html", "reference/settings.html", "reference/platform-models.html"):
        assert (out / page).is_file(), f"{page} not built"
    assert "PBA_QUEUE" in (out / "reference" / "settings.html").read_text()


# ------------------------------------------------------------------ reference coverage ----
def sections(markdown: str, level: str) -> dict[str, str]:
    """Heading text -> the text below it up to the next heading of the same level."""
    parts = re.split(rf"^{level} (.+)$", markdown, flags=re.M)
    return {parts[i].strip(): parts[i + 1] for i in range(1, len(parts) - 1, 2)}


def missing_job_fields(page: str) -> list[str]:
    from pydantic import BaseModel

    from solver.schema import job as job_module

    found = sections(page, "##")
    missing = []
    models = {c.__name__: c for c in vars(job_module).values() if isinstance(c, type) and issubclass(c, BaseModel) and c.__module__ == job_module.__name__}
    for name, model in models.items():
        if not model.model_fields or name.startswith("_"):
            continue
        if name not in found:
            missing.append(name)
            continue
        for field, info in model.model_fields.items():
            key = info.alias or field
            if f"| `{key}` |" not in found[name]:
                missing.append(f"{name}.{key}")
    return missing


def missing_cli_flags(page: str) -> list[str]:
    found = sections(page, "##")
    missing = []

    def walk(parser: argparse.ArgumentParser, path: list[str]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    here = [*path, name]
                    title = " ".join(here)
                    if title not in found:
                        missing.append(title)
                    else:
                        for a in sub._actions:
                            if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
                                continue
                            for flag in a.option_strings or [a.metavar or a.dest]:
                                if f"`{flag}`" not in found[title]:
                                    missing.append(f"{title} {flag}")
                    walk(sub, here)

    from service.cli import register
    from solver.cli import build_parser

    walk(build_parser(extra=(register,)), ["pba"])
    return missing


def missing_endpoints(page: str) -> list[str]:
    """Every operation of the running application's OpenAPI document (not the openapi.yaml
    file the page is generated from) must have its heading."""
    from service.app import create_app
    from service.settings import Settings

    paths = create_app(Settings(_env_file=None)).openapi()["paths"]  # type: ignore[call-arg]
    headings = set(sections(page, "##"))
    return [
        f"{method.upper()} {path}"
        for path, ops in paths.items()
        for method in ops
        if method in gen_reference.HTTP_METHODS and f"{method.upper()} {path}" not in headings
    ]


def missing_settings(page: str) -> list[str]:
    from service.settings import Settings

    return [f"PBA_{n.upper()}" for n in Settings.model_fields if f"| `PBA_{n.upper()}` |" not in page]


def missing_models(page: str) -> list[str]:
    """Every registered model has its heading, and every other name a job may use for it
    (MT12 for ON2) is named in that model's section."""
    from solver.platforms import aliases, all_models

    found = sections(page, "##")
    missing = [m.name for m in all_models() if m.name not in found]
    missing += [a for m in all_models() if m.name in found for a in aliases(m) if f"`{a}`" not in found[m.name]]
    return missing


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    out = tmp_path_factory.mktemp("reference")
    gen_reference.write(out)
    return {p.relative_to(out).as_posix(): p.read_text() for p in out.rglob("*.md")}


def test_every_job_field_has_its_entry(generated: dict[str, str]) -> None:
    assert missing_job_fields(generated["reference/job.md"]) == []


def test_every_cli_command_and_flag_has_its_entry(generated: dict[str, str]) -> None:
    assert missing_cli_flags(generated["reference/cli.md"]) == []


def test_every_endpoint_has_its_entry(generated: dict[str, str]) -> None:
    assert missing_endpoints(generated["reference/http-api.md"]) == []


def test_every_setting_has_its_entry(generated: dict[str, str]) -> None:
    assert missing_settings(generated["reference/settings.md"]) == []


def test_every_platform_model_has_its_entry(generated: dict[str, str]) -> None:
    assert missing_models(generated["reference/platform-models.md"]) == []


def test_the_coverage_checks_have_teeth(generated: dict[str, str]) -> None:
    """Each check finds an entry taken out of its page."""
    job = generated["reference/job.md"].replace("| `dx_mm` |", "| dx |", 1)
    assert "Chip.dx_mm" in missing_job_fields(job)
    cli = generated["reference/cli.md"].replace("`--per-chip`", "per-chip")
    assert any(m.endswith("--per-chip") for m in missing_cli_flags(cli))
    http = generated["reference/http-api.md"].replace("## GET /conformance", "## conformance")
    assert "GET /conformance" in missing_endpoints(http)
    settings = generated["reference/settings.md"].replace("| `PBA_LEASE_S` |", "| lease |")
    assert missing_settings(settings) == ["PBA_LEASE_S"]
    models = generated["reference/platform-models.md"].replace("## PASS-J2\n", "## pass\n")
    assert missing_models(models) == ["PASS-J2"]
    assert missing_models(generated["reference/platform-models.md"].replace("`MT12`", "MT12")) == ["MT12"]


def test_every_report_key_is_listed_and_in_the_contract(generated: dict[str, str]) -> None:
    """Every key of the pinned example reports has its row in the generated page, and the
    hand-written contract (docs/report-contract.md) names it."""
    import gzip
    import json

    keys: set[str] = set()
    paths: set[str] = set()

    def walk(node: object, path: str) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                keys.add(key)
                paths.add(f"{path}/{key}" if path else key)
                walk(value, f"{path}/{key}" if path else key)
        elif isinstance(node, list):
            for item in node:
                walk(item, path + "[]")

    fixtures = sorted((ROOT / "tests" / "fixtures" / "reports").glob("*.report.json.gz"))
    assert fixtures
    for fixture in fixtures:
        with gzip.open(fixture, "rt") as f:
            walk(json.load(f), "")
    page = generated["reference/report-keys.md"]
    assert [p for p in sorted(paths) if f"| `{p}` |" not in page] == []
    contract = (ROOT / "docs" / "report-contract.md").read_text()
    assert sorted(k for k in keys if f'"{k}"' not in contract) == []


def numeric_fields_without_unit() -> list[str]:
    """``Model.field`` of every numeric job field (numbers, integers, lists or maps of them)
    whose name states no unit and that :data:`gen_reference.FIELD_UNITS` does not list."""
    from solver.schema.job import Job

    schema = Job.model_json_schema(by_alias=True)

    def numeric(prop: dict) -> bool:
        if prop.get("type") in ("number", "integer"):
            return True
        if any(numeric(sub) for key in ("anyOf", "prefixItems") for sub in prop.get(key, [])):
            return True
        return any(isinstance(prop.get(key), dict) and numeric(prop[key]) for key in ("items", "additionalProperties"))

    models = [("Job", schema), *sorted(schema.get("$defs", {}).items())]
    return [f"{name}.{field}" for name, s in models for field, prop in s.get("properties", {}).items()
            if numeric(prop) and not gen_reference.field_unit(name, field)]


def test_every_numeric_job_field_has_its_unit(generated: dict[str, str]) -> None:
    assert numeric_fields_without_unit() == []
    assert "| `coordinates` |" in generated["reference/job.md"] and "ellipsoidal height m" in generated["reference/job.md"]
    stale = sorted(set(gen_reference.FIELD_UNITS) - {f"{n}.{f}" for n, f in _all_fields()})
    assert stale == []  # every listed field still exists


def test_the_unit_check_has_teeth(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delitem(gen_reference.FIELD_UNITS, "Rpc.height_off")
    assert numeric_fields_without_unit() == ["Rpc.height_off"]


def _all_fields() -> list[tuple[str, str]]:
    from solver.schema.job import Job

    schema = Job.model_json_schema(by_alias=True)
    models = [("Job", schema), *schema.get("$defs", {}).items()]
    return [(name, field) for name, s in models for field in s.get("properties", {})]


def test_units_come_from_the_names() -> None:
    assert [gen_reference.unit_of(n) for n in ("focal_mm", "sigma_velocity_m_s", "time_s", "sigma_m", "roll_deg", "sigma_px", "id")] == [
        "mm", "m/s", "s", "m", "deg", "px", ""]


# ------------------------------------------------------------------ words --------------
def user_facing_text() -> dict[str, str]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "examples").rglob("README.md"))]
    return {str(p.relative_to(ROOT)): p.read_text() for p in files}


def test_no_issue_numbers_in_user_facing_text() -> None:
    found = [f"{name}: {m.group(0)!r}" for name, text in user_facing_text().items() for m in ISSUE_NUMBER.finditer(text)]
    assert found == []
    assert ISSUE_NUMBER.search("Blunder detection (issue 15)") and ISSUE_NUMBER.search("fixed in (#12)")


def test_no_issue_numbers_in_the_generated_reference(generated: dict[str, str]) -> None:
    """The reference pages carry the code's own words (help texts, model sources, docstrings)."""
    found = [f"{name}: {m.group(0)!r}" for name, text in generated.items() for m in ISSUE_NUMBER.finditer(text)]
    assert found == []


def test_readme_is_a_front_page() -> None:
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 160
    assert "make serve" in text and "make test" in text and "http://127.0.0.1:8000" in text
    for target in re.findall(r"\]\(((?:docs|examples)/[^)#\s]+)", text):
        assert (ROOT / target).exists(), f"README links to {target}, which does not exist"
    assert "docs/img/web-page.jpg" in text and (ROOT / "docs/img/web-page.jpg").stat().st_size < 300_000


# ------------------------------------------------------------------ tutorials ----------
def tutorial_blocks(markdown: str) -> list[tuple[str, str]]:
    """The (language, code) of every ``sh``/``python`` block a reader runs, in order."""
    blocks = []
    for m in FENCE.finditer(markdown):
        lang = m.group(1)
        if lang not in ("sh", "python"):
            continue
        before = markdown[: m.start()].rstrip().rsplit("\n", 1)[-1]
        if NOT_RUN.search(before):
            continue
        blocks.append((lang, m.group(2)))
    return blocks


def run_tutorial(page: Path, workdir: Path, timeout_s: float, substitutions: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """One bash script of the page's blocks (python blocks through the venv's python), run in
    ``workdir`` (holding copies of ``examples/``, the vendors' metadata files and the real
    image crops, ``tests/data/vendor/`` and ``tests/data/matching/``, as a clone does) with ``pba`` and ``python`` of this environment
    first on the PATH; each key of ``substitutions`` (e.g. the page's port) replaced by its value."""
    shutil.copytree(ROOT / "examples", workdir / "examples")
    for data in ("vendor", "matching", "dem"):
        shutil.copytree(ROOT / "tests" / "data" / data, workdir / "tests" / "data" / data)
    script = ["set -euo pipefail"]
    text = page.read_text()
    for old, new in (substitutions or {}).items():
        text = text.replace(old, new)
    for i, (lang, code) in enumerate(tutorial_blocks(text)):
        if lang == "sh":
            script.append(code)
        else:
            (workdir / f".block{i}.py").write_text(code)
            script.append(f'python "{workdir}/.block{i}.py"')
    full_env = {k: v for k, v in os.environ.items() if not k.startswith("PBA_")}
    full_env["PATH"] = f"{BIN}{os.pathsep}{full_env.get('PATH', '')}"
    full_env["PYTHONPATH"] = str(ROOT)
    return subprocess.run(["bash", "-c", "\n".join(script)], cwd=workdir, env=full_env, capture_output=True, text=True, timeout=timeout_s)


def stated_outputs(markdown: str) -> list[str]:
    """The lines of every ``text`` block marked ``<!-- output -->`` on the line before its fence:
    what the page says the reader will see."""
    lines = []
    for m in FENCE.finditer(markdown):
        before = markdown[: m.start()].rstrip().rsplit("\n", 1)[-1]
        if m.group(1) == "text" and OUTPUT_MARK.search(before):
            lines += [line for line in m.group(2).splitlines() if line.strip()]
    return lines


def _last_digit(number: str) -> float:
    mantissa = re.split("[eE]", number)[0]
    exponent = int(re.split("[eE]", number)[1]) if re.search("[eE]", number) else 0
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    return 10.0 ** (exponent - decimals)


def line_matches(stated: str, seen: str) -> bool:
    """The same words, the same integers (counts), and each decimal number within
    OUTPUT_REL_TOL or one unit of its last digit."""
    if NUMBER.sub("#", stated).strip() != NUMBER.sub("#", seen).strip():
        return False
    for a, b in zip(NUMBER.findall(stated), NUMBER.findall(seen)):
        if a.lstrip("+-").isdigit():
            if int(a) != int(float(b)) or not b.lstrip("+-").isdigit():
                return False
        elif abs(float(a) - float(b)) > max(1.0001 * _last_digit(a), OUTPUT_REL_TOL * abs(float(a))):
            return False
    return True


def missing_outputs(markdown: str, output: str) -> list[str]:
    """The stated output lines (:func:`stated_outputs`) no line of ``output`` matches."""
    seen = [line for line in output.splitlines() if line.strip()]
    return [line for line in stated_outputs(markdown) if not any(line_matches(line, s) for s in seen)]


def test_stated_outputs_are_compared_with_tolerance() -> None:
    page = "x\n<!-- output -->\n```text\nsigma0 0.971 (a priori 1.0), 20 points\n```\n\n```text\nnot marked\n```\n"
    assert stated_outputs(page) == ["sigma0 0.971 (a priori 1.0), 20 points"]
    assert missing_outputs(page, "sigma0 0.972 (a priori 1.0), 20 points\n") == []
    assert missing_outputs(page, "sigma0 0.995 (a priori 1.0), 20 points\n") != []  # 2.5 % off: stale
    assert missing_outputs(page, "sigma0 0.971 (a priori 1.0), 21 points\n") != []
    assert missing_outputs(page, "sigma0 0.971 (a posteriori 1.0), 20 points\n") != []


def test_tutorial_blocks_are_found() -> None:
    page = "text\n\n```sh\necho a\n```\n\n<!-- not run: needs Docker -->\n```sh\ndocker x\n```\n\n```python\nprint(1)\n```\n\n```text\nout\n```\n"
    assert tutorial_blocks(page) == [("sh", "echo a\n"), ("python", "print(1)\n")]


@pytest.mark.slow
def test_tutorial_prism_triplet_runs(tmp_path: Path) -> None:
    page = ROOT / "docs" / "tutorials" / "prism-triplet.md"
    proc = run_tutorial(page, tmp_path, timeout_s=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert missing_outputs(page.read_text(), proc.stdout + proc.stderr) == [], proc.stdout[-3000:] + proc.stderr[-3000:]
    work = tmp_path / "triplet"
    for made in ("job.json", "report.json", "ortho.tif", "prism-nadir_RPC.TXT", "pixel.csv"):
        assert (work / made).is_file(), made


@pytest.mark.slow
def test_tutorial_lab_server_runs(tmp_path: Path) -> None:
    with socket.socket() as s:  # a free port instead of the page's 8765
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = run_tutorial(ROOT / "docs" / "tutorials" / "lab-server.md", tmp_path, timeout_s=600, substitutions={"8765": str(port)})
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = proc.stdout
    # no key: 401; Alice's job solved; her camera created (201) and shared; Bob reads the shared
    # camera; the metrics count one successful job of hers and the worker; the admin lists users
    assert out.splitlines().count("401") == 1, out
    assert "sigma0 " in out and "lab-prism-nadir version 1 shared True" in out, out
    assert 'pba_user_jobs_total{status="successful",user="alice"} 1.0' in out and "pba_workers 1.0" in out, out
    assert "['alice', 'bob', 'maria']" in out and "would delete 0 finished jobs" in out + proc.stderr, out


@pytest.mark.slow
def test_tutorial_worldview_pair_runs(tmp_path: Path) -> None:
    """The real WorldView-2 metadata with simulated measurements: every stated output (the
    metadata's agreement with the RPCs, the check-point RMSEs of the four runs, the RPCs'
    distances) is what the commands print."""
    page = ROOT / "docs" / "tutorials" / "worldview-pair.md"
    proc = run_tutorial(page, tmp_path, timeout_s=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert missing_outputs(page.read_text(), proc.stdout + proc.stderr) == [], proc.stdout[-3000:] + proc.stderr[-3000:]
    for made in ("fragment.json", "direct.report.json", "adjusted.report.json", "rpc-shift.report.json", "L_RPC.TXT"):
        assert (tmp_path / "wv2" / made).is_file(), made


@pytest.mark.slow
def test_tutorial_no_control_runs(tmp_path: Path) -> None:
    """Real Pleiades images, their RPCs and a public SRTM crop, no control point: the job is
    composed, matched and adjusted; the datum comes from the bias priors and the DEM, and the
    DEM heights agree with the tie points' (the report's dem section)."""
    import json

    page = ROOT / "docs" / "tutorials" / "no-control.md"
    proc = run_tutorial(page, tmp_path, timeout_s=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads((tmp_path / "report.json").read_text())
    datum = report["quality"]["datum"]
    assert any(d.startswith("heights from the DEM") for d in datum["defined_by"]) and not datum["undetermined"]
    height = next(d["sigma_m"] for d in datum["directions"] if d["direction"] == "shift_height")
    assert height < 3.0  # the DEM's 235 heights (0.87 m), against 20 m from the bias priors alone
    stats = report["dem"]["statistics"]
    assert stats["n"] >= 50 and abs(stats["weighted_mean_m"]) < 3.0 and stats["rms_normalised"] < 1.5
    assert "refused" in proc.stdout + proc.stderr or "datum is not determined" in proc.stdout + proc.stderr


@pytest.mark.slow
def test_tutorial_rpc_triplet_runs(tmp_path: Path) -> None:
    """Simulated RPC images (480 x 480 px, so it stays short): matching, the RPC-DRIFT bias
    recovered (the page's own assertion), the comparison table and the refined RPCs' distances
    as stated."""
    page = ROOT / "docs" / "tutorials" / "rpc-triplet.md"
    proc = run_tutorial(page, tmp_path, timeout_s=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert missing_outputs(page.read_text(), proc.stdout + proc.stderr) == [], proc.stdout[-3000:] + proc.stderr[-3000:]
    for made in ("ties.csv", "job.json", "report.json", "comparison.json", "refined/back.tif", "refined/fwd.tif"):
        assert (tmp_path / "triplet" / made).is_file(), made
